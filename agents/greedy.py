"""The information-greedy planner as a policy: the strong non-learned baseline.

Each step it flies the command :class:`aasl_gym.planning.GreedyPlanner` picks (the one of 27 whose next
3 s would add the most position information at the current estimate). It reads only the observation
(see ``aasl_gym.env.OBSERVATION_LAYOUT``), so it runs on ``AASL-v0`` in any vector env: the planner
carries its information from the estimates and reported receiver states it is shown. Until the filter
has an estimate it flies the helix; it then flies exactly what ``AASL-Greedy-v0`` does with a zero
action.
"""

from __future__ import annotations

import numpy as np

from aasl_gym.config import EnvConfig
from aasl_gym.env import OBSERVATION_SLICES
from aasl_gym.planning import GreedyPlanner

from agents.scripted import PatrolPolicy


class GreedyInformationPolicy:
    """``predict(obs)`` like an SB3 model; one instance per env (it keeps that episode's information)."""

    def __init__(self, config: EnvConfig, horizon: float = 3.0):
        self.config = config
        self.planner = GreedyPlanner(config, horizon)
        self.fallback = PatrolPolicy("helix", config)
        self.last_time = np.inf

    def _read(self, obs: np.ndarray) -> dict[str, np.ndarray | float | bool]:
        cfg, s = self.config, OBSERVATION_SLICES
        receiver = obs[s["receiver_position"]] * cfg.world.region_radius
        return {
            "time": float(obs[s["time"]][0]) * cfg.episode.duration,
            "initialized": bool(obs[s["initialized"]][0] > 0.5),
            "receiver": receiver,
            "receiver_velocity": obs[s["receiver_velocity"]] * cfg.receiver.max_speed,
            "estimate": obs[s["relative_estimate"]] * cfg.world.region_radius + receiver,
            "estimate_velocity": obs[s["estimate_velocity"]] * cfg.source.max_speed,
        }

    def _action(self, obs: np.ndarray) -> np.ndarray:
        seen = self._read(np.asarray(obs, dtype=float))
        if seen["time"] < self.last_time:  # a new episode
            self.planner.reset()
        elif seen["time"] > self.last_time:  # the env measured once more since the last call
            self.planner.observe(seen["initialized"], seen["estimate"], seen["estimate_velocity"], seen["receiver"], seen["receiver_velocity"])
        self.last_time = seen["time"]
        if not seen["initialized"]:
            return self.fallback.predict(obs)[0]
        command = self.planner.command(seen["estimate"], seen["estimate_velocity"], seen["receiver"])
        return (command / self.config.receiver.max_speed).astype(np.float32)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        observation = np.asarray(observation)
        if observation.ndim != 1:
            raise ValueError("GreedyInformationPolicy keeps one episode's information: give it one env's observation")
        return self._action(observation), state
