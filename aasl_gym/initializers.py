"""Initializers: start the filter from a short burst of measurements (SPEC section 4).

All share one interface: ``initializer(burst, rng) -> InitialEstimate``, the estimate of the base state
[p, v, b_p, b_v] and its covariance at the *last* time of the burst. Choose one by name with
:func:`make_initializer`: ``lcmap`` (locus-constrained MAP, the reference paper's contribution),
``naive``, ``random`` and ``tdoa-ls``.

LC-MAP in short. The first RD of the burst, minus a whole number of wavelengths, puts the source on one
sheet of a hyperboloid whose foci are the two hydrophones; |RD| can never exceed the baseline, so only a
few offsets are feasible. Candidates are drawn on every feasible sheet, one per direction of a
Fibonacci lattice seen from the mobile hydrophone (closed form, below). For each candidate the source
velocity follows from a regularized (MAP) Gauss-Newton solve on the burst - the RRD is linear in v_s -
and the candidate is scored by the burst's chi-square J minus ``lambda * log det F``, F the burst's
Fisher information at the candidate (with lambda = 1 this is the MAP under a Jeffreys prior).
Implausible candidates (outside the water column or the surveillance region, too fast) are dropped.
The grid stage scores on at most ``grid_samples`` of the burst (a long window at 1 Hz is plenty to
find basins); the best grid candidates (overall and on every sheet) are then refined by Gauss-Newton
on (p, v) over at most ``refine_samples`` of it and scored again on the whole burst. A 2 s burst rarely
tells the sheets apart, so LC-MAP returns up to ``config.hypotheses`` distinct candidates - the best of
every sheet first, then the next best - each with the inverse of its F (times ``covariance_inflation``)
as covariance and its burst likelihood exp(-J / 2) as relative weight; the tracker runs one UKF per
hypothesis (``hypotheses: 1`` is the paper's single filter).

LC-MAP fits the trajectory the filter's motion model allows. With ``cv`` (the default) it is a
straight line. With ``ctrv`` every candidate position is tried at each turn rate of a small grid
(``initializer.turn_rate_steps`` values over +-``max_turn_rate``) and the refinement fits the rate; with
``ca`` the refinement fits a constant acceleration (prior sd ``acceleration_prior_sd``). Over the tens of
seconds a re-seed window spans, a straight-line fit of a turning or accelerating source finds the wrong
basin. For a fixed turn rate or acceleration the trajectory is still affine in (p, v), so the velocity
solve and the refinement are the same Gauss-Newton steps.

Locus in closed form: with a = p_m - p_f and a candidate p = p_m + r u (u a unit vector),
|p - p_f| = r - RD gives r = (RD^2 - |a|^2) / (2 (a . u + RD)), valid where r > 0.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from aasl_gym import geometry, kernels
from aasl_gym.config import InitializerConfig
from aasl_gym.measurement_models import direct_measurement, receiver_jacobian, receiver_noise
from aasl_gym.motion import Box, coordinated_turn_displacement

logger = logging.getLogger(__name__)

MeasurementFunction = Callable[..., np.ndarray]  # (p, v, p_m, v_m, p_f) -> (..., 2) [RD, RRD] without biases


@dataclass(frozen=True)
class Burst:
    """The measurements an initializer sees (receiver states are the *reported* ones)."""

    times: np.ndarray  # (K,) s
    measurements: np.ndarray  # (K, 2) [RD, RRD], m and m/s
    receiver_positions: np.ndarray  # (K, 3) m
    receiver_velocities: np.ndarray  # (K, 3) m/s
    fixed_position: np.ndarray  # (3,) m
    noise_covariance: np.ndarray  # (2, 2) acoustic R (R_ac)
    wavelength: float | None  # m; None when the RD is unambiguous
    measurement_function: MeasurementFunction
    residual_period: float | None = None  # m: RD residuals are taken modulo this (the phasor model's wavelength)
    navigation_sd: tuple[float, float] = (0.0, 0.0)  # m, m/s: white error of the reported receiver state
    robust: bool = False  # soft-L1 loss: for data the model explains only roughly (multipath taken as noise)

    @property
    def uniform_covariance(self) -> np.ndarray:
        """R_ac plus the direct path's navigation term diag(sigma_p^2, sigma_v^2): one R for every sample
        and candidate, cheap, for finding basins (the multipath model's own term varies on a wavelength)."""
        return self.noise_covariance + np.diag(np.square(self.navigation_sd))


@dataclass(frozen=True)
class InitialEstimate:
    """Hypotheses about the base state [p, v, b_p, b_v] at ``burst.times[-1]``, the initializer's pick first.

    Each row is a Gaussian (state, covariance) that starts one UKF; ``log_weights`` are their log
    likelihoods on the burst relative to the likeliest (so at most 0). The simple initializers return
    one hypothesis.
    """

    states: np.ndarray  # (H, 8)
    covariances: np.ndarray  # (H, 8, 8)
    log_weights: np.ndarray  # (H,)
    candidates: int = 1  # how many plausible candidates were scored
    turn_rates: np.ndarray | None = None  # (H,) rad/s, the turn each hypothesis was fitted with (None: straight)
    accelerations: np.ndarray | None = None  # (H, 3) m/s^2, the acceleration each was fitted with (None: none)

    @classmethod
    def single(cls, state: np.ndarray, covariance: np.ndarray, candidates: int = 1) -> InitialEstimate:
        return cls(state[None], covariance[None], np.zeros(1), candidates)

    @property
    def state(self) -> np.ndarray:
        return self.states[0]

    @property
    def covariance(self) -> np.ndarray:
        return self.covariances[0]


class Initializer(Protocol):
    def __call__(self, burst: Burst, rng: np.random.Generator) -> InitialEstimate: ...


def fibonacci_directions(count: int) -> np.ndarray:
    """Nearly uniform unit vectors on the sphere (golden-angle lattice), shape (count, 3)."""
    index = np.arange(count) + 0.5
    z = 1 - 2 * index / count
    azimuth = np.pi * (1 + 5**0.5) * index
    radial = np.sqrt(1 - z**2)
    return np.stack([radial * np.cos(azimuth), radial * np.sin(azimuth), z], axis=-1)


def feasible_offsets(first_rd: float, baseline: float | np.floating, wavelength: float | None) -> np.ndarray:
    """Whole-period biases b_p = k * wavelength with |first_rd - b_p| <= baseline (m); none when the baseline
    is under half a wavelength and the measured RD (noise, or a reported receiver position off by more than
    the baseline's slack) lies beyond it from every multiple of the wavelength."""
    if wavelength is None:
        return np.zeros(1)
    k = np.arange(np.ceil((first_rd - baseline) / wavelength), np.floor((first_rd + baseline) / wavelength) + 1)
    return k * wavelength


def locus_points(mobile: np.ndarray, fixed: np.ndarray, range_difference: float, directions: np.ndarray) -> np.ndarray:
    """Points p = p_m + r u with |p - p_m| - |p - p_f| = range_difference; rows where no such r > 0 are NaN."""
    a = mobile - fixed
    denominator = 2 * (directions @ a + range_difference)
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = (range_difference**2 - a @ a) / denominator
    distance = np.where((denominator < 0) & np.isfinite(distance), distance, np.nan)
    return mobile + distance[:, None] * directions


class CandidateMotion:
    """How each candidate's trajectory over a window follows from its position p and velocity v at the
    window's first sample: straight, turning horizontally at a fixed rate omega, or at a fixed acceleration a.

    p(tau) = p + A(tau) v + a tau^2 / 2 and v(tau) = B(tau) v + a tau, affine in (p, v), with
    A = [[s, -c, 0], [c, s, 0], [0, 0, tau]], B = [[cos, -sin, 0], [sin, cos, 0], [0, 0, 1]],
    s = sin(omega tau) / omega and c = (1 - cos(omega tau)) / omega; omega = 0 is a straight line
    (s = tau, c = 0, B = I). Arrays are (C, K): candidate by sample.
    """

    def __init__(self, tau: np.ndarray, turn_rates: np.ndarray, accelerations: np.ndarray | None = None):
        shape = (len(turn_rates), len(tau))
        self.tau = tau
        self.accelerations = accelerations  # (C, 3) m/s^2, or None
        self.straight = not np.any(turn_rates)  # the common case, with a shortcut: it is most of the cost
        if self.straight:
            self.s, self.c = np.broadcast_to(tau, shape), np.zeros(shape)
            self.cos, self.sin = np.ones(shape), np.zeros(shape)
            return
        east = np.broadcast_to([1.0, 0.0, 0.0], shape + (3,))
        displacement, velocity = coordinated_turn_displacement(east, np.asarray(turn_rates)[:, None], tau[None, :])
        self.s, self.c = displacement[..., 0], displacement[..., 1]
        self.cos, self.sin = velocity[..., 0], velocity[..., 1]

    def trajectory(self, positions: np.ndarray, velocities: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (C, K, 3) and velocities (C, K, 3) from p, v (C, 3) at the first sample."""
        if self.straight:
            trajectory, velocity = (
                positions[:, None, :] + velocities[:, None, :] * self.tau[None, :, None],
                velocities[:, None, :],
            )
        else:
            vx, vy, vz = (velocities[:, i, None] for i in range(3))
            displacement = np.stack([self.s * vx - self.c * vy, self.c * vx + self.s * vy, vz * self.tau], axis=-1)
            velocity = np.stack(
                [self.cos * vx - self.sin * vy, self.sin * vx + self.cos * vy, np.broadcast_to(vz, self.s.shape)],
                axis=-1,
            )
            trajectory = positions[:, None, :] + displacement
        if self.accelerations is not None:
            a, tau = self.accelerations[:, None, :], self.tau[None, :, None]
            trajectory, velocity = trajectory + 0.5 * a * tau**2, velocity + a * tau
        return trajectory, velocity

    def chain(self, local: np.ndarray, with_acceleration: bool = False, overwrite: bool = False) -> np.ndarray:
        """d z / d[p, v] (and d[a], with ``with_acceleration``) at the first sample from the local
        Jacobian d z / d[p(tau), v(tau)] (C, K, 2, 6): (C, K, 2, 6 or 9). ``overwrite``: ``local`` may
        be changed in place (a straight line's chain then needs no copy)."""
        jac_p, jac_v = local[..., 0:3], local[..., 3:6]
        tau = self.tau[:, None, None]
        if self.straight:
            acceleration_columns = 0.5 * jac_p * tau**2 + jac_v * tau if with_acceleration else None
            out = local if overwrite else local.copy()
            out[..., 3:6] += jac_p * tau
            if with_acceleration:
                return np.concatenate([out, acceleration_columns], axis=-1)
        else:
            s, c, cos, sin = (a[..., None] for a in (self.s, self.c, self.cos, self.sin))
            out = np.empty_like(local)
            out[..., 0:3] = jac_p
            out[..., 3] = jac_p[..., 0] * s + jac_p[..., 1] * c + jac_v[..., 0] * cos + jac_v[..., 1] * sin
            out[..., 4] = -jac_p[..., 0] * c + jac_p[..., 1] * s - jac_v[..., 0] * sin + jac_v[..., 1] * cos
            out[..., 5] = jac_p[..., 2] * self.tau[:, None] + jac_v[..., 2]
        if with_acceleration:
            out = np.concatenate([out, 0.5 * jac_p * tau**2 + jac_v * tau], axis=-1)
        return out

    def propagate(self, states: np.ndarray, covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Base states (C, 8) and covariances (C, 8, 8) carried to the last sample (the acceleration,
        if any, taken as known)."""

        def rotation_like(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # [[a, -b], [b, a]], (C, 2, 2)
            return np.stack([np.stack([a, -b], -1), np.stack([b, a], -1)], -2)

        f = np.tile(np.eye(8), (len(states), 1, 1))
        f[:, 0:2, 3:5] = rotation_like(self.s[:, -1], self.c[:, -1])
        f[:, 2, 5] = self.tau[-1]
        f[:, 3:5, 3:5] = rotation_like(self.cos[:, -1], self.sin[:, -1])
        moved = (f @ states[..., None])[..., 0]
        if self.accelerations is not None:
            moved[:, 0:3] += 0.5 * self.accelerations * self.tau[-1] ** 2
            moved[:, 3:6] += self.accelerations * self.tau[-1]
        return moved, f @ covariances @ f.transpose(0, 2, 1)


def _uninformed_bias_sd(burst: Burst) -> float:
    baseline = np.linalg.norm(burst.receiver_positions[0] - burst.fixed_position)
    return max(baseline, burst.wavelength or 0.0) / np.sqrt(3.0)


class _BroadPrior:
    """Shared by the simple initializers: a broad diagonal covariance around their guess."""

    def __init__(self, config: InitializerConfig):
        self.config = config

    def estimate(self, burst: Burst, position: np.ndarray, range_bias: float, bias_sd: float) -> InitialEstimate:
        c = self.config
        state = np.concatenate([position, np.zeros(3), [range_bias, 0.0]])
        covariance = np.diag([c.position_sd**2] * 3 + [c.velocity_prior_sd**2] * 3 + [bias_sd**2, c.rate_bias_sd**2])
        return InitialEstimate.single(state, covariance)


class NaiveInitializer(_BroadPrior):
    """Midpoint of the two hydrophones, zero velocity, no knowledge of the whole-period offset."""

    def __call__(self, burst: Burst, rng: np.random.Generator) -> InitialEstimate:
        midpoint = 0.5 * (burst.receiver_positions[-1] + burst.fixed_position)
        return self.estimate(burst, midpoint, 0.0, _uninformed_bias_sd(burst))


class TdoaLeastSquaresInitializer(_BroadPrior):
    """Gauss-Newton (minimum-norm steps) on the last RD alone, from a generic point half
    ``initializer.position_sd`` from the pod towards the middle of ``region``'s depths (below a pod near
    the surface, above one on the bed)."""

    iterations = 20

    def __init__(self, config: InitializerConfig, region: Box):
        super().__init__(config)
        self.region = region

    def __call__(self, burst: Burst, rng: np.random.Generator) -> InitialEstimate:
        mobile, fixed = burst.receiver_positions[-1], burst.fixed_position
        target = burst.measurements[-1, 0]
        step = self.region.towards_middle(fixed[2]) * 0.5 * self.config.position_sd
        position = fixed + np.array([0.0, 0.0, step])
        for _ in range(self.iterations):
            gradient = geometry.ranges(position, mobile)[1] - geometry.ranges(position, fixed)[1]
            norm2 = gradient @ gradient
            if norm2 < 1e-9:
                break
            position = position + gradient * (target - geometry.range_difference(position, mobile, fixed)) / norm2
        return self.estimate(burst, position, 0.0, _uninformed_bias_sd(burst))


def subsample(burst: Burst, samples: int) -> Burst:
    """At most ``samples`` of the burst, evenly spaced and ending on its last sample (where the states are)."""
    count = len(burst.times)
    if count <= samples:
        return burst
    return select_samples(burst, np.round(np.linspace(count - 1, 0, samples))[::-1].astype(int))


def select_samples(burst: Burst, index: np.ndarray | slice) -> Burst:
    """The burst's samples at ``index`` (an index array or a slice), with its noise and model."""
    per_sample = ("times", "measurements", "receiver_positions", "receiver_velocities")
    return replace(burst, **{name: getattr(burst, name)[index] for name in per_sample})


def recent_samples(burst: Burst, seconds: float) -> Burst:
    """The burst's samples taken within ``seconds`` (s) of its last one (all of them for ``np.inf``)."""
    return select_samples(burst, np.abs(burst.times - burst.times[-1]) <= seconds + 1e-9)


def periodic_residual(residual: np.ndarray, burst: Burst) -> np.ndarray:
    """RD residuals (..., 2) modulo the burst's ``residual_period``, if it has one (in place)."""
    if burst.residual_period is not None:
        residual[..., 0] = geometry.wrap_to_period(residual[..., 0], burst.residual_period)
    return residual


def robust_loss(squared: np.ndarray, robust: bool) -> np.ndarray:
    """The loss of squared whitened residuals: themselves, or (``robust``) soft-L1, 2 (sqrt(1 + r^2) - 1)."""
    return 2 * (np.sqrt(1 + squared) - 1) if robust else squared


def robust_weights(residual: np.ndarray, robust: bool) -> np.ndarray:
    """Iteratively reweighted least squares weights of whitened residuals: 1 / sqrt(1 + r^2), or ones."""
    return 1 / np.sqrt(1 + residual**2) if robust else np.ones_like(residual)


def whitener(burst: Burst) -> np.ndarray:
    """W (2, 2) with W^T W = R^-1 for the burst's uniform R: whitened residuals W r have unit covariance."""
    return np.linalg.cholesky(np.linalg.inv(burst.uniform_covariance)).T


def inverse_cholesky(covariance: np.ndarray) -> np.ndarray:
    """W = L^-1 (..., 2, 2) for R = L L^T, so W^T W = R^-1; closed form for 2 x 2, batched."""
    a = np.sqrt(covariance[..., 0, 0])
    b = covariance[..., 1, 0] / a
    c = np.sqrt(covariance[..., 1, 1] - b**2)
    white = np.zeros(covariance.shape)
    white[..., 0, 0], white[..., 1, 0], white[..., 1, 1] = 1 / a, -b / (a * c), 1 / c
    return white


def trajectory_whitener(burst: Burst, trajectory: np.ndarray, trajectory_velocity: np.ndarray) -> np.ndarray:
    """W (C, K, 2, 2) for R_eff = R_ac + H_r Sigma_r H_r^T of every candidate at every sample, H_r the
    burst model's own receiver Jacobian along the candidate's trajectory (C, K, 3)."""
    receivers = burst.receiver_positions[None], burst.receiver_velocities[None]
    jacobian = receiver_jacobian(
        burst.measurement_function, trajectory, trajectory_velocity, *receivers, burst.fixed_position
    )
    return inverse_cholesky(burst.noise_covariance + receiver_noise(jacobian, *burst.navigation_sd))


def whiten(white: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """W r for residuals (..., 2) and one W (2, 2) or one per residual (..., 2, 2)."""
    if white.ndim == 2:
        return residual @ white.T
    return np.einsum("...ij,...j->...i", white, residual)


def _normal_equations(jacobian: np.ndarray, residual: np.ndarray, white: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J^T R^-1 J (C, n, n) and J^T R^-1 r (C, n) summed over the burst, as batched matrix products.

    ``jacobian`` is (C, K, 2, n), ``residual`` the *whitened* residual (C, K, 2), ``white`` from :func:`whitener`.
    """
    count, samples, _, n = jacobian.shape
    whitened = np.matmul(white, jacobian).reshape(count, 2 * samples, n)
    transposed = whitened.transpose(0, 2, 1)
    return transposed @ whitened, (transposed @ residual.reshape(count, 2 * samples, 1))[..., 0]


def _predicted(burst: Burst, positions: np.ndarray, velocities: np.ndarray, motion: CandidateMotion) -> np.ndarray:
    """[RD, RRD] without biases along each candidate's trajectory: (C, K, 2)."""
    trajectory, trajectory_velocity = motion.trajectory(positions, velocities)
    return burst.measurement_function(
        trajectory,
        trajectory_velocity,
        burst.receiver_positions[None],
        burst.receiver_velocities[None],
        burst.fixed_position,
    )


def _burst_chi_square(
    burst: Burst,
    positions: np.ndarray,
    velocities: np.ndarray,
    biases: np.ndarray,
    motion: CandidateMotion | None = None,
    per_sample: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Chi-square of the burst for candidate trajectories from p, v at its first time, moving as
    ``motion`` says (straight without): (C,), the whitened residuals (C, K, 2) and the whitener used:
    the burst's uniform one, or with ``per_sample`` each candidate's own R_eff at every sample.

    A ``robust`` burst sums the soft-L1 loss 2 (sqrt(1 + r^2) - 1) instead of r^2, and returns the
    residuals and whiteners scaled by the square roots of its weights 1 / sqrt(1 + r^2), so that the
    Gauss-Newton steps built from them are iteratively reweighted least squares."""
    if motion is None:
        motion = CandidateMotion(burst.times - burst.times[0], np.zeros(len(positions)))
    trajectory, trajectory_velocity = motion.trajectory(positions, velocities)
    mobile, mobile_velocity = burst.receiver_positions[None], burst.receiver_velocities[None]
    residual = burst.measurements[None] - burst.measurement_function(
        trajectory, trajectory_velocity, mobile, mobile_velocity, burst.fixed_position
    )
    residual[..., 0] -= biases[:, None]
    residual = periodic_residual(residual, burst)
    white = trajectory_whitener(burst, trajectory, trajectory_velocity) if per_sample else whitener(burst)
    whitened = whiten(white, residual)
    if not burst.robust:
        return np.sum(whitened**2, axis=(1, 2)), whitened, white
    root_weight = (1 + whitened**2) ** -0.25
    cost = np.sum(robust_loss(whitened**2, True), axis=(1, 2))
    return cost, root_weight * whitened, root_weight[..., None] * np.broadcast_to(white, whitened.shape + (2,))


class RandomInitializer(_BroadPrior):
    """Random points on the first RD's locus (every feasible sheet), zero velocity; keep the best fit."""

    def __call__(self, burst: Burst, rng: np.random.Generator) -> InitialEstimate:
        mobile, fixed = burst.receiver_positions[0], burst.fixed_position
        baseline = np.linalg.norm(mobile - fixed)
        offsets = feasible_offsets(burst.measurements[0, 0], baseline, burst.wavelength)
        directions = rng.normal(size=(self.config.candidate_directions, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        if not len(offsets):  # see LCMAPInitializer.candidates
            return NaiveInitializer(self.config)(burst, rng)
        points = np.concatenate(
            [locus_points(mobile, fixed, burst.measurements[0, 0] - b, directions) for b in offsets]
        )
        biases = np.repeat(offsets, len(directions))
        keep = np.isfinite(points[:, 0])
        if not keep.any():
            return NaiveInitializer(self.config)(burst, rng)
        points, biases = points[keep], biases[keep]
        chi_square, _, _ = _burst_chi_square(burst, points, np.zeros_like(points), biases)
        best = int(np.argmin(chi_square))
        estimate = self.estimate(burst, points[best], biases[best], self.config.range_bias_sd)
        return InitialEstimate.single(estimate.state, estimate.covariance, candidates=len(points))


class LCMAPInitializer:
    """Locus-constrained MAP (module docstring). ``region`` bounds plausible source positions."""

    velocity_iterations = 2
    refine_iterations = 6
    refine_best = 16  # grid candidates refined overall
    refine_per_sheet = 3  # and on every whole-period sheet
    separation = 2.0  # m: closer candidates on one sheet are one hypothesis
    grid_samples = 20  # burst samples the grid stage uses at most
    refine_samples = 100  # and the refinement (a window fit follows a re-seed's; 20 s at 5 Hz find a basin's bottom)

    def __init__(self, config: InitializerConfig, region: Box, motion: str = "cv"):
        """``motion``: the filter's motion model, which the fit follows - ``cv`` straight lines,
        ``ctrv`` turns (a grid of rates, then fitted), ``ca`` a fitted constant acceleration."""
        self.config = config
        self.region = region
        self.fit_turn, self.fit_acceleration = motion == "ctrv", motion == "ca"
        self.turn_rates = config.turn_rates if self.fit_turn else np.zeros(1)  # rad/s, every candidate is tried at each
        self.directions = fibonacci_directions(config.candidate_directions)

    def candidates(self, burst: Burst) -> tuple[np.ndarray, np.ndarray]:
        """Candidate positions at the burst's first time and their whole-period biases."""
        mobile, fixed = burst.receiver_positions[0], burst.fixed_position
        baseline = np.linalg.norm(mobile - fixed)
        offsets = feasible_offsets(burst.measurements[0, 0], baseline, burst.wavelength)
        if not len(offsets):  # the RD exceeds the reported baseline by more than a period's slack: no locus
            return np.zeros((0, 3)), np.zeros(0)
        points = np.concatenate(
            [locus_points(mobile, fixed, burst.measurements[0, 0] - b, self.directions) for b in offsets]
        )
        biases = np.repeat(offsets, len(self.directions))
        region = self.region
        keep = (
            np.isfinite(points[:, 0])
            & (points[:, 2] >= region.z_min)
            & (points[:, 2] <= region.z_max)
            & (np.hypot(points[:, 0], points[:, 1]) <= region.radius)
        )
        return points[keep], biases[keep]

    @staticmethod
    def _jacobians(
        burst: Burst,
        positions: np.ndarray,
        velocities: np.ndarray,
        motion: CandidateMotion,
        with_acceleration: bool = False,
    ) -> np.ndarray:
        """d[RD, RRD]_k / d[p(t0), v(t0) (, a)] for every candidate and burst sample: (C, K, 2, 6 or 9)."""
        local = LCMAPInitializer._local_jacobians(burst, positions, velocities, motion)
        return motion.chain(local, with_acceleration, overwrite=True)

    @staticmethod
    def _local_jacobians(burst: Burst, positions, velocities, motion: CandidateMotion) -> np.ndarray:
        """d[RD, RRD]_k / d[p(t_k), v(t_k)] along each candidate's trajectory: (C, K, 2, 6)."""
        trajectory, trajectory_velocity = motion.trajectory(positions, velocities)
        # The [p, v] columns of fisher.measurement_jacobian, without copying them into its 8 columns first.
        return geometry.direct_jacobian(
            trajectory,
            trajectory_velocity,
            burst.receiver_positions[None],
            burst.receiver_velocities[None],
            burst.fixed_position,
        )

    def _solve_velocities(
        self, burst: Burst, positions: np.ndarray, biases: np.ndarray, motion: CandidateMotion, copies: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """MAP velocities for fixed positions, and the Jacobians (C, K, 2, 6) of the last linearization.

        ``positions`` and ``biases`` may be ``copies`` copies of one set, one per turn rate of the grid:
        the solve starts from rest, where every copy's trajectory is the same fixed point, so the first
        linearization is made once for all of them (a turning grid's most costly step)."""
        prior = np.eye(3) / self.config.velocity_prior_sd**2
        velocities = np.zeros_like(positions)
        for iteration in range(self.velocity_iterations):
            if iteration == 0 and copies > 1:
                residual, white, jac = self._linearize_at_rest(burst, positions, biases, motion, copies)
            else:
                _, residual, white = _burst_chi_square(burst, positions, velocities, biases, motion)
                jac = self._jacobians(burst, positions, velocities, motion)
            normal, gradient = _normal_equations(jac[..., 3:6], residual, white)
            normal = normal + prior
            gradient = gradient - velocities @ prior
            velocities = velocities + np.linalg.solve(normal, gradient[..., None])[..., 0]
        return velocities, jac

    def _grid(self, burst: Burst, positions, biases, motion: CandidateMotion, copies: int):
        """The grid's MAP velocities (C, 3; m/s) and scores (C,; J - lambda log det F): :meth:`_solve_velocities` then
        :meth:`_score` with its Jacobians, compiled for the direct path (:func:`aasl_gym.kernels.lcmap_grid`, the
        grid's cost: a thousand candidates or more along twenty samples), else in NumPy. ``copies``: see
        :meth:`_solve_velocities`."""
        c = self.config
        assert motion.accelerations is None  # the grid's candidates move straight or turn; CA fits its own later
        if burst.measurement_function is not direct_measurement:
            velocities, jacobians = self._solve_velocities(burst, positions, biases, motion, copies)
            return velocities, self._score(burst, positions, velocities, biases, motion, jacobians)[0]
        shared = slice(0, 1) if motion.straight else slice(None)  # a straight grid's candidates all move alike
        motion_rows = np.stack([motion.s[shared], motion.c[shared], motion.cos[shared], motion.sin[shared]])
        velocities, chi_square, information = kernels.lcmap_grid(
            positions,
            biases,
            motion.tau,
            motion_rows,
            (burst.receiver_positions, burst.receiver_velocities),
            burst.fixed_position,
            burst.measurements,
            whitener(burst),
            burst.residual_period,
            burst.robust,
            c.position_sd,
            c.velocity_prior_sd,
            self.velocity_iterations,
        )
        return velocities, chi_square - c.information_weight * np.linalg.slogdet(information)[1]

    def _linearize_at_rest(self, burst: Burst, positions, biases, motion: CandidateMotion, copies: int):
        """The whitened residuals, whitener and Jacobians of :meth:`_solve_velocities`' first step
        (zero velocities) for ``copies`` copies of one set of positions, computed on one copy."""
        distinct = len(positions) // copies
        at_rest = CandidateMotion(motion.tau, np.zeros(distinct))
        still, zero = positions[:distinct], np.zeros((distinct, 3))
        _, residual, white = _burst_chi_square(burst, still, zero, biases[:distinct], at_rest)
        local = self._local_jacobians(burst, still, zero, at_rest)
        if white.ndim > 2:  # a robust burst's weights are per residual
            white = np.tile(white, (copies, 1, 1, 1))
        return np.tile(residual, (copies, 1, 1)), white, motion.chain(np.tile(local, (copies, 1, 1, 1)), overwrite=True)

    def _score(
        self, burst: Burst, positions, velocities, biases, motion: CandidateMotion, jacobians=None, per_sample=False
    ):
        """MAP objective J - lambda log det F for each candidate, J itself, and the information F (C, 6, 6).

        F uses ``jacobians`` when given (the grid passes those of its velocity solve's last step, one
        small Gauss-Newton step away, which saves a third of the grid's cost). ``per_sample``: weigh
        with each candidate's own R_eff (see :func:`_burst_chi_square`).
        """
        c = self.config
        chi_square, _, white = _burst_chi_square(burst, positions, velocities, biases, motion, per_sample)
        chi_square = chi_square + np.sum(velocities**2, axis=1) / c.velocity_prior_sd**2
        jac = self._jacobians(burst, positions, velocities, motion) if jacobians is None else jacobians
        prior = np.diag([1 / c.position_sd**2] * 3 + [1 / c.velocity_prior_sd**2] * 3)
        information = _normal_equations(jac, np.zeros(jac.shape[:3]), white)[0] + prior
        _, logdet = np.linalg.slogdet(information)
        return chi_square - c.information_weight * logdet, chi_square, information

    def _motion(self, tau: np.ndarray, theta: np.ndarray, turn_rates: np.ndarray) -> CandidateMotion:
        """The candidates' motion for parameters theta = [p, v, (omega | a)] (the turn rate from theta when fitted)."""
        if self.fit_turn:
            return CandidateMotion(tau, theta[:, 6])
        return CandidateMotion(tau, turn_rates, theta[:, 6:9] if self.fit_acceleration else None)

    def _refine(self, burst: Burst, positions, velocities, biases, turn_rates):
        """Gauss-Newton jointly over the burst (the caller's subsample), from the best grid candidates,
        on (p, v) and the motion's own parameter: the turn rate (its derivative by central differences)
        or the acceleration.

        The grid spacing on the locus (and in turn rate) is coarse against a long burst's precision, so
        the grid only finds the basin; these steps find its bottom. Returns theta = [p, v, (omega | a)].
        """
        c = self.config
        tau = burst.times - burst.times[0]
        extra_prior = (
            [1 / c.max_turn_rate**2]
            if self.fit_turn
            else [1 / c.acceleration_prior_sd**2] * 3
            if self.fit_acceleration
            else []
        )
        prior = np.diag([1e-6] * 3 + [1 / c.velocity_prior_sd**2] * 3 + extra_prior)
        start = [turn_rates[:, None]] if self.fit_turn else [np.zeros_like(positions)] if self.fit_acceleration else []
        theta = np.concatenate([positions, velocities] + start, axis=1)
        for _ in range(self.refine_iterations):
            motion = self._motion(tau, theta, turn_rates)
            _, residual, white = _burst_chi_square(burst, theta[:, :3], theta[:, 3:6], biases, motion, per_sample=True)
            jac = self._jacobians(burst, theta[:, :3], theta[:, 3:6], motion, self.fit_acceleration)
            if self.fit_turn:
                step_size = 1e-4  # rad/s
                ahead, behind = (
                    _predicted(burst, theta[:, :3], theta[:, 3:6], CandidateMotion(tau, theta[:, 6] + d))
                    for d in (step_size, -step_size)
                )
                jac = np.concatenate([jac, ((ahead - behind) / (2 * step_size))[..., None]], axis=-1)
            normal, gradient = _normal_equations(jac, residual, white)
            normal = normal + prior
            gradient[:, 3:] -= theta[:, 3:] @ prior[3:, 3:]
            step = np.linalg.solve(normal, gradient[..., None])[..., 0]
            # Keep each step within a few metres: far from the basin the linearization is poor.
            scale = np.minimum(1.0, 5.0 / np.maximum(np.linalg.norm(step[:, :3], axis=1), 1e-12))
            theta = theta + step * scale[:, None]
            if self.fit_turn:
                theta[:, 6] = np.clip(theta[:, 6], -c.max_turn_rate, c.max_turn_rate)
        return theta

    def _plausible(self, positions, velocities, motion: CandidateMotion):
        """Not too fast, and inside the region at the burst's end (``motion`` over [0, burst length])."""
        end = motion.trajectory(positions, velocities)[0][:, -1]
        region = self.region
        return (
            (np.linalg.norm(velocities, axis=1) <= self.config.max_source_speed)
            & (end[:, 2] >= region.z_min)
            & (end[:, 2] <= region.z_max)
            & (np.hypot(end[:, 0], end[:, 1]) <= region.radius)
        )

    def __call__(self, burst: Burst, rng: np.random.Generator) -> InitialEstimate:
        c = self.config
        positions, biases = self.candidates(burst)
        if len(positions) == 0:
            logger.warning("LC-MAP found no candidate on the locus inside the region; falling back to naive")
            return NaiveInitializer(c)(burst, rng)
        # Every candidate position at every turn rate of the grid (constant velocity alone by default).
        turn_rates = np.repeat(self.turn_rates, len(positions))
        positions, biases = np.tile(positions, (len(self.turn_rates), 1)), np.tile(biases, len(self.turn_rates))
        tau_end = np.array([burst.times[-1] - burst.times[0]])
        # The grid only has to find basins: on a long window a 1 Hz subset of the burst is enough.
        stride = -(-len(burst.times) // self.grid_samples)
        grid_burst = replace(
            burst,
            **{
                name: getattr(burst, name)[::stride]
                for name in ("times", "measurements", "receiver_positions", "receiver_velocities")
            },
        )
        grid_motion = CandidateMotion(grid_burst.times - grid_burst.times[0], turn_rates)
        velocities, score = self._grid(grid_burst, positions, biases, grid_motion, len(self.turn_rates))
        plausible = self._plausible(positions, velocities, CandidateMotion(tau_end, turn_rates))
        score = np.where(plausible, score, np.inf) if plausible.any() else score
        # Refine the best few of every whole-period sheet and the best overall.
        order = np.argsort(score)
        on_sheets = [order[biases[order] == bias][: self.refine_per_sheet] for bias in np.unique(biases)]
        chosen = np.unique(np.concatenate([order[: self.refine_best], *on_sheets]))
        biases, turn_rates = biases[chosen], turn_rates[chosen]
        theta = self._refine(
            subsample(burst, self.refine_samples), positions[chosen], velocities[chosen], biases, turn_rates
        )
        refined_p, refined_v = theta[:, 0:3], theta[:, 3:6]
        motion = self._motion(burst.times - burst.times[0], theta, turn_rates)
        refined_score, chi_square, information = self._score(
            burst, refined_p, refined_v, biases, motion, per_sample=True
        )
        ok = self._plausible(refined_p, refined_v, self._motion(tau_end, theta, turn_rates)) & np.isfinite(
            refined_score
        )
        if ok.any():
            refined_score = np.where(ok, refined_score, np.inf)
        ranked = [i for i in np.argsort(refined_score, kind="stable") if np.isfinite(refined_score[i])] or [
            int(np.argmin(refined_score))
        ]
        kept = np.array(
            distinct_hypotheses(
                ranked, refined_p, biases, c.hypotheses, self.separation, burst.wavelength, sheets_first=True
            )
        )
        states = np.concatenate(
            [refined_p[kept], refined_v[kept], biases[kept, None], np.zeros((len(kept), 1))], axis=1
        )
        covariances = np.zeros((len(kept), 8, 8))
        covariances[:, :6, :6] = np.linalg.inv(information[kept]) * c.covariance_inflation
        covariances[:, 6, 6] = c.range_bias_sd**2
        covariances[:, 7, 7] = c.rate_bias_sd**2
        states, covariances = self._motion(tau_end, theta[kept], turn_rates[kept]).propagate(states, covariances)
        # The score ranks candidates; the filters' weights are likelihoods, so they start from the
        # burst's own: exp(-J / 2), relative to the likeliest kept hypothesis.
        log_weights = -0.5 * (chi_square[kept] - chi_square[kept].min())
        return InitialEstimate(
            states,
            covariances,
            log_weights,
            int(plausible.sum()),
            turn_rates=theta[kept, 6] if self.fit_turn else None,
            accelerations=theta[kept, 6:9] if self.fit_acceleration else None,
        )


def distinct_hypotheses(
    order,
    positions: np.ndarray,
    sheets: np.ndarray,
    limit: int,
    separation: float,
    wavelength: float | None,
    sheets_first: bool = False,
) -> list[int]:
    """Up to ``limit`` indices taken from ``order`` (best first), never two on one whole-period sheet
    (range biases closer than half a wavelength) within ``separation`` metres of each other. With
    ``sheets_first`` the best of every sheet comes before any sheet's second."""
    tolerance = 0.5 * wavelength if wavelength else np.inf

    def near(i: int, j: int) -> bool | np.bool_:
        return abs(sheets[i] - sheets[j]) < tolerance and np.linalg.norm(positions[i] - positions[j]) < separation

    kept: list[int] = []
    for first_pass in (True, False) if sheets_first else (False,):
        for i in order:
            if len(kept) == limit:
                return kept
            on_a_kept_sheet = any(abs(sheets[i] - sheets[j]) < tolerance for j in kept)
            if i in kept or (first_pass and on_a_kept_sheet) or any(near(i, j) for j in kept):
                continue
            kept.append(int(i))
    return kept


def make_initializer(name: str, config: InitializerConfig, region: Box, motion: str = "cv") -> Initializer:
    """The initializer called ``name``: lcmap (fitting the filter's ``motion`` model), naive, random or tdoa-ls."""
    if name == "lcmap":
        return LCMAPInitializer(config, region, motion)
    if name == "tdoa-ls":
        return TdoaLeastSquaresInitializer(config, region)
    simple: dict[str, Callable[[InitializerConfig], Initializer]] = {
        "naive": NaiveInitializer,
        "random": RandomInitializer,
    }
    if name not in simple:
        raise ValueError(f"unknown initializer {name!r}; allowed: ['lcmap', 'naive', 'random', 'tdoa-ls']")
    return simple[name](config)
