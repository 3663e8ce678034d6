"""Stable-Baselines3 glue: the only module that imports stable_baselines3 (and sb3_contrib).

A saved policy is ``NAME.zip`` (the SB3 model) and, when training normalized observations or rewards,
``NAME.vecnormalize.pkl`` beside it (the running statistics); :func:`load_model` picks both up, so a
loaded policy sees observations exactly as it did in training. Both are written atomically, and the model
records the SHA-256 of the statistics saved with it (``aasl_statistics``; None without), so that a load refuses
another save's (a crash between the two writes, or a later run into the same folder). The model
also carries the id of the env it was trained on (``aasl_env_id``; SB3 saves a model's attributes with
it), because a policy trained on ``AASL-Greedy-v0`` outputs a residual on the planner's command and
must be run in that env: :attr:`LoadedPolicy.env_id` tells the evaluation which.

:func:`train` runs a training schedule (:mod:`agents.training`) with the callbacks of
:func:`make_callbacks`: evaluation on fixed seeds, atomic checkpoints and the episodes' metrics.
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import pickle
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger, make_output_format
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.utils import get_latest_run_id

from aasl_gym.config import ConfigError, EnvConfig
from aasl_gym.io import atomic_write, atomic_write_text
from aasl_gym.registration import ALL_IDS, FACILITY_ID
from agents.rollout import play_episode
from agents.training import ALGORITHMS, Schedule

logger = logging.getLogger(__name__)


def algorithm_class(name: str):
    """The SB3 class for ``name`` (``recurrent-ppo`` needs sb3-contrib)."""
    if name not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {name!r}; allowed: {list(ALGORITHMS)}")
    if name == "recurrent-ppo":
        try:
            from sb3_contrib import RecurrentPPO
        except ImportError as exc:
            raise ImportError(
                "recurrent-ppo needs sb3-contrib (a dependency of aasl-gym): pip install sb3-contrib"
            ) from exc
        return RecurrentPPO
    import stable_baselines3

    return getattr(stable_baselines3, name.upper())


def statistics_path(model_path: str | Path) -> Path:
    """Where a model's normalization statistics live: ``NAME.zip`` -> ``NAME.vecnormalize.pkl``."""
    path = Path(model_path)
    return path.with_name(path.stem + ".vecnormalize.pkl")


def save_model(model, path: str | Path) -> Path:
    """Save ``model`` to ``path`` (a .zip) and its VecNormalize statistics beside it, each atomically, the model
    with their digest; a model without statistics removes an earlier save's from beside it."""
    path = Path(path)
    normalizer = model.get_vec_normalize_env()
    statistics = None if normalizer is None else pickle.dumps(normalizer)  # what VecNormalize.save writes
    model.aasl_statistics = None if statistics is None else hashlib.sha256(statistics).hexdigest()
    if statistics is None:
        statistics_path(path).unlink(missing_ok=True)
    else:
        atomic_write(statistics_path(path), lambda tmp: Path(tmp).write_bytes(statistics))
    atomic_write(path, lambda tmp: model.save(tmp))
    return path


_NOT_RECORDED = object()  # a model saved before the statistics' digest (models/ppo_default.zip)


def _load_statistics(spec: str, model, stats: Path):
    """The VecNormalize statistics saved with ``model`` (from ``stats``), or None. A model that records their digest
    takes only those; one saved before the digest, whatever file lies beside it."""
    recorded = getattr(model, "aasl_statistics", _NOT_RECORDED)
    if recorded is None:
        if stats.is_file():
            logger.warning("model %s was saved without statistics: %s beside it is ignored", spec, stats)
        return None
    if not stats.is_file():
        if recorded is _NOT_RECORDED:
            return None
        raise FileNotFoundError(f"model {spec!r}: its statistics {stats} are missing (the model was saved with them)")
    data = stats.read_bytes()
    if recorded is not _NOT_RECORDED and hashlib.sha256(data).hexdigest() != recorded:
        raise ValueError(f"model {spec!r}: {stats} holds another save's statistics, not the model's own")
    try:
        normalizer = pickle.loads(data)
    except Exception as exc:
        raise ValueError(
            f"model {spec!r}: its statistics {stats} could not be loaded ({type(exc).__name__}: {exc})"
        ) from exc
    if not hasattr(normalizer, "normalize_obs"):
        raise ValueError(f"model {spec!r}: {stats} holds no VecNormalize statistics")
    normalizer.training = False
    return normalizer


