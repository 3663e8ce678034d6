"""Train a Stable-Baselines3 policy on an AASL-Gym environment.

    python train.py --algo ppo [--env ID] [--config FILE] [--timesteps N] [--n-envs K] [--seed S] [--out DIR]

Writes DIR/model.zip (with DIR/model.vecnormalize.pkl when the schedule normalizes observations or
rewards), DIR/config.yaml (the exact env config), DIR/hyperparameters.yaml, checkpoints under
DIR/checkpoints/, the best model of the periodic evaluations under DIR/best/, their learning curve in
DIR/evaluations.csv and, when TensorBoard is installed, logs under DIR/tb/. Every file is written
atomically. The periodic evaluation runs the same seeds each time (``schedule.eval_seed`` onward), which training never uses: training env i
starts from seed S + i and every later episode continues that env's generator.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from aasl_gym.config import ConfigError, load_config, save_config
from aasl_gym.io import atomic_write_text
from aasl_gym.registration import ENV_IDS

ROOT = Path(__file__).resolve().parent


def parse_args(argv=None) -> argparse.Namespace:
    from agents.sb3 import ALGORITHMS

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", choices=ALGORITHMS, default="ppo")
    parser.add_argument("--env", choices=sorted(ENV_IDS), default=None, help="default: schedule.env in --hyperparameters")
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "default.yaml", help="env config (YAML)")
    parser.add_argument("--hyperparameters", type=Path, default=ROOT / "configs" / "training.yaml")
    parser.add_argument("--timesteps", type=int, default=None, help="default: the schedule in --hyperparameters")
    parser.add_argument("--n-envs", type=int, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None, help="default: runs/ALGO-SEED")
    args = parser.parse_args(argv)
    if args.timesteps is not None and args.timesteps < 1:
        parser.error(f"--timesteps must be >= 1, got {args.timesteps}")
    if args.n_envs is not None and args.n_envs < 1:
        parser.error(f"--n-envs must be >= 1, got {args.n_envs}")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        config = load_config(args.config)
    except ConfigError as exc:
        print(f"error: --config: {exc}", file=sys.stderr)
        return 2
    if not args.hyperparameters.is_file():
        print(f"error: --hyperparameters: no file at {args.hyperparameters}", file=sys.stderr)
        return 2
    try:
        hyper = yaml.safe_load(args.hyperparameters.read_text())
    except yaml.YAMLError as exc:
        print(f"error: --hyperparameters: {args.hyperparameters} is not valid YAML ({exc})", file=sys.stderr)
        return 2
    if not isinstance(hyper, dict) or "schedule" not in hyper or args.algo not in hyper:
        print(f"error: --hyperparameters: {args.hyperparameters} needs a 'schedule' section and a '{args.algo}' section", file=sys.stderr)
        return 2
    schedule = hyper["schedule"]
    try:
        timesteps = args.timesteps or int(schedule["timesteps"])
        n_envs = args.n_envs or int(schedule["n_envs"])
        eval_every, eval_episodes = int(schedule["eval_every"]), int(schedule["eval_episodes"])
        eval_seed, checkpoint_every = int(schedule["eval_seed"]), int(schedule["checkpoint_every"])
        normalize_observation = bool(schedule.get("normalize_observation", False))
        normalize_reward = bool(schedule.get("normalize_reward", False))
    except (KeyError, TypeError, ValueError) as exc:
        print(f"error: --hyperparameters: schedule needs integer timesteps, n_envs, eval_every, eval_episodes, eval_seed "
              f"and checkpoint_every ({type(exc).__name__}: {exc})", file=sys.stderr)
        return 2
    env_name = args.env or schedule.get("env", "AASL-v0")
    if env_name not in ENV_IDS:
        print(f"error: --hyperparameters: schedule.env {env_name!r} is not one of {sorted(ENV_IDS)}", file=sys.stderr)
        return 2
    out = args.out or ROOT / "runs" / f"{args.algo}-{args.seed}"
    out.mkdir(parents=True, exist_ok=True)

    import gymnasium as gym
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv, VecNormalize

    from agents.sb3 import algorithm_class, make_callbacks, save_model

    env_id = f"aasl_gym:{env_name}"
    env_kwargs = {"config": config}
    vec_cls = SubprocVecEnv if n_envs > 1 else None
    envs = make_vec_env(env_id, n_envs=n_envs, seed=args.seed, env_kwargs=env_kwargs, vec_env_cls=vec_cls)
    if normalize_observation or normalize_reward:
        gamma = float(hyper[args.algo].get("gamma", 0.99))
        envs = VecNormalize(envs, norm_obs=normalize_observation, norm_reward=normalize_reward, gamma=gamma)
    try:
        import tensorboard  # noqa: F401

        tensorboard_log = str(out / "tb")
    except ImportError:
        tensorboard_log = None
    cls = algorithm_class(args.algo)
    policy = "MlpLstmPolicy" if args.algo == "recurrent-ppo" else "MlpPolicy"
    try:
        model = cls(policy, envs, seed=args.seed, verbose=0, tensorboard_log=tensorboard_log, device="auto", **hyper[args.algo])
    except TypeError as exc:
        print(f"error: --hyperparameters: section '{args.algo}' has a keyword {cls.__name__} does not take ({exc})", file=sys.stderr)
        return 2
    model.aasl_env_id = env_name  # saved with every checkpoint, so evaluation runs the policy in its env
    eval_seeds = list(range(eval_seed, eval_seed + eval_episodes))
    callbacks = make_callbacks(out, args.algo, lambda: gym.make(env_id, **env_kwargs), eval_seeds, eval_every,
                               checkpoint_every, report=lambda line: print(line, flush=True))
    print(f"training {args.algo} on {env_name} for {timesteps:,} steps with {n_envs} envs -> {out}; "
          f"evaluating every {eval_every:,} steps on seeds {eval_seeds[0]}-{eval_seeds[-1]}")
    model.learn(total_timesteps=timesteps, callback=callbacks, progress_bar=True)
    save_model(model, out / "model.zip")
    save_config(config, out / "config.yaml")
    atomic_write_text(out / "hyperparameters.yaml", yaml.safe_dump({"algo": args.algo, "env": env_name, "seed": args.seed,
                                                                      "timesteps": timesteps, "n_envs": n_envs,
                                                                      "schedule": schedule, args.algo: hyper[args.algo]}))
    envs.close()
    print(f"saved {out / 'model.zip'} (evaluate with: python evaluate.py --policies helix {args.algo}:{out / 'model.zip'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
