"""The training schedule and hyperparameters (``configs/training.yaml``): a small validated dataclass for
the schedule, each algorithm's Stable-Baselines3 keyword arguments beside it.

The schedule is checked like the env config (:mod:`aasl_gym.config`, whose helpers it uses): unknown
keys, wrong types and out-of-range values raise :class:`~aasl_gym.config.ConfigError` naming the key and
what is allowed. The keyword arguments are checked by the algorithm that takes them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from aasl_gym.config import ConfigError, build_section, require, require_choice, to_dict
from aasl_gym.io import read_yaml
from aasl_gym.registration import ALL_IDS

ALGORITHMS = ("ppo", "sac", "td3", "a2c", "recurrent-ppo")


@dataclass(frozen=True)
class Schedule:
    """How a policy trains. Steps count environment steps over all the training envs; training env i
    starts from seed S + i, and evaluation runs seeds ``eval_seed``, ``eval_seed + 1``, ..., which
    training never uses."""

    timesteps: int  # env steps in all
    n_envs: int  # training envs stepped together
    eval_every: int  # env steps between evaluations on the fixed seeds
    eval_episodes: int  # episodes per evaluation
    eval_seed: int  # the first evaluation seed
    checkpoint_every: int  # env steps between checkpoints
    env: str = "AASL-v0"  # the env id trained on (AASL-Greedy-v0: a residual on the greedy planner)
    normalize_observation: bool = False  # running mean and variance of the observation (VecNormalize)
    normalize_reward: bool = False  # running scale of the discounted return (VecNormalize)

    def __post_init__(self) -> None:
        require_choice(self.env, tuple(sorted(ALL_IDS)), "schedule.env")
        for name in ("timesteps", "n_envs", "eval_every", "eval_episodes", "checkpoint_every"):
            value = getattr(self, name)
            require(
                isinstance(value, int) and value >= 1, f"schedule.{name}", f"must be an integer >= 1, got {value!r}"
            )
        require(
            isinstance(self.eval_seed, int) and self.eval_seed >= 0,
            "schedule.eval_seed",
            f"must be an integer >= 0, got {self.eval_seed!r}",
        )

    @property
    def eval_seeds(self) -> list[int]:
        return list(range(self.eval_seed, self.eval_seed + self.eval_episodes))

    def replace(self, **changes: Any) -> Schedule:
        """A copy with some fields changed (``None`` keeps a field), validated again."""
        return dataclasses.replace(self, **{name: value for name, value in changes.items() if value is not None})


REQUIRED = tuple(f.name for f in dataclasses.fields(Schedule) if f.default is dataclasses.MISSING)


def schedule_from_dict(data: Mapping[str, Any]) -> Schedule:
    """Build and validate a :class:`Schedule` from plain values (the optional keys keep their defaults)."""
    require(isinstance(data, Mapping), "schedule", f"must be a mapping, got {type(data).__name__}")
    missing = [name for name in REQUIRED if name not in data]
    if missing:
        raise ConfigError(f"schedule needs integer {', '.join(REQUIRED[:-1])} and {REQUIRED[-1]} (missing: {missing})")
    return build_section(Schedule, data, "schedule")


def load_training(path: str | Path, algo: str) -> tuple[Schedule, dict[str, Any]]:
    """The schedule and ``algo``'s keyword arguments from a YAML file with a ``schedule`` section and one
    section per algorithm; errors name the file and the offending section or key."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"no file at {path}")
    try:
        data = read_yaml(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path} is not valid YAML ({exc})") from exc
    if not isinstance(data, dict) or "schedule" not in data or algo not in data:
        raise ConfigError(f"{path} needs a 'schedule' section and a '{algo}' section")
    require(
        isinstance(data[algo], Mapping), algo, f"must be a mapping of {algo}'s keyword arguments, got {data[algo]!r}"
    )
    return schedule_from_dict(data["schedule"]), dict(data[algo])


def training_record(algo: str, seed: int, schedule: Schedule, run: Schedule, hyperparameters: dict[str, Any]) -> dict:
    """What a run's ``hyperparameters.yaml`` holds: the algorithm, env, seed, steps and envs it ran with
    (``run``: the schedule with the command line's choices), the schedule as the file gives it, and the
    algorithm's keyword arguments."""
    return {
        "algo": algo,
        "env": run.env,
        "seed": seed,
        "timesteps": run.timesteps,
        "n_envs": run.n_envs,
        "schedule": to_dict(schedule),
        algo: hyperparameters,
    }
