"""The information-greedy planner: the strong non-learned baseline.

Every step it scores a set of candidate velocity commands (the 26 directions of a 3x3x3 grid at full
speed, and standing still) by the Fisher information about the source's position that the robot would
gather flying each one for ``horizon`` seconds, evaluated at the current *estimate* (no ground truth),
and takes the best. The information is carried like the env's own (``aasl_gym.fisher``): an
extended-Kalman covariance recursion on [p, v, b_p, b_v] with the constant-velocity model, from the
same prior, with the measurement Jacobian at the estimate and the noise a frame there would have
(:func:`aasl_gym.measurements.expected_noise_covariance`). Candidates whose straight path would leave
the robot's region or enter the keep-out sphere are not taken while any other is open.

It reads only the observation (see ``aasl_gym.env.OBSERVATION_LAYOUT``), so it runs on ``AASL-v0`` in
any vector env; until the filter has an estimate it flies the helix.

It looks one decision ahead (SPEC section 6), but scores each command held for ``horizon`` seconds
rather than for one 0.2 s step, whose information differs too little between commands near a
receding source: on seeds 5000-5005 (free field, signal mode) ``horizon=0.2`` converged on 6/6 static
sources (mean 10.1 s) but 5/6 CV sources (one after 117 s); ``horizon=3`` on 6/6 and 6/6 (10.3 s and
10.1 s).
"""

from __future__ import annotations

import itertools

import numpy as np

from aasl_gym.config import EnvConfig
from aasl_gym.env import OBSERVATION_SLICES
from aasl_gym.filters import ConstantVelocity
from aasl_gym.fisher import InformationTracker, cv_transition_matrix, information_prior, measurement_jacobian, position_information_logdet, updated_covariance
from aasl_gym.measurements import expected_noise_covariance
from aasl_gym.motion import receiver_region

from agents.scripted import PatrolPolicy


def candidate_directions(surface: bool) -> np.ndarray:
    """Unit commands of the 3x3x3 grid (horizontal ones only for a surface vessel) and the zero command."""
    grid = [d for d in itertools.product((-1.0, 0.0, 1.0), repeat=3) if any(d) and not (surface and d[2])]
    directions = np.array(grid)
    return np.vstack([directions / np.linalg.norm(directions, axis=1, keepdims=True), np.zeros(3)])


class GreedyInformationPolicy:
    """``predict(obs)`` like an SB3 model; one instance per env (it keeps that episode's information)."""

    def __init__(self, config: EnvConfig, horizon: float = 3.0):
        if not horizon > 0:
            raise ValueError(f"horizon must be > 0 s, got {horizon!r}")
        self.config = config
        self.dt = config.dt
        self.steps = max(1, int(round(horizon / self.dt)))
        self.surface_depth = config.receiver.surface_depth if config.receiver.kind == "surface" else None
        self.commands = config.receiver.max_speed * candidate_directions(self.surface_depth is not None)
        self.region = receiver_region(config.world, config.receiver)
        self.fixed = np.asarray(config.world.fixed_position, dtype=float)
        self.prior_mean, self.prior_covariance = information_prior(config)
        self.transition = cv_transition_matrix(self.dt)
        self.process_noise = ConstantVelocity(config.filter).process_noise(self.dt)
        self.information = InformationTracker(self.process_noise)
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
            jacobian = measurement_jacobian(point[:3], point[3:], seen["receiver"], seen["receiver_velocity"], self.fixed)
            self.information.step(self.dt, jacobian, expected_noise_covariance(self.config, point[:3], seen["receiver"]))
        self.last_time = seen["time"]

    def scores(self, seen: dict) -> np.ndarray:
        """Position information (log det, nats) after flying each command for the horizon; -inf where
        the straight path leaves the region or enters the keep-out sphere."""
        lags = self.dt * np.arange(1, self.steps + 1)  # (S,)
        paths = seen["receiver"] + self.commands[:, None, :] * lags[None, :, None]  # (C, S, 3)
        if self.surface_depth is not None:
            paths[..., 2] = -self.surface_depth
        source = seen["estimate"] + seen["estimate_velocity"] * lags[:, None]  # (S, 3)
        jacobians = measurement_jacobian(source[None], seen["estimate_velocity"], paths, self.commands[:, None], self.fixed)  # (C, S, 2, 8)
        noises = expected_noise_covariance(self.config, source[None], paths)  # (C, S, 2, 2)
        covariance = np.broadcast_to(self.information.covariance, (len(self.commands), 8, 8))
        for k in range(self.steps):
            predicted = self.transition @ covariance @ self.transition.T + self.process_noise
            covariance = updated_covariance(predicted, jacobians[:, k], noises[:, k])
        score = position_information_logdet(covariance)
        region = self.region
        inside = (
            (np.hypot(paths[..., 0], paths[..., 1]) <= region.radius).all(axis=1)
            & (paths[..., 2] >= region.z_min).all(axis=1) & (paths[..., 2] <= region.z_max).all(axis=1)
            & (np.linalg.norm(paths - self.fixed, axis=-1) >= self.config.receiver.keep_out_radius).all(axis=1)
        )
        return np.where(inside, score, -np.inf) if inside.any() else score

    def _action(self, obs: np.ndarray) -> np.ndarray:
        seen = self._read(np.asarray(obs, dtype=float))
        self._track(seen)
        if not seen["initialized"]:
            return self.fallback.predict(obs)[0]
        best = int(np.argmax(self.scores(seen)))
        return (self.commands[best] / self.config.receiver.max_speed).astype(np.float32)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        observation = np.asarray(observation)
        if observation.ndim != 1:
            raise ValueError("GreedyInformationPolicy keeps one episode's information: give it one env's observation")
        return self._action(observation), state
