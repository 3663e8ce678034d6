"""Scripted policies for ``AASL-v0``: the patrol patterns, a random policy and the zero action.

A patrol policy reads the robot's reported position and the elapsed time from the observation (see
:mod:`aasl_gym.observation`) and returns the pattern's velocity command as an action, so it flies
exactly what ``AASL-<Pattern>-v0`` flies with a zero action.
"""

from __future__ import annotations

import numpy as np

from aasl_gym.config import PATROLS, EnvConfig
from aasl_gym.observation import decode_observation
from aasl_gym.patrols import PatrolGeometry, patrol_command


class PatrolPolicy:
    """Flies the patrol ``pattern`` (one of :data:`~aasl_gym.config.PATROLS`) from the observation alone."""

    def __init__(self, pattern: str, config: EnvConfig):
        if pattern not in PATROLS:
            raise ValueError(f"unknown patrol pattern {pattern!r}; allowed: {list(PATROLS)}")
        self.pattern = pattern
        self.config = config
        self.geometry = PatrolGeometry.from_config(config)

    def _action(self, obs: np.ndarray) -> np.ndarray:
        seen = decode_observation(obs, self.config)
        command = patrol_command(self.pattern, seen.time, seen.receiver_position, self.config.patrol, self.geometry)
        return command / self.config.receiver.max_speed

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        observation = np.asarray(observation)
        if observation.ndim == 1:
            return self._action(observation).astype(np.float32), state
        return np.stack([self._action(o) for o in observation]).astype(np.float32), state


class RandomPolicy:
    """Uniform actions in the box, from its own seeded generator."""

    def __init__(self, seed: int | None = None):
        self.rng = np.random.default_rng(seed)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        shape = np.shape(observation)[:-1] + (3,)
        return self.rng.uniform(-1.0, 1.0, shape).astype(np.float32), state


class ZeroPolicy:
    """Always zero: on a patrol env this is the pure scripted pattern."""

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        return np.zeros(np.shape(observation)[:-1] + (3,), dtype=np.float32), state