class LoadedPolicy:
    """A trained model with the observation normalization it was trained with, behind ``predict``;
    ``env_id`` is the env it was trained on (``AASL-v0`` for models saved without one)."""

    def __init__(self, model, normalizer=None):
        self.model = model
        self.normalizer = normalizer  # a VecNormalize without its env, or None
        self.env_id = getattr(model, "aasl_env_id", "AASL-v0")

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        if self.normalizer is not None:
            observation = self.normalizer.normalize_obs(np.asarray(observation, dtype=np.float32))
        return self.model.predict(observation, state=state, episode_start=episode_start, deterministic=deterministic)


def load_model(spec: str, device: str = "cpu") -> LoadedPolicy:
    """Load ``ALGO:PATH`` (e.g. ``ppo:runs/x/model.zip``) and its normalization statistics, if saved,
    with a clear error if either is missing or corrupt."""
    if not isinstance(spec, str):
        raise TypeError(f"model {spec!r}: expected a string ALGO:PATH, e.g. ppo:models/ppo_default.zip")
    algo, sep, path = spec.partition(":")
    if not sep or not path:
        raise ValueError(f"model {spec!r}: expected ALGO:PATH, e.g. ppo:models/ppo_default.zip")
    cls = algorithm_class(algo)
    try:
        torch.device(device)
    except RuntimeError as exc:
        raise ValueError(f"device {device!r}: not a torch device, e.g. cpu, cuda or cuda:0 ({exc})") from None
    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f"model {spec!r}: no file at {file}")
    if not zipfile.is_zipfile(file):
        raise ValueError(f"model {spec!r}: {file} is not a Stable-Baselines3 model (not a zip archive)")
    try:
        data, _, _ = load_from_zip_file(file, device="cpu")
        trained_with = (data or {}).get("aasl_algorithm")  # None for a model saved before it was recorded
        if trained_with is None or trained_with == algo:
            model = cls.load(file, device=device)
    except Exception as exc:  # SB3 raises many kinds on a damaged archive
        raise ValueError(f"model {spec!r}: {file} could not be loaded ({type(exc).__name__}: {exc})") from exc
    if trained_with not in (None, algo):
        raise ValueError(f"model {spec!r}: {file} was trained with {trained_with}: load it as {trained_with}:{path}")
    policy = LoadedPolicy(model)
    if policy.env_id not in ALL_IDS:
        raise ValueError(f"model {spec!r}: trained on env {policy.env_id!r}, which is not one of {sorted(ALL_IDS)}")
    policy.normalizer = _load_statistics(spec, model, statistics_path(file))
    return policy


