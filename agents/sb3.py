"""Stable-Baselines3 glue: the only module that imports stable_baselines3 (and sb3_contrib).

A saved policy is ``NAME.zip`` (the SB3 model) and, when training normalized observations or rewards,
``NAME.vecnormalize.pkl`` beside it (the running statistics); :func:`load_model` picks both up, so a
loaded policy sees observations exactly as it did in training. Both are written atomically. The model
also carries the id of the env it was trained on (``aasl_env_id``; SB3 saves a model's attributes with
it), because a policy trained on ``AASL-Greedy-v0`` outputs a residual on the planner's command and
must be run in that env: :attr:`LoadedPolicy.env_id` tells the evaluation which.
"""

from __future__ import annotations

import logging
import pickle
import zipfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

from aasl_gym.io import atomic_write, atomic_write_text
from aasl_gym.registration import ENV_IDS
from agents.rollout import play_episode

logger = logging.getLogger(__name__)

ALGORITHMS = ("ppo", "sac", "td3", "a2c", "recurrent-ppo")


def algorithm_class(name: str):
    """The SB3 class for ``name`` (``recurrent-ppo`` needs sb3-contrib)."""
    if name not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {name!r}; allowed: {list(ALGORITHMS)}")
    if name == "recurrent-ppo":
        try:
            from sb3_contrib import RecurrentPPO
        except ImportError as exc:
            raise ImportError("recurrent-ppo needs sb3-contrib (a dependency of aasl-gym): pip install sb3-contrib") from exc
        return RecurrentPPO
    import stable_baselines3

    return getattr(stable_baselines3, name.upper())


def statistics_path(model_path: str | Path) -> Path:
    """Where a model's normalization statistics live: ``NAME.zip`` -> ``NAME.vecnormalize.pkl``."""
    path = Path(model_path)
    return path.with_name(path.stem + ".vecnormalize.pkl")


def save_model(model, path: str | Path) -> Path:
    """Save ``model`` to ``path`` (a .zip) and its VecNormalize statistics beside it, each atomically."""
    path = Path(path)
    atomic_write(path, lambda tmp: model.save(tmp))
    normalizer = model.get_vec_normalize_env()
    if normalizer is not None:
        atomic_write(statistics_path(path), lambda tmp: normalizer.save(tmp))
    return path


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
    algo, sep, path = spec.partition(":")
    if not sep or not path:
        raise ValueError(f"model {spec!r}: expected ALGO:PATH, e.g. ppo:models/ppo_default.zip")
    cls = algorithm_class(algo)
    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f"model {spec!r}: no file at {file}")
    if not zipfile.is_zipfile(file):
        raise ValueError(f"model {spec!r}: {file} is not a Stable-Baselines3 model (not a zip archive)")
    try:
        model = cls.load(file, device=device)
    except Exception as exc:  # SB3 raises many kinds on a damaged archive
        raise ValueError(f"model {spec!r}: {file} could not be loaded ({type(exc).__name__}: {exc})") from exc
    stats = statistics_path(file)
    normalizer = None
    if stats.is_file():
        try:
            with open(stats, "rb") as handle:
                normalizer = pickle.load(handle)
        except Exception as exc:
            raise ValueError(f"model {spec!r}: its statistics {stats} could not be loaded ({type(exc).__name__}: {exc})") from exc
        if not hasattr(normalizer, "normalize_obs"):
            raise ValueError(f"model {spec!r}: {stats} holds no VecNormalize statistics")
        normalizer.training = False
    policy = LoadedPolicy(model, normalizer)
    if policy.env_id not in ENV_IDS:
        raise ValueError(f"model {spec!r}: trained on env {policy.env_id!r}, which is not one of {sorted(ENV_IDS)}")
    return policy


def make_callbacks(out: Path, algo: str, make_env: Callable[[], Any], eval_seeds: list[int], eval_every: int,
                   checkpoint_every: int, report: Callable[[str], None]):
    """The training callbacks: evaluation on fixed seeds (keeping the best model), atomic checkpoints, and
    the training episodes' metrics in the log.

    ``eval_every`` and ``checkpoint_every`` count environment steps over all the training envs.
    ``report`` receives one line per evaluation (the CLI prints it); the evaluations so far are also
    rewritten to ``out/evaluations.csv`` after each one (the learning curve, with or without TensorBoard).
    """
    from stable_baselines3.common.callbacks import BaseCallback

    class FixedSeedEvaluation(BaseCallback):
        """Runs the policy deterministically on the same seeds every time, so evaluations compare."""

        def __init__(self):
            super().__init__()
            self.env = make_env()
            self.best = -np.inf
            self.next_at = eval_every
            self.curve = ["timesteps,mean_return,success_1m,mean_convergence_time_s"]

        def _on_step(self) -> bool:
            if self.num_timesteps < self.next_at:
                return True
            self.next_at += eval_every
            policy = LoadedPolicy(self.model, self.model.get_vec_normalize_env())
            returns, successes, times = [], [], []
            for seed in eval_seeds:
                rewards = []
                info = play_episode(self.env, policy, seed, on_step=lambda reward, _: rewards.append(reward))
                returns.append(sum(rewards))
                successes.append(bool(info["success"]["1.0"]))
                times.append(float(info["convergence_time"]))
            mean_return, success = float(np.mean(returns)), float(np.mean(successes))
            converged = [t for t in times if np.isfinite(t)]
            mean_time = float(np.mean(converged)) if converged else float("nan")
            self.logger.record("eval/mean_return", mean_return)
            self.logger.record("eval/success_1m", success)
            if converged:
                self.logger.record("eval/mean_convergence_time", mean_time)
            line = f"step {self.num_timesteps:,}: return {mean_return:.1f}, success at 1 m {success:.0%}"
            if converged:
                line += f", mean convergence time {mean_time:.1f} s"
            self.curve.append(f"{self.num_timesteps},{mean_return:.4f},{success:.4f},{mean_time:.4f}")
            atomic_write_text(out / "evaluations.csv", "\n".join(self.curve) + "\n")
            if mean_return > self.best:
                self.best = mean_return
                save_model(self.model, out / "best" / "model.zip")
                line += " (best so far, saved)"
            report(line)
            return True

    class AtomicCheckpoint(BaseCallback):
        def __init__(self):
            super().__init__()
            self.next_at = checkpoint_every

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_at:
                self.next_at += checkpoint_every
                save_model(self.model, out / "checkpoints" / f"{algo}_{self.num_timesteps}.zip")
            return True

    class EpisodeMetrics(BaseCallback):
        """Logs the training episodes' convergence time, success and final error beside the reward
        (TensorBoard's ``episode/`` scalars), averaged over the episodes that ended in each rollout."""

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

    return [FixedSeedEvaluation(), AtomicCheckpoint(), EpisodeMetrics()]
