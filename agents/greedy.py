"""The information-greedy planner as a policy: the strong non-learned baseline.

Each step it flies the command :class:`aasl_gym.planning.GreedyPlanner` picks (the one of 27 whose next
3 s would add the most position information at the current estimate). It reads only the observation
(see ``aasl_gym.env.OBSERVATION_LAYOUT``), so it runs on ``AASL-v0`` in any vector env: it keeps its
own copy of the env's information recursion (``aasl_gym.fisher``) from the estimates and reported
receiver states it is shown, with the noise a frame there would have. Until the filter has an
estimate it flies the helix.
"""

from __future__ import annotations

import numpy as np

from aasl_gym.config import EnvConfig
from aasl_gym.env import OBSERVATION_SLICES
from aasl_gym.fisher import InformationTracker, information_prior, measurement_jacobian
from aasl_gym.measurements import expected_noise_covariance
from aasl_gym.planning import GreedyPlanner

from agents.scripted import PatrolPolicy


class GreedyInformationPolicy:
    """``predict(obs)`` like an SB3 model; one instance per env (it keeps that episode's information)."""

    def __init__(self, config: EnvConfig, horizon: float = 3.0):
        self.config = config
        self.planner = GreedyPlanner(config, horizon)
        self.prior_mean, self.prior_covariance = information_prior(config)
        self.information = InformationTracker(self.planner.process_noise)
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

    def _track(self, seen: dict) -> None:
        """Add the latest measurement's information (what the env's own tracker did this step)."""
        if seen["time"] < self.last_time:  # a new episode
            self.information.reset(self.prior_covariance)
        elif seen["time"] > self.last_time:
            point = np.concatenate([seen["estimate"], seen["estimate_velocity"]]) if seen["initialized"] else self.prior_mean[:6]
            jacobian = measurement_jacobian(point[:3], point[3:], seen["receiver"], seen["receiver_velocity"], self.planner.fixed)
            self.information.step(self.planner.dt, jacobian, expected_noise_covariance(self.config, point[:3], seen["receiver"]))
        self.last_time = seen["time"]

    def _action(self, obs: np.ndarray) -> np.ndarray:
        seen = self._read(np.asarray(obs, dtype=float))
        self._track(seen)
        if not seen["initialized"]:
            return self.fallback.predict(obs)[0]
        command = self.planner.command(self.information.covariance, seen["estimate"], seen["estimate_velocity"], seen["receiver"])
        return (command / self.config.receiver.max_speed).astype(np.float32)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        observation = np.asarray(observation)
        if observation.ndim != 1:
            raise ValueError("GreedyInformationPolicy keeps one episode's information: give it one env's observation")
        return self._action(observation), state
