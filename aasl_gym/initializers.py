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
on (p, v) over the whole burst and scored again. A 2 s burst rarely tells the sheets apart, so LC-MAP
returns up to ``config.hypotheses`` distinct candidates - the best of every sheet first, then the next
best - each with the inverse of its F (times ``covariance_inflation``) as covariance and its burst
likelihood exp(-J / 2) as relative weight; the tracker runs one UKF per hypothesis
(``hypotheses: 1`` is the paper's single filter).

Locus in closed form: with a = p_m - p_f and a candidate p = p_m + r u (u a unit vector),
|p - p_f| = r - RD gives r = (RD^2 - |a|^2) / (2 (a . u + RD)), valid where r > 0.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Callable, Protocol

import numpy as np

from aasl_gym import geometry
from aasl_gym.config import InitializerConfig
from aasl_gym.fisher import measurement_jacobian
from aasl_gym.motion import Box

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
    noise_covariance: np.ndarray  # (2, 2) R_eff
    wavelength: float | None  # m; None when the RD is unambiguous
    measurement_function: MeasurementFunction


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

    @classmethod
    def single(cls, state: np.ndarray, covariance: np.ndarray, candidates: int = 1) -> "InitialEstimate":
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


def feasible_offsets(first_rd: float, baseline: float, wavelength: float | None) -> np.ndarray:
    """Whole-period biases b_p = k * wavelength with |first_rd - b_p| <= baseline (m)."""
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


def _cv_propagate(states: np.ndarray, covariances: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity prediction of base states (..., 8) and covariances (..., 8, 8) over dt seconds."""
    f = np.eye(8)
    f[0:3, 3:6] = dt * np.eye(3)
    return states @ f.T, f @ covariances @ f.T


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
    """Gauss-Newton (minimum-norm steps) on the last RD alone, from a generic point below the pod."""

    iterations = 20

    def __call__(self, burst: Burst, rng: np.random.Generator) -> InitialEstimate:
        mobile, fixed = burst.receiver_positions[-1], burst.fixed_position
        target = burst.measurements[-1, 0]
        position = fixed + np.array([0.0, 0.0, -0.5 * self.config.position_sd])
        for _ in range(self.iterations):
            gradient = geometry.ranges(position, mobile)[1] - geometry.ranges(position, fixed)[1]
            norm2 = gradient @ gradient
            if norm2 < 1e-9:
                break
            position = position + gradient * (target - geometry.range_difference(position, mobile, fixed)) / norm2
        return self.estimate(burst, position, 0.0, _uninformed_bias_sd(burst))


def whitener(burst: Burst) -> np.ndarray:
    """W (2, 2) with W^T W = R^-1: whitened residuals W r have unit covariance."""
    return np.linalg.cholesky(np.linalg.inv(burst.noise_covariance)).T


def _normal_equations(jacobian: np.ndarray, residual: np.ndarray, white: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J^T R^-1 J (C, n, n) and J^T R^-1 r (C, n) summed over the burst, as batched matrix products.

    ``jacobian`` is (C, K, 2, n), ``residual`` the *whitened* residual (C, K, 2), ``white`` from :func:`whitener`.
    """
    count, samples, _, n = jacobian.shape
    whitened = np.matmul(white, jacobian).reshape(count, 2 * samples, n)
    transposed = whitened.transpose(0, 2, 1)
    return transposed @ whitened, (transposed @ residual.reshape(count, 2 * samples, 1))[..., 0]


def _burst_chi_square(burst: Burst, positions: np.ndarray, velocities: np.ndarray, biases: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Chi-square of the burst for candidate trajectories p(t) = p + v (t - t0): (C,), and the whitened
    residuals (C, K, 2)."""
    tau = burst.times - burst.times[0]
    trajectory = positions[:, None, :] + velocities[:, None, :] * tau[None, :, None]
    predicted = burst.measurement_function(
        trajectory, velocities[:, None, :], burst.receiver_positions[None], burst.receiver_velocities[None], burst.fixed_position
    )
    residual = burst.measurements[None] - predicted
    residual[..., 0] -= biases[:, None]
    whitened = residual @ whitener(burst).T
    return np.sum(whitened**2, axis=(1, 2)), whitened


class RandomInitializer(_BroadPrior):
    """Random points on the first RD's locus (every feasible sheet), zero velocity; keep the best fit."""

    def __call__(self, burst: Burst, rng: np.random.Generator) -> InitialEstimate:
        mobile, fixed = burst.receiver_positions[0], burst.fixed_position
        baseline = np.linalg.norm(mobile - fixed)
        offsets = feasible_offsets(burst.measurements[0, 0], baseline, burst.wavelength)
        directions = rng.normal(size=(self.config.candidate_directions, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        points = np.concatenate([locus_points(mobile, fixed, burst.measurements[0, 0] - b, directions) for b in offsets])
        biases = np.repeat(offsets, len(directions))
        keep = np.isfinite(points[:, 0])
        if not keep.any():
            return NaiveInitializer(self.config)(burst, rng)
        points, biases = points[keep], biases[keep]
        chi_square, _ = _burst_chi_square(burst, points, np.zeros_like(points), biases)
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
    grid_samples = 20  # burst samples the grid stage uses at most (the refinement uses all)

    def __init__(self, config: InitializerConfig, region: Box):
        self.config = config
        self.region = region
        self.directions = fibonacci_directions(config.candidate_directions)

    def candidates(self, burst: Burst) -> tuple[np.ndarray, np.ndarray]:
        """Candidate positions at the burst's first time and their whole-period biases."""
        mobile, fixed = burst.receiver_positions[0], burst.fixed_position
        baseline = np.linalg.norm(mobile - fixed)
        offsets = feasible_offsets(burst.measurements[0, 0], baseline, burst.wavelength)
        points = np.concatenate([locus_points(mobile, fixed, burst.measurements[0, 0] - b, self.directions) for b in offsets])
        biases = np.repeat(offsets, len(self.directions))
        region = self.region
        keep = (
            np.isfinite(points[:, 0])
            & (points[:, 2] >= region.z_min)
            & (points[:, 2] <= region.z_max)
            & (np.hypot(points[:, 0], points[:, 1]) <= region.radius)
        )
        return points[keep], biases[keep]

    def _jacobians(self, burst: Burst, positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
        """d[RD, RRD]_k / d[p(t0), v] for every candidate and burst sample: (C, K, 2, 6)."""
        tau = burst.times - burst.times[0]
        trajectory = positions[:, None, :] + velocities[:, None, :] * tau[None, :, None]
        local = measurement_jacobian(trajectory, velocities[:, None, :], burst.receiver_positions[None], burst.receiver_velocities[None], burst.fixed_position)[..., :6]
        jac = local.copy()
        jac[..., 3:6] += local[..., 0:3] * tau[None, :, None, None]  # p(t_k) = p + v tau_k
        return jac

    def _solve_velocities(self, burst: Burst, positions: np.ndarray, biases: np.ndarray) -> np.ndarray:
        white = whitener(burst)
        prior = np.eye(3) / self.config.velocity_prior_sd**2
        velocities = np.zeros_like(positions)
        for _ in range(self.velocity_iterations):
            _, residual = _burst_chi_square(burst, positions, velocities, biases)
            jac_v = self._jacobians(burst, positions, velocities)[..., 3:6]  # (C, K, 2, 3)
            normal, gradient = _normal_equations(jac_v, residual, white)
            normal = normal + prior
            gradient = gradient - velocities @ prior
            velocities = velocities + np.linalg.solve(normal, gradient[..., None])[..., 0]
        return velocities

    def _score(self, burst: Burst, positions, velocities, biases):
        """MAP objective J - lambda log det F for each candidate, J itself, and the information F (C, 6, 6)."""
        c = self.config
        chi_square, _ = _burst_chi_square(burst, positions, velocities, biases)
        chi_square = chi_square + np.sum(velocities**2, axis=1) / c.velocity_prior_sd**2
        jac = self._jacobians(burst, positions, velocities)
        prior = np.diag([1 / c.position_sd**2] * 3 + [1 / c.velocity_prior_sd**2] * 3)
        information = _normal_equations(jac, np.zeros(jac.shape[:3]), whitener(burst))[0] + prior
        _, logdet = np.linalg.slogdet(information)
        return chi_square - c.information_weight * logdet, chi_square, information

    def _refine(self, burst: Burst, positions, velocities, biases):
        """Gauss-Newton on (p, v) jointly over the whole burst, from the best grid candidates.

        The grid spacing on the locus is coarse against a long burst's precision, so the grid only
        finds the basin; these steps find its bottom.
        """
        white = whitener(burst)
        prior = np.diag([1e-6] * 3 + [1 / self.config.velocity_prior_sd**2] * 3)
        theta = np.concatenate([positions, velocities], axis=1)
        for _ in range(self.refine_iterations):
            _, residual = _burst_chi_square(burst, theta[:, :3], theta[:, 3:], biases)
            jac = self._jacobians(burst, theta[:, :3], theta[:, 3:])
            normal, gradient = _normal_equations(jac, residual, white)
            normal = normal + prior
            gradient[:, 3:] -= theta[:, 3:] @ prior[3:, 3:]
            step = np.linalg.solve(normal, gradient[..., None])[..., 0]
            # Keep each step within a few metres: far from the basin the linearization is poor.
            scale = np.minimum(1.0, 5.0 / np.maximum(np.linalg.norm(step[:, :3], axis=1), 1e-12))
            theta = theta + step * scale[:, None]
        return theta[:, :3], theta[:, 3:]

    def _plausible(self, positions, velocities, tau_end):
        end = positions + velocities * tau_end
        region = self.region
        return (
            (np.linalg.norm(velocities, axis=1) <= self.config.max_source_speed)
            & (end[:, 2] >= region.z_min) & (end[:, 2] <= region.z_max)
            & (np.hypot(end[:, 0], end[:, 1]) <= region.radius)
        )

    def __call__(self, burst: Burst, rng: np.random.Generator) -> InitialEstimate:
        c = self.config
        positions, biases = self.candidates(burst)
        if len(positions) == 0:
            logger.warning("LC-MAP found no candidate on the locus inside the region; falling back to naive")
            return NaiveInitializer(c)(burst, rng)
        tau_end = burst.times[-1] - burst.times[0]
        # The grid only has to find basins: on a long window a 1 Hz subset of the burst is enough.
        stride = -(-len(burst.times) // self.grid_samples)
        grid_burst = replace(burst, **{name: getattr(burst, name)[::stride] for name in ("times", "measurements", "receiver_positions", "receiver_velocities")})
        velocities = self._solve_velocities(grid_burst, positions, biases)
        score, _, _ = self._score(grid_burst, positions, velocities, biases)
        plausible = self._plausible(positions, velocities, tau_end)
        score = np.where(plausible, score, np.inf) if plausible.any() else score
        # Refine the best few of every whole-period sheet and the best overall.
        order = np.argsort(score)
        chosen = list(order[: self.refine_best])
        for bias in np.unique(biases):
            chosen += [i for i in order if biases[i] == bias][: self.refine_per_sheet]
        chosen = np.unique(chosen)
        refined_p, refined_v = self._refine(burst, positions[chosen], velocities[chosen], biases[chosen])
        biases = biases[chosen]
        refined_score, chi_square, information = self._score(burst, refined_p, refined_v, biases)
        ok = self._plausible(refined_p, refined_v, tau_end) & np.isfinite(refined_score)
        if ok.any():
            refined_score = np.where(ok, refined_score, np.inf)
        order = [i for i in np.argsort(refined_score, kind="stable") if np.isfinite(refined_score[i])] or [int(np.argmin(refined_score))]
        kept = np.array(distinct_hypotheses(order, refined_p, biases, c.hypotheses, self.separation, burst.wavelength, sheets_first=True))
        states = np.concatenate([refined_p[kept], refined_v[kept], biases[kept, None], np.zeros((len(kept), 1))], axis=1)
        covariances = np.zeros((len(kept), 8, 8))
        covariances[:, :6, :6] = np.linalg.inv(information[kept]) * c.covariance_inflation
        covariances[:, 6, 6] = c.range_bias_sd**2
        covariances[:, 7, 7] = c.rate_bias_sd**2
        states, covariances = _cv_propagate(states, covariances, tau_end)
        # The score ranks candidates; the filters' weights are likelihoods, so they start from the
        # burst's own: exp(-J / 2), relative to the likeliest kept hypothesis.
        log_weights = -0.5 * (chi_square[kept] - chi_square[kept].min())
        return InitialEstimate(states, covariances, log_weights, candidates=int(plausible.sum()))


def distinct_hypotheses(order, positions: np.ndarray, sheets: np.ndarray, limit: int, separation: float,
                        wavelength: float | None, sheets_first: bool = False) -> list[int]:
    """Up to ``limit`` indices taken from ``order`` (best first), never two on one whole-period sheet
    (range biases closer than half a wavelength) within ``separation`` metres of each other. With
    ``sheets_first`` the best of every sheet comes before any sheet's second."""
    tolerance = 0.5 * wavelength if wavelength else np.inf

    def near(i: int, j: int) -> bool:
        return abs(sheets[i] - sheets[j]) < tolerance and np.linalg.norm(positions[i] - positions[j]) < separation

    kept: list[int] = []
    for first_pass in ((True, False) if sheets_first else (False,)):
        for i in order:
            if len(kept) == limit:
                return kept
            on_a_kept_sheet = any(abs(sheets[i] - sheets[j]) < tolerance for j in kept)
            if i in kept or (first_pass and on_a_kept_sheet) or any(near(i, j) for j in kept):
                continue
            kept.append(int(i))
    return kept


def make_initializer(name: str, config: InitializerConfig, region: Box) -> Initializer:
    """The initializer called ``name``: lcmap, naive, random or tdoa-ls."""
    if name == "lcmap":
        return LCMAPInitializer(config, region)
    simple = {"naive": NaiveInitializer, "random": RandomInitializer, "tdoa-ls": TdoaLeastSquaresInitializer}
    if name not in simple:
        raise ValueError(f"unknown initializer {name!r}; allowed: ['lcmap', 'naive', 'random', 'tdoa-ls']")
    return simple[name](config)
