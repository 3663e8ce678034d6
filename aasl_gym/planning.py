"""Information-greedy planning: which velocity command gathers the most information about the source.

:class:`GreedyPlanner` scores a set of candidate commands (the 26 directions of a 3x3x3 grid at full
speed, and standing still) by the position information the robot would hold after flying each one for
``horizon`` seconds, evaluated at the current *estimate* (no ground truth): the extended-Kalman
covariance recursion of :mod:`aasl_gym.fisher` on [p, v, b_p, b_v] with the constant-velocity model,
the measurement Jacobian at the estimate moving on its estimated velocity, and the noise a frame there
would have (:func:`aasl_gym.measurement_models.expected_noise_covariance`). Commands whose straight path
would leave the robot's region or enter the keep-out sphere are not taken while any other is open.

It looks one decision ahead (SPEC section 6) but holds each command for ``horizon`` seconds rather
than one 0.2 s step, whose information differs too little between commands near a receding source: on
seeds 5000-5005 (free field, signal mode) ``horizon=0.2`` converged on 6/6 static sources (mean 10.1 s)
but 5/6 CV sources (one after 117 s); ``horizon=3`` on 6/6 and 6/6 (10.3 s and 10.1 s).

Used by the ``greedy`` policy (``agents/greedy.py``, from observations alone) and by ``AASL-Greedy-v0``
(from the env's estimate; the action is a residual on the planner's command); both fly the same path.
"""

from __future__ import annotations

import itertools

import numpy as np

from aasl_gym import kernels
from aasl_gym.config import EnvConfig
from aasl_gym.filters import ConstantVelocity
from aasl_gym.fisher import InformationTracker, information_prior, measurement_jacobian
from aasl_gym.measurement_models import expected_noise_covariance
from aasl_gym.motion import receiver_region


def candidate_directions(surface: bool) -> np.ndarray:
    """Unit commands of the 3x3x3 grid (horizontal ones only for a surface vessel) and the zero command."""
    grid = [d for d in itertools.product((-1.0, 0.0, 1.0), repeat=3) if any(d) and not (surface and d[2])]
    directions = np.array(grid)
    return np.vstack([directions / np.linalg.norm(directions, axis=1, keepdims=True), np.zeros(3)])


class GreedyPlanner:
    """Scores and picks velocity commands (m/s) for envs built from ``config``.

    It carries the information it plans from: :meth:`reset` at an episode's start, :meth:`observe`
    after every measurement, with the R a frame at the estimate would have - the same R its look-ahead
    assumes. (Carried with the frames' *measured* R instead, as the env's own ``fim_logdet`` is, the
    planner mixed two scales; on seeds 5000-5005 it then took 62-92 s on 3 of 12 sources that it
    otherwise localized in 7-9 s.)
    """

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
        self.process_noise = ConstantVelocity(config.filter).process_noise(self.dt)
        self.prior_mean, self.prior_covariance = information_prior(config)
        self.information = InformationTracker(self.process_noise)
        self.reset()

    def reset(self) -> None:
        """A new episode: back to the prior."""
        self.information.reset(self.prior_covariance)

    def observe(self, initialized: bool, estimate, estimate_velocity, receiver, receiver_velocity) -> None:
        """Add one measurement's information, linearized at the estimate (at the prior's mean before the
        filter starts), the robot at its reported ``receiver`` position and velocity."""
        point = np.concatenate([estimate, estimate_velocity]) if initialized else self.prior_mean[:6]
        jacobian = measurement_jacobian(point[:3], point[3:], receiver, receiver_velocity, self.fixed)
        self.information.step(self.dt, jacobian, expected_noise_covariance(self.config, point[:3], receiver))

    def scores(
        self, covariance: np.ndarray, estimate: np.ndarray, estimate_velocity: np.ndarray, receiver: np.ndarray
    ) -> np.ndarray:
        """Position information (log det, nats) after flying each command for the horizon, starting from
        the information ``covariance`` (8x8) about the source at ``estimate`` moving at ``estimate_velocity``
        with the robot at ``receiver``; -inf where the straight path leaves the region or enters the
        keep-out sphere (unless every path does)."""
        lags = self.dt * np.arange(1, self.steps + 1)  # (S,)
        paths = receiver + self.commands[:, None, :] * lags[None, :, None]  # (C, S, 3)
        if self.surface_depth is not None:
            paths[..., 2] = -self.surface_depth
        source = estimate + estimate_velocity * lags[:, None]  # (S, 3)
        jacobians = measurement_jacobian(
            source[None], estimate_velocity, paths, self.commands[:, None], self.fixed
        )  # (C, S, 2, 8)
        noises = expected_noise_covariance(self.config, source[None], paths)  # (C, S, 2, 2)
        # Compiled: as NumPy's stacked 8 x 8 products and solves, a third of a greedy env step.
        score = kernels.horizon_information(covariance, self.dt, self.process_noise, jacobians, noises)
        region = self.region
        inside = (
            (np.hypot(paths[..., 0], paths[..., 1]) <= region.radius).all(axis=1)
            & (paths[..., 2] >= region.z_min).all(axis=1)
            & (paths[..., 2] <= region.z_max).all(axis=1)
            & (np.linalg.norm(paths - self.fixed, axis=-1) >= self.config.receiver.keep_out_radius).all(axis=1)
        )
        return np.where(inside, score, -np.inf) if inside.any() else score

    def command(self, estimate, estimate_velocity, receiver) -> np.ndarray:
        """The best-scored command (m/s) from the information observed so far."""
        return self.commands[
            int(np.argmax(self.scores(self.information.covariance, estimate, estimate_velocity, receiver)))
        ]