class FixedSeedEvaluation(BaseCallback):
    """Every ``eval_every`` env steps, runs the policy deterministically on the same seeds, so evaluations
    compare; keeps the best model (by mean return) in ``out/best/``, rewrites the evaluations so far to
    ``out/evaluations.csv`` (the learning curve, with or without TensorBoard) and hands ``report`` one line."""

    def __init__(
        self,
        out: Path,
        make_env: Callable[[], Any],
        eval_seeds: list[int],
        eval_every: int,
        report: Callable[[str], None],
    ):
        super().__init__()
        self.out, self.eval_seeds, self.eval_every, self.report = out, eval_seeds, eval_every, report
        self.env = make_env()
        self.best = -np.inf
        self.next_at = eval_every
        self.curve = ["timesteps,mean_return,success_1m,mean_convergence_time_s"]

    def _on_step(self) -> bool:
        if self.num_timesteps < self.next_at:
            return True
        self.next_at += self.eval_every
        mean_return, success, converged = self._evaluate()
        mean_time = float(np.mean(converged)) if converged else float("nan")
        self.logger.record("eval/mean_return", mean_return)
        self.logger.record("eval/success_1m", success)
        if converged:
            self.logger.record("eval/mean_convergence_time", mean_time)
        line = f"step {self.num_timesteps:,}: return {mean_return:.1f}, success at 1 m {success:.0%}"
        if converged:
            line += f", mean convergence time {mean_time:.1f} s"
        self.curve.append(f"{self.num_timesteps},{mean_return:.4f},{success:.4f},{mean_time:.4f}")
        atomic_write_text(self.out / "evaluations.csv", "\n".join(self.curve) + "\n")
        if mean_return > self.best:
            self.best = mean_return
            save_model(self.model, self.out / "best" / "model.zip")
            line += " (best so far, saved)"
        self.report(line)
        return True

    def _evaluate(self) -> tuple[float, float, list[float]]:
        """Mean return, share of successes at 1 m, and the convergence times of the episodes that converged."""
        policy = LoadedPolicy(self.model, self.model.get_vec_normalize_env())
        returns, successes, times = [], [], []
        for seed in self.eval_seeds:
            rewards = []
            # The closure runs within this iteration (play_episode calls it), so it sees this episode's list.
            info = play_episode(self.env, policy, seed, on_step=lambda reward, _: rewards.append(reward))  # noqa: B023
            returns.append(sum(rewards))
            successes.append(bool(info["success"]["1.0"]))
            times.append(float(info["convergence_time"]))
        return float(np.mean(returns)), float(np.mean(successes)), [t for t in times if np.isfinite(t)]


class AtomicCheckpoint(BaseCallback):
    """Every ``checkpoint_every`` env steps, saves the model to ``out/checkpoints/ALGO_STEPS.zip``, atomically."""

    def __init__(self, out: Path, algo: str, checkpoint_every: int):
        super().__init__()
        self.out, self.algo, self.checkpoint_every = out, algo, checkpoint_every
        self.next_at = checkpoint_every

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.next_at:
            self.next_at += self.checkpoint_every
            save_model(self.model, self.out / "checkpoints" / f"{self.algo}_{self.num_timesteps}.zip")
        return True


class EpisodeMetrics(BaseCallback):
    """Logs the training episodes' convergence time, success and final error beside the reward
    (the ``episode/`` columns of ``progress.csv`` and TensorBoard's scalars), averaged over the episodes that ended
    in each rollout."""

    def __init__(self):
        super().__init__()
        self.ended: list[dict] = []

    def _on_step(self) -> bool:
        self.ended += [info for info in self.locals.get("infos", []) if "convergence_time" in info]
        return True

    def _on_rollout_end(self) -> None:
        if not self.ended:
            return
        times = [float(i["convergence_time"]) for i in self.ended]
        converged = [t for t in times if np.isfinite(t)]
        self.logger.record("episode/success_1m", float(np.mean([bool(i["success"]["1.0"]) for i in self.ended])))
        finals = [float(i["final_error"]) for i in self.ended if np.isfinite(float(i["final_error"]))]
        if finals:
            self.logger.record("episode/final_error", float(np.median(finals)))
        if converged:
            self.logger.record("episode/convergence_time", float(np.mean(converged)))
        self.ended = []


def make_callbacks(
    out: Path,
    algo: str,
    make_env: Callable[[], Any],
    eval_seeds: list[int],
    eval_every: int,
    checkpoint_every: int,
    report: Callable[[str], None],
) -> list[BaseCallback]:
    """The training callbacks: evaluation on fixed seeds (keeping the best model), atomic checkpoints, and
    the training episodes' metrics in the log.

    ``eval_every`` and ``checkpoint_every`` count environment steps over all the training envs.
    ``report`` receives one line per evaluation (the CLI prints it); the evaluations so far are also
    rewritten to ``out/evaluations.csv`` after each one (the learning curve, with or without TensorBoard).
    """
    return [
        FixedSeedEvaluation(out, make_env, eval_seeds, eval_every, report),
        AtomicCheckpoint(out, algo, checkpoint_every),
        EpisodeMetrics(),
    ]


