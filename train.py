"""Train a Stable-Baselines3 policy on an AASL-Gym environment.

    python train.py --algo ppo [--env ID] [--scenario NAME] [--config FILE] [--timesteps N] [--n-envs K]
                           [--seed S] [--out DIR]

Writes DIR/config.yaml (the exact env config) and DIR/hyperparameters.yaml before training starts, then
DIR/model.zip (with DIR/model.vecnormalize.pkl when the schedule normalizes observations or rewards), checkpoints
under DIR/checkpoints/, the best model of the periodic evaluations under DIR/best/, their learning curve in
DIR/evaluations.csv, and SB3's records as training goes (losses, the training episodes' metrics) in
DIR/progress.csv and, when TensorBoard is installed, under DIR/tb/ (a folder per run, as SB3 numbers them). Every
file but those running logs is written atomically (SB3 rewrites progress.csv whole when a column first appears, so a
run killed at that moment can lose it); a run into a DIR used before replaces its files. The periodic
evaluation runs the same seeds each time (``schedule.eval_seed`` onward), which training never uses: training
env i starts from seed S + i and every later episode continues that env's generator.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from aasl_gym.config import ConfigError, save_config
from aasl_gym.io import atomic_write_text
from aasl_gym.registration import ALL_IDS, FACILITY_ID, check_env_fits
from aasl_gym.scenarios import add_scenario_arguments, command_line_config
from agents.training import ALGORITHMS, load_training, training_record

ROOT = Path(__file__).resolve().parent


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", choices=ALGORITHMS, default="ppo")
    parser.add_argument(
        "--env",
        choices=sorted(ALL_IDS),
        default=None,
        help="default: schedule.env in --hyperparameters (a facility, --scenario facility, trains on AASL-Facility-v0)",
    )
    add_scenario_arguments(parser)
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
    if args.seed < 0:
        parser.error(f"--seed must be >= 0 (Gymnasium's seeds), got {args.seed}")
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        parser.error(f"--out {args.out}: a file is there; give a folder for the run")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        config = command_line_config(args.scenario, args.config, ROOT / "configs" / "default.yaml")
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        schedule, hyperparameters = load_training(args.hyperparameters, args.algo)
    except ConfigError as exc:
        print(f"error: --hyperparameters: {exc}", file=sys.stderr)
        return 2
    run = schedule.replace(env=args.env, timesteps=args.timesteps, n_envs=args.n_envs)
    try:
        option = "--env" if args.env else "--hyperparameters: schedule.env"
        check_env_fits(run.env, config, option, remedy=f" (--env {FACILITY_ID})")
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = args.out or ROOT / "runs" / f"{args.algo}-{args.seed}"
    out.mkdir(parents=True, exist_ok=True)
    # Before training: a run stopped part-way leaves its checkpoints beside the config they were trained with.
    save_config(config, out / "config.yaml")
    record = training_record(args.algo, args.seed, schedule, run, hyperparameters)
    atomic_write_text(out / "hyperparameters.yaml", yaml.safe_dump(record))

    from agents.sb3 import train  # Stable-Baselines3 and torch: only once the input is known to be good

    try:
        model_path = train(
            args.algo, config, run, hyperparameters, args.seed, out, report=lambda line: print(line, flush=True)
        )
    except ConfigError as exc:
        print(f"error: --hyperparameters: {exc}", file=sys.stderr)
        return 2
    beside = "facility" if run.env == FACILITY_ID else "helix"  # the baseline: the facility's own patrol, or the helix
    print(
        f"saved {model_path} (evaluate with: python evaluate.py --config {out / 'config.yaml'} "
        f"--policies {beside} {args.algo}:{model_path})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
