"""The information-greedy planner as a policy: the strong non-learned baseline.

Each step it flies the command :class:`aasl_gym.planning.GreedyPlanner` picks (the one of 27 whose next
3 s would add the most position information at the current estimate). It reads only the observation
(decoded by :func:`aasl_gym.observation.decode_observation`), so it runs on ``AASL-v0`` in any vector
env: the planner carries its information from the estimates and reported receiver states it is shown.
Until the filter has an estimate it flies the helix; it then flies exactly what ``AASL-Greedy-v0``
does with a zero action.
"""

from __future__ import annotations

import numpy as np

from aasl_gym.config import EnvConfig
from aasl_gym.observation import decode_observation
from aasl_gym.patrols import PatrolGeometry, patrol_command
from aasl_gym.planning import GreedyPlanner


class GreedyInformationPolicy:
    """``predict(obs)`` like an SB3 model; one instance per env (it keeps that episode's information)."""

    def __init__(self, config: EnvConfig, horizon: float = 3.0):
        self.config = config
        self.planner = GreedyPlanner(config, horizon)
        self.patrol_geometry = PatrolGeometry.from_config(config)
        self.last_time = np.inf

    def _action(self, obs: np.ndarray) -> np.ndarray:
        seen = decode_observation(obs, self.config)
        if seen.time < self.last_time:  # a new episode
            self.planner.reset()
        elif seen.time > self.last_time:  # the env measured once more since the last call
            self.planner.observe(
                seen.initialized,
                seen.estimate_position,
                seen.estimate_velocity,
                seen.receiver_position,
                seen.receiver_velocity,
            )
        self.last_time = seen.time
        if seen.initialized:
            command = self.planner.command(seen.estimate_position, seen.estimate_velocity, seen.receiver_position)
        else:  # the helix, as AASL-Greedy-v0 flies before the filter starts
            command = patrol_command(
                "helix", seen.time, seen.receiver_position, self.config.patrol, self.patrol_geometry
            )
        return (command / self.config.receiver.max_speed).astype(np.float32)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        observation = np.asarray(observation)
        if observation.ndim != 1:
            raise ValueError("GreedyInformationPolicy keeps one episode's information: give it one env's observation")
        return self._action(observation), state