def _training_logger(out: Path, name: str) -> Logger:
    """SB3's logger for a run of algorithm ``name`` (its class's): its records (losses, the training episodes'
    metrics) to ``out/progress.csv`` and, when TensorBoard is installed, to ``out/tb/NAME_i``, numbered per run as
    SB3 numbers them. Set on the model: left to itself, SB3 makes a folder in the system's temporary directory for
    every run without TensorBoard."""
    formats = [make_output_format("csv", str(out))]
    if importlib.util.find_spec("tensorboard") is not None:
        try:
            run = out / "tb" / f"{name}_{get_latest_run_id(str(out / 'tb'), name) + 1}"
            formats.append(make_output_format("tensorboard", str(run)))
        except BaseException:
            formats[0].close()
            raise
    return Logger(folder=str(out), output_formats=formats)


def train(
    algo: str,
    config: EnvConfig,
    schedule: Schedule,
    hyperparameters: dict[str, Any],
    seed: int,
    out: Path,
    report: Callable[[str], None],
) -> Path:
    """Train ``algo`` on ``schedule.env`` with ``config`` and save ``out/model.zip`` (with its normalization
    statistics), besides the checkpoints, best model and learning curve of :func:`make_callbacks`; returns
    the model's path. ``report`` receives the opening line and one per evaluation. Raises
    :class:`~aasl_gym.config.ConfigError` for a keyword the algorithm does not take or a value it refuses."""
    import gymnasium as gym
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv, VecNormalize

    env_id = f"aasl_gym:{schedule.env}"
    env_kwargs: dict[str, Any] = {"config": config}
    if schedule.env == FACILITY_ID:
        env_kwargs["scenario"] = None  # the config is complete: not over the id's default scenario
    vec_cls = SubprocVecEnv if schedule.n_envs > 1 else None
    envs = make_vec_env(env_id, n_envs=schedule.n_envs, seed=seed, env_kwargs=env_kwargs, vec_env_cls=vec_cls)
    try:
        if schedule.normalize_observation or schedule.normalize_reward:
            envs = VecNormalize(
                envs,
                norm_obs=schedule.normalize_observation,
                norm_reward=schedule.normalize_reward,
                gamma=float(hyperparameters.get("gamma", 0.99)),
            )
        cls = algorithm_class(algo)
        policy = "MlpLstmPolicy" if algo == "recurrent-ppo" else "MlpPolicy"
        try:
            model = cls(
                policy,
                envs,
                seed=seed,
                verbose=0,
                device="auto",
                **hyperparameters,
            )
        except TypeError as exc:
            unknown = "unexpected keyword" in str(exc)
            what = f"a keyword {cls.__name__} does not take" if unknown else f"a value {cls.__name__} cannot use"
            raise ConfigError(f"section '{algo}' has {what} ({exc})") from exc
        except (AssertionError, ValueError) as exc:  # SB3's and torch's own checks of the values
            refused = f"{cls.__name__} refused a value ({type(exc).__name__}: {exc})"
            raise ConfigError(f"section '{algo}': {refused}") from exc
        # Saved with every checkpoint: evaluation runs the policy in its env, and a load names the algorithm.
        model.aasl_env_id, model.aasl_algorithm = schedule.env, algo
        callbacks = make_callbacks(
            out,
            algo,
            lambda: gym.make(env_id, **env_kwargs),
            schedule.eval_seeds,
            schedule.eval_every,
            schedule.checkpoint_every,
            report,
        )
        report(
            f"training {algo} on {schedule.env} for {schedule.timesteps:,} steps with {schedule.n_envs} envs -> "
            f"{out}; evaluating every {schedule.eval_every:,} steps on seeds {schedule.eval_seeds[0]}-"
            f"{schedule.eval_seeds[-1]}"
        )
        model.set_logger(_training_logger(out, cls.__name__))
        try:
            model.learn(total_timesteps=schedule.timesteps, callback=callbacks, progress_bar=True)
        finally:
            model.logger.close()
        return save_model(model, out / "model.zip")
    finally:
        envs.close()
