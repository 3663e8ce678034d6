"""Unscented Kalman filter (Merwe scaled sigma points, vectorized) and the source motion models.

State layouts (positions m, velocities m/s, b_p m, b_v m/s):

* ``cv``   (8):  [p(3), v(3), b_p, b_v]                 constant velocity, white acceleration
* ``ca``   (11): [p(3), v(3), a(3), b_p, b_v]           constant acceleration, white jerk; with a
  speed limit the source stops accelerating at that speed, and v is the velocity it would have had
  without the limit (:class:`ConstantAcceleration`)
* ``ctrv`` (9):  [p(3), v(3), omega, b_p, b_v]          horizontal coordinated turn at rate omega (rad/s)

Every layout keeps p in 0:3, v in 3:6 and the two measurement biases last, so the measurement function
is shared; it takes the source's velocity from :meth:`MotionModel.velocity`. The UKF follows filterpy's
``UnscentedKalmanFilter`` step for step (a test runs both): the predict step redraws the sigma points from
the predicted mean and covariance, and the update uses them.

References: R. van der Merwe, "Sigma-Point Kalman Filters for Probabilistic Inference in Dynamic
State-Space Models", 2004; Y. Bar-Shalom et al., "Estimation with Applications to Tracking and
Navigation", 2001 (process-noise models, section 6.2).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from scipy import linalg

from aasl_gym import kernels
from aasl_gym.config import FilterConfig
from aasl_gym.motion import coordinated_turn_displacement, small_angle_series

BASE_DIM = 8  # [p, v, b_p, b_v]: the layout initializers produce
LIMIT_GRAZE = 0.05  # a speed-limited CA's Jacobian: the least cosine between a and the velocity at the limit
FREE_MATRICES_KEPT = 64  # free-motion matrices (K, 6, n - 2) a linear model keeps: a few MB at most
LOG_NORMALIZER_2D = 2 * math.log(2 * math.pi)  # log (2 pi)^2: a 2-D Gaussian's log density carries half of it


def _white_noise_blocks(dt: float, order: int) -> np.ndarray:
    """Covariance per unit spectral density of a continuous white-noise (order-1)-th derivative model.

    order 2: white acceleration on [p, v]; order 3: white jerk on [p, v, a].
    """
    if order == 2:
        return np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    return np.array(
        [
            [dt**5 / 20, dt**4 / 8, dt**3 / 6],
            [dt**4 / 8, dt**3 / 3, dt**2 / 2],
            [dt**3 / 6, dt**2 / 2, dt],
        ]
    )


class MotionModel:
    """A filter motion model: its state size, transition and process noise.

    With ``depth_bounds`` (z_min, z_max in m) the source stays in that slab of the water column, as a
    moving source must: it reflects specularly at the bounds, as the world's sources do at
    ``source.boundary_margin`` from the surface and the bed. A filter's mean that a prediction carries
    across a bound is reflected with its covariance (:meth:`reflect`). With ``fold_trajectories`` a
    window's trajectories (:meth:`trajectory`) are folded into the slab too, which is that reflection
    exactly for any number of bounces, forward or back. (In the free field both took CV sources from
    30 to 34 of 40 tuning seeds, no track lost against one.)
    """

    name: str
    dim: int

    def __init__(
        self,
        config: FilterConfig,
        depth_bounds: tuple[float, float] | None = None,
        fold_trajectories: bool = False,
        speed_limit: float | None = None,
    ):
        self.config = config
        self.speed_limit = speed_limit  # m/s; only a constant acceleration reaches it (:class:`ConstantAcceleration`)
        self.depth_bounds = depth_bounds
        self.fold_trajectories = fold_trajectories and depth_bounds is not None
        self._noise_cache: dict[float, np.ndarray] = {}
        self._free_matrices: dict[bytes, np.ndarray] = {}  # see LinearMotionModel._free_matrix

    def velocity(self, states: np.ndarray) -> np.ndarray:
        """The source's velocity (..., 3; m/s) in states (..., n): components 3:6 (a view)."""
        return states[..., 3:6]

    def transition(self, states: np.ndarray, dt: float | np.ndarray) -> np.ndarray:
        """States (..., n) ``dt`` seconds later (``dt`` a scalar or broadcasting beside the states),
        moving freely: the filter reflects its mean afterwards (:meth:`reflect`)."""
        return self._advance(states, dt)

    def _advance(self, states: np.ndarray, dt: float | np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def _vertical(self) -> np.ndarray:
        """Indices of z, the vertical velocity and (ca) the vertical acceleration."""
        return np.array([2, 5, 8]) if self.name == "ca" else np.array([2, 5])

    def _fold(self, states: np.ndarray) -> np.ndarray:
        """Free-motion states (..., n) folded into the depth bounds (in place): z mirrored, the vertical
        velocity and acceleration negated on every odd fold."""
        low, span, phase, mirrored = self._fold_phase(states[..., 2])
        states[..., 2] = low + np.where(mirrored, 2 * span - phase, phase)
        states[..., self._vertical()[1:]] *= np.where(mirrored, -1.0, 1.0)[..., None]
        return states

    def _fold_phase(self, free_depth: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray]:
        """Where a free motion's z (m) lies in the folding's period: the lower bound, the slab's span, the
        phase in [0, 2 span) above the lower bound and whether it was mirrored (an odd number of reflections)."""
        assert self.depth_bounds is not None  # fold_trajectories needs them
        low, high = self.depth_bounds
        span = high - low
        phase = np.mod(free_depth - low, 2 * span)
        return low, span, phase, phase > span

    def _vertical_flip(self) -> np.ndarray:
        """(n,) signs of a reflection off a depth bound: -1 on z and the vertical velocity and acceleration."""
        flip = np.ones(self.dim)
        flip[self._vertical()] = -1.0
        return flip

    def fold_states(self, states: np.ndarray, information: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States (C, n) and their information (C, n, n) as a folded trajectory sees them (:meth:`trajectory`
        folds every sample, the one the states are given at included): copies, each state folded into the
        depth bounds and its information mirrored with it. A state beyond a bound and its mirror within
        explain a window alike, but only the mirror is where the source can be. Unchanged without folding."""
        states, information = np.array(states, dtype=float), np.array(information, dtype=float)
        if not self.fold_trajectories:
            return states, information
        mirrored = self._fold_phase(states[:, 2])[3]
        signs = np.where(mirrored[:, None], self._vertical_flip(), 1.0)
        return self._fold(states), information * signs[:, :, None] * signs[:, None, :]

    def reflect(self, x: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A filter's mean and covariance once its mean is beyond a depth bound and moving away, by more
        than twice its sd (a prediction or an update took it there): the mean reflected as the source
        would be, the covariance by the same linear reflection, so that it stays Gaussian. (Folding
        every sigma point instead splits a spread near the bound in two; a slow mean near the surface
        is left to the measurements.)"""
        if self.depth_bounds is None:
            return x, covariance
        low, high = self.depth_bounds
        outward, rising = 2 * np.sqrt(covariance[5, 5]), self.velocity(x)[2]
        if not ((x[2] > high and rising > outward) or (x[2] < low and rising < -outward)):
            return x, covariance
        flip = self._vertical_flip()
        reflected = x * flip
        reflected[2] += 2 * (high if x[2] > high else low)
        return reflected, covariance * np.outer(flip, flip)

    def _kinematic_noise(self, dt: float) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def trajectory(self, states: np.ndarray, lags: np.ndarray) -> np.ndarray:
        """States (C, n) carried ``lags`` (K,) seconds along the model (lags may be negative): (C, K, n)."""
        moved = self._free_trajectory(states, lags)
        return self._fold(moved) if self.fold_trajectories else moved

    def _free_trajectory(self, states: np.ndarray, lags: np.ndarray) -> np.ndarray:
        """:meth:`trajectory` before the fold (a fresh array)."""
        expanded = np.broadcast_to(states[:, None, :], (len(states), len(lags), self.dim))
        return self._advance(expanded, np.asarray(lags, dtype=float)[None, :, None])

    def source_trajectory(self, states: np.ndarray, lags: np.ndarray) -> np.ndarray:
        """:meth:`trajectory` as a measurement sees it: the source's own velocity (:meth:`velocity`) in 3:6."""
        return self._source_velocity(self.trajectory(states, lags))

    def _source_velocity(self, trajectory: np.ndarray) -> np.ndarray:
        """A trajectory (..., n) with the source's own velocity in 3:6, in place (the state's, for most models)."""
        return trajectory

    def trajectory_jacobian(self, states: np.ndarray, lags: np.ndarray) -> np.ndarray:
        """d[p, v](t_k) / d x of :meth:`trajectory`: (C, K, 6, n - 2), over the components that move the
        trajectory (the biases do not); each model gives it in closed form."""
        return self._trajectory_jacobian(states, lags, None)

    def _trajectory_jacobian(
        self, states: np.ndarray, lags: np.ndarray, free_depth: np.ndarray | None
    ) -> np.ndarray:  # pragma: no cover - interface
        """:meth:`trajectory_jacobian`, the fold's signs taken from ``free_depth``, the unfolded trajectory's z
        (C, K), where the caller has it (:meth:`trajectory_terms`), else from the free motion run again."""
        raise NotImplementedError

    def trajectory_terms(self, states: np.ndarray, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`source_trajectory` and :meth:`trajectory_jacobian` of ``states`` (C, n) at ``lags`` (K,) together,
        the same arrays, with the free motion run once for both: what a window fit reads where the free motion is
        not one matrix (a CTRV's, a speed-limited CA's). Run apart, the Jacobian's fold ran it again."""
        lags = np.asarray(lags, dtype=float)
        moved = self._free_trajectory(states, lags)
        free_depth = moved[..., 2].copy()  # the fold changes it in place
        trajectory = self._fold(moved) if self.fold_trajectories else moved
        return self._source_velocity(trajectory), self._trajectory_jacobian(states, lags, free_depth)

    def free_motion_matrix(self, lags: np.ndarray) -> np.ndarray | None:
        """Where the free motion is linear in the state, one matrix for every state: d[p, v](t_k) / d x of it
        (K, 6, n - 2), over the components that move the trajectory; else None. A trajectory is then that matrix
        times the state, folded into :attr:`fold_bounds`, and its Jacobian the matrix with the fold's sign on its z
        and v_z rows: what a compiled window fit computes itself instead of reading (C, K, n) and (C, K, 6, n - 2)."""
        return None

    @property
    def fold_bounds(self) -> tuple[float, float] | None:
        """(z_min, z_max) (m) that :meth:`trajectory` folds into, or None."""
        return self.depth_bounds if self.fold_trajectories else None

    def _folded(
        self, jacobian: np.ndarray, states: np.ndarray, lags: np.ndarray, free_depth: np.ndarray | None = None
    ) -> np.ndarray:
        """A free trajectory's Jacobian (C, K, 6, m) with the fold's sign (see :meth:`_fold`) on its z and
        v_z rows where the fold mirrored the state. A free motion's vertical part is the same in every
        model (z + v_z t, with a_z t^2 / 2 for CA), so the fold is one sign per sample. ``free_depth``: the
        unfolded trajectory's z (C, K), run here if None."""
        if not self.fold_trajectories:
            return jacobian
        if free_depth is None:
            free_depth = self._free_trajectory(states, lags)[..., 2]
        mirrored = self._fold_phase(free_depth)[3]
        sign = np.ones(jacobian.shape[:2] + (6, 1))
        sign[..., [2, 5], 0] = np.where(mirrored, -1.0, 1.0)[..., None]
        return jacobian * sign

    def process_noise(self, dt: float) -> np.ndarray:
        if dt not in self._noise_cache:
            q = np.zeros((self.dim, self.dim))
            kinematic = self._kinematic_noise(dt)
            q[: kinematic.shape[0], : kinematic.shape[0]] = kinematic
            q[-2, -2] = self.config.range_bias_psd * dt
            q[-1, -1] = self.config.rate_bias_psd * dt
            self._noise_cache[dt] = q
        return self._noise_cache[dt]

    @property
    def base_index(self) -> np.ndarray:
        """Where the base-layout components [p, v, b_p, b_v] sit in this model's state."""
        return np.r_[0:6, self.dim - 2, self.dim - 1]

    def embed(
        self, state: np.ndarray, covariance: np.ndarray, extra_sd: float, extra_value: float | np.ndarray = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Lift a base-layout state [p, v, b_p, b_v] (and covariance) into this model's layout.

        The model's extra components (acceleration, turn rate) start at ``extra_value`` with sd ``extra_sd``.
        """
        extra = self.dim - BASE_DIM
        index = self.base_index
        x = np.zeros(self.dim)
        x[6 : 6 + extra] = extra_value
        x[index] = state
        p = np.zeros((self.dim, self.dim))
        p[np.ix_(index, index)] = covariance
        p[6 : 6 + extra, 6 : 6 + extra] = np.eye(extra) * extra_sd**2
        return x, p


class LinearMotionModel(MotionModel):
    """A model whose free motion is linear in the state: its trajectory Jacobian is the transition's
    matrix, the same for every state, with the fold's sign on the vertical rows."""

    def _trajectory_jacobian(self, states: np.ndarray, lags: np.ndarray, free_depth: np.ndarray | None) -> np.ndarray:
        """:meth:`MotionModel.trajectory_jacobian`: the transition of each moving component's unit vector,
        sign-flipped in z and v_z where a fold mirrored the state. Without folding it is a read-only view
        shared by all the states."""
        lags = np.asarray(lags, dtype=float)
        matrix = self._free_matrix(lags)
        return self._folded(np.broadcast_to(matrix, (len(states),) + matrix.shape), states, lags, free_depth)

    def free_motion_matrix(self, lags: np.ndarray) -> np.ndarray | None:
        """:meth:`MotionModel.free_motion_matrix`: the transition of each moving component's unit vector."""
        return self._free_matrix(np.asarray(lags, dtype=float))

    def _free_matrix(self, lags: np.ndarray) -> np.ndarray:
        """:meth:`free_motion_matrix` (read-only), kept per distinct ``lags``: the history is sampled evenly, so
        windows of one length share their lags, and a re-seed's fits, the next re-seed's and the track checks'
        read the same few matrices."""
        key = lags.tobytes()
        matrix = self._free_matrices.get(key)
        if matrix is None:
            moving = self.dim - 2
            units = np.broadcast_to(np.eye(self.dim)[:moving], (len(lags), moving, self.dim))
            matrix = np.swapaxes(self._advance(units, lags[:, None, None])[..., 0:6], -1, -2)
            matrix.flags.writeable = False
            if len(self._free_matrices) >= FREE_MATRICES_KEPT:
                del self._free_matrices[next(iter(self._free_matrices))]  # the first kept
            self._free_matrices[key] = matrix
        return matrix


class ConstantVelocity(LinearMotionModel):
    name, dim = "cv", 8

    def _advance(self, states: np.ndarray, dt: float | np.ndarray) -> np.ndarray:
        out = states.copy()
        out[..., 0:3] += dt * states[..., 3:6]
        return out

    def _kinematic_noise(self, dt: float) -> np.ndarray:
        return np.kron(_white_noise_blocks(dt, 2), np.eye(3)) * self.config.acceleration_psd


class ConstantAcceleration(LinearMotionModel):
    """Constant acceleration; with a ``speed_limit`` (m/s) as the world's CA sources move: the source
    accelerates until its speed reaches the limit and keeps that velocity from then on.

    A state at the limit then carries its acceleration on, and v (components 3:6) is the velocity the
    source would have had without the limit, v + a s in s seconds, forward or back: the lag at which that
    line leaves the ball of the limit's radius is when the source reached it, which a state given after
    that time must know to run a window back. The source's own velocity is :meth:`velocity`."""

    name, dim = "ca", 11

    def _advance(self, states: np.ndarray, dt: float | np.ndarray) -> np.ndarray:
        if self.speed_limit is None:
            return self._free_advance(states, dt)
        return self._limited_advance(states, dt, states)

    def _free_trajectory(self, states: np.ndarray, lags: np.ndarray) -> np.ndarray:
        if self.speed_limit is None:
            return super()._free_trajectory(states, lags)
        expanded = np.broadcast_to(states[:, None, :], (len(states), len(lags), self.dim))
        return self._limited_advance(expanded, np.asarray(lags, dtype=float)[None, :, None], states[:, None, :])

    def _limited_advance(self, states: np.ndarray, dt: float | np.ndarray, own: np.ndarray) -> np.ndarray:
        """:meth:`_advance` with the speed limit. ``own``: the states before they were broadcast to ``states``
        (C, 1, n for a trajectory's (C, K, n); else ``states`` itself): the lag each reaches the limit at is taken
        from them, once a state rather than at every sample."""
        unlimited, acceleration = own[..., 3:6], own[..., 6:9]
        reached = self._limit_lag(own)[..., None]

        def travelled(lag):  # m from the state's position after ``lag`` s, the velocity held from ``reached`` on
            held = np.minimum(lag, reached)
            return unlimited * held + 0.5 * acceleration * held**2 + (unlimited + acceleration * held) * (lag - held)

        out = states.copy()
        out[..., 0:3] += travelled(dt) - travelled(0.0)
        out[..., 3:6] += dt * acceleration
        return out

    @staticmethod
    def _free_advance(states: np.ndarray, dt: float | np.ndarray) -> np.ndarray:
        out = states.copy()
        out[..., 0:3] += dt * states[..., 3:6] + 0.5 * dt**2 * states[..., 6:9]
        out[..., 3:6] += dt * states[..., 6:9]
        return out

    def _limit_lag(self, states: np.ndarray) -> np.ndarray:
        """s (...,): the lag (from the states' time) at which the source reached or reaches the speed limit:
        the later root of |v + a s|^2 = limit^2. A line that never enters the limit's ball (no source could
        have come from below the limit along it) is held where it passes closest, the lag its two roots meet
        at as it stops crossing, so that the motion stays continuous in the state; +inf without acceleration."""
        square, along, discriminant = self._limit_crossing(states[..., 3:6], states[..., 6:9])
        accelerating = square > 0
        root = (np.sqrt(np.maximum(discriminant, 0.0)) - along) / np.where(accelerating, square, 1.0)
        return np.where(accelerating, root, np.inf)

    def _limit_crossing(self, unlimited: np.ndarray, acceleration: np.ndarray) -> tuple[np.ndarray, ...]:
        """|a|^2, v . a and the discriminant (v . a)^2 - |a|^2 (|v|^2 - limit^2) (each (...,)) of the line
        v + a s of velocities (v, a: (..., 3)) meeting the limit's sphere: it crosses where that is positive."""
        assert self.speed_limit is not None  # only a limited model reaches its limit
        square = np.einsum("...i,...i->...", acceleration, acceleration)
        along = np.einsum("...i,...i->...", unlimited, acceleration)
        discriminant = along**2 - square * (np.einsum("...i,...i->...", unlimited, unlimited) - self.speed_limit**2)
        return square, along, discriminant

    def velocity(self, states: np.ndarray) -> np.ndarray:
        """The source's velocity (..., 3; m/s): v, or with a speed limit v less a times the time since the
        source reached it."""
        if self.speed_limit is None:
            return states[..., 3:6]
        since = np.minimum(self._limit_lag(states), 0.0)[..., None]
        return states[..., 3:6] + states[..., 6:9] * since

    def embed(
        self, state: np.ndarray, covariance: np.ndarray, extra_sd: float, extra_value: float | np.ndarray = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`MotionModel.embed`; with a speed limit a velocity above it is taken down to it: a source at
        its limit (an initializer's fit does not know the limit)."""
        x, p = super().embed(state, covariance, extra_sd, extra_value)
        speed = np.linalg.norm(x[3:6])
        if self.speed_limit is not None and speed > self.speed_limit:
            x[3:6] *= self.speed_limit / speed
        return x, p

    def _source_velocity(self, trajectory: np.ndarray) -> np.ndarray:
        if self.speed_limit is not None:
            trajectory[..., 3:6] = self.velocity(trajectory)
        return trajectory

    def free_motion_matrix(self, lags: np.ndarray) -> np.ndarray | None:
        """:meth:`MotionModel.free_motion_matrix`: the free motion's, or None with a speed limit (the lag it is
        reached at moves with the state)."""
        return super().free_motion_matrix(lags) if self.speed_limit is None else None

    def _trajectory_jacobian(self, states: np.ndarray, lags: np.ndarray, free_depth: np.ndarray | None) -> np.ndarray:
        """:meth:`MotionModel.trajectory_jacobian`: the free motion's (:class:`LinearMotionModel`), or with a
        speed limit the limited one's in closed form. With r the lag the limit is reached at, h = min(s, r)
        and h0 = min(0, r), the position is p + v s + a (h s - h^2 / 2 + h0^2 / 2) and the velocity v + a h,
        r moving with the state (:meth:`_limit_lag_gradient`)."""
        if self.speed_limit is None:
            return super()._trajectory_jacobian(states, lags, free_depth)
        lags = np.asarray(lags, dtype=float)[None, :]  # (1, K)
        unlimited, acceleration = states[:, None, 3:6], states[:, None, 6:9]  # (C, 1, 3)
        reached = self._limit_lag(states)[:, None]  # (C, 1)
        finite = np.isfinite(reached)
        at_limit = np.where(finite, reached, 0.0)
        held, held_now = np.minimum(lags, reached), np.minimum(at_limit, 0.0)  # (C, K), (C, 1)
        lag_gradient = np.where(finite[..., None], self._limit_lag_gradient(unlimited, acceleration, at_limit), 0.0)
        # d(a h)/d[v, a] where h = r: a times dr/d[v, a], as (C, 1, 3, 6).
        through_limit = acceleration[..., :, None] * lag_gradient[..., None, :]
        capped = (lags > at_limit) & finite  # the samples after the source reached the limit
        eye = np.eye(3)
        jacobian = np.zeros(held.shape + (6, self.dim - 2))
        jacobian[..., 0:3, 0:3] = eye
        jacobian[..., 0:3, 3:6] = lags[..., None, None] * eye
        jacobian[..., 0:3, 6:9] = (held * lags - held**2 / 2 + held_now**2 / 2)[..., None, None] * eye
        jacobian[..., 3:6, 3:6] = eye
        jacobian[..., 3:6, 6:9] = held[..., None, None] * eye
        position_weight = np.where(capped, lags - at_limit, 0.0) + held_now  # of (s - h) dh and h0 dh0
        jacobian[..., 0:3, 3:9] += position_weight[..., None, None] * through_limit
        jacobian[..., 3:6, 3:9] += capped[..., None, None] * through_limit
        return self._folded(jacobian, states, lags[0], free_depth)

    def _limit_lag_gradient(self, unlimited: np.ndarray, acceleration: np.ndarray, lag: np.ndarray) -> np.ndarray:
        """d r / d[v, a] (..., 6) of :meth:`_limit_lag`'s finite ``lag`` r, for v and a (..., 3). Where the line
        crosses the limit, dr/dv = -w / (a . w) and dr/da = r dr/dv (w = v + a r, at the limit), the rate a . w
        kept above ``LIMIT_GRAZE`` |a| limit where the line grazes the ball (r turns on a square root there);
        where it passes outside, r = -(v . a) / |a|^2: dr/dv = -a / |a|^2 and dr/da = -(v + 2 r a) / |a|^2."""
        assert self.speed_limit is not None  # only a limited model reaches its limit
        square, _, discriminant = (term[..., None] for term in self._limit_crossing(unlimited, acceleration))
        crossing = discriminant > 0
        at_limit = unlimited + acceleration * lag[..., None]
        rising = np.einsum("...i,...i->...", acceleration, at_limit)[..., None]
        rate = np.maximum(rising, LIMIT_GRAZE * np.sqrt(square) * self.speed_limit)
        through = -at_limit / np.where(square > 0, rate, 1.0)
        safe_square = np.where(square > 0, square, 1.0)
        by_velocity = np.where(crossing, through, -acceleration / safe_square)
        passing = -(unlimited + 2 * lag[..., None] * acceleration) / safe_square
        by_acceleration = np.where(crossing, through * lag[..., None], passing)
        return np.concatenate([by_velocity, by_acceleration], axis=-1)

    def _kinematic_noise(self, dt: float) -> np.ndarray:
        return np.kron(_white_noise_blocks(dt, 3), np.eye(3)) * self.config.jerk_psd


class CoordinatedTurn(MotionModel):
    """CTRV written in Cartesian velocity: the horizontal velocity turns at omega, its norm is kept."""

    name, dim = "ctrv", 9

    def _advance(self, states: np.ndarray, dt: float | np.ndarray) -> np.ndarray:
        out = states.copy()
        step = np.asarray(dt)  # a scalar, or (..., 1) beside the states (see :meth:`MotionModel.trajectory`)
        turn_step = step[..., 0] if step.ndim else step
        displacement, velocity = coordinated_turn_displacement(states[..., 3:6], states[..., 6], turn_step)
        out[..., 0:3] += displacement
        out[..., 3:6] = velocity
        return out

    def _trajectory_jacobian(self, states: np.ndarray, lags: np.ndarray, free_depth: np.ndarray | None) -> np.ndarray:
        """:meth:`MotionModel.trajectory_jacobian`. With
        p(t) = p + D v, v(t) = B v (:func:`~aasl_gym.motion.coordinated_turn_displacement`:
        D = [[s, -c, 0], [c, s, 0], [0, 0, t]], B the rotation by omega t, s = sin(omega t) / omega,
        c = (1 - cos(omega t)) / omega), the omega column is dD/domega v and dB/domega v."""
        lags = np.asarray(lags, dtype=float)[None, :]
        turn = states[:, 6, None]
        angle = turn * lags
        cos_a, sin_a = np.cos(angle), np.sin(angle)
        small = np.abs(angle) < 1e-4
        safe = np.where(small, 1.0, turn)
        sine_term = small_angle_series(small, sin_a / safe, lambda a, t: t * (1 - a**2 / 6), angle, lags)
        cosine_term = small_angle_series(small, (1 - cos_a) / safe, lambda a, t: t * (a / 2 - a**3 / 24), angle, lags)
        # d s / d omega and d c / d omega, by their series where omega t is small.
        sine_rate = small_angle_series(small, (lags * cos_a - sine_term) / safe, lambda w, t: -w * t**3 / 3, turn, lags)
        cosine_rate = small_angle_series(
            small, (lags * sin_a - cosine_term) / safe, lambda w, t: t**2 / 2 - w**2 * t**4 / 8, turn, lags
        )
        vx, vy = states[:, 3, None], states[:, 4, None]
        jacobian = np.zeros(angle.shape + (6, 7))
        jacobian[..., [0, 1, 2], [0, 1, 2]] = 1.0
        jacobian[..., 0, 3], jacobian[..., 0, 4] = sine_term, -cosine_term
        jacobian[..., 1, 3], jacobian[..., 1, 4] = cosine_term, sine_term
        jacobian[..., 2, 5] = lags
        jacobian[..., 3, 3], jacobian[..., 3, 4] = cos_a, -sin_a
        jacobian[..., 4, 3], jacobian[..., 4, 4] = sin_a, cos_a
        jacobian[..., 5, 5] = 1.0
        jacobian[..., 0, 6] = sine_rate * vx - cosine_rate * vy
        jacobian[..., 1, 6] = cosine_rate * vx + sine_rate * vy
        jacobian[..., 3, 6] = -lags * (sin_a * vx + cos_a * vy)
        jacobian[..., 4, 6] = lags * (cos_a * vx - sin_a * vy)
        return self._folded(jacobian, states, lags[0], free_depth)

    def _kinematic_noise(self, dt: float) -> np.ndarray:
        q = np.zeros((7, 7))
        q[:6, :6] = np.kron(_white_noise_blocks(dt, 2), np.eye(3)) * self.config.acceleration_psd
        q[6, 6] = self.config.turn_rate_psd * dt
        return q


MOTION_MODELS: dict[str, type[MotionModel]] = {
    m.name: m for m in (ConstantVelocity, ConstantAcceleration, CoordinatedTurn)
}


def make_motion_model(
    config: FilterConfig,
    depth_bounds: tuple[float, float] | None = None,
    fold_trajectories: bool = False,
    speed_limit: float | None = None,
) -> MotionModel:
    """The filter's motion model (``config.motion_model``); ``speed_limit`` (m/s) is the top speed a
    constant acceleration stops at (:attr:`~aasl_gym.config.EnvConfig.filter_speed_limit`; None: none)."""
    return MOTION_MODELS[config.motion_model](config, depth_bounds, fold_trajectories, speed_limit)


def merwe_weights(n: int, alpha: float, beta: float, kappa: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Mean and covariance weights of the 2n+1 Merwe scaled sigma points, and the spread n + lambda."""
    lambda_ = alpha**2 * (n + kappa) - n
    spread = n + lambda_
    wm = np.full(2 * n + 1, 0.5 / spread)
    wc = wm.copy()
    wm[0] = lambda_ / spread
    wc[0] = lambda_ / spread + (1 - alpha**2 + beta)
    return wm, wc, spread


def merwe_sigma_points(x: np.ndarray, covariance: np.ndarray, spread: float) -> np.ndarray:
    """Sigma points x, x + sqrt((n + lambda) P)_i, x - sqrt((n + lambda) P)_i as rows, shape (2n+1, n).

    Raises ``numpy.linalg.LinAlgError`` when P is not positive definite.
    """
    root = np.linalg.cholesky(spread * covariance).T  # rows of the upper factor, as filterpy uses
    return np.concatenate([x[None, :], x + root, x - root])


def stacked(arrays: list[np.ndarray]) -> np.ndarray:
    """``np.stack(arrays)`` for a reader only: a lone array as a view of it (most steps carry one filter, and
    the copy's call cost more than the kernels' loops over it)."""
    return arrays[0][None] if len(arrays) == 1 else np.stack(arrays)


def predict_together(filters: Sequence[UnscentedKalmanFilter], dt: float) -> list[int]:
    """Predict ``filters`` (one motion model and one set of weights) ``dt`` seconds on as a batch, the sigma points and
    the moments compiled (:func:`aasl_gym.kernels.sigma_points`, :func:`aasl_gym.kernels.sigma_moments`; a CV bank
    without depth bounds all in one call, :func:`aasl_gym.kernels.constant_velocity_prediction`), each as its
    own :meth:`UnscentedKalmanFilter.predict` would; the indices of those that predicted. A filter whose covariance
    is not positive definite, before or after the prediction, is left out and left as it was (its mean and covariance
    not half predicted)."""
    if not filters:
        return []
    first = filters[0]
    model, spread = first.model, first.spread
    gaussians = stacked([f.x for f in filters]), stacked([f.P for f in filters])
    noise = model.process_noise(dt)
    if isinstance(model, ConstantVelocity) and model.depth_bounds is None:  # nothing reflects: one compiled call
        means, covariances, predicted_sigmas, valid = kernels.constant_velocity_prediction(
            *gaussians, spread, dt, first.Wm, first.Wc, noise
        )
    else:
        sigmas, valid = kernels.sigma_points(*gaussians, spread)
        means, covariances = kernels.sigma_moments(model.transition(sigmas, dt), first.Wm, first.Wc, noise)
        if model.depth_bounds is not None:
            reflected = [model.reflect(mean, covariance) for mean, covariance in zip(means, covariances)]
            means, covariances = (np.stack(parts) for parts in zip(*reflected))
        predicted_sigmas, predicted_valid = kernels.sigma_points(means, covariances, spread)
        valid = valid & predicted_valid
    kept = [i for i in range(len(filters)) if valid[i]]
    for i in kept:
        filters[i].x, filters[i].P, filters[i].sigmas_f = means[i], covariances[i], predicted_sigmas[i]
    return kept


def update_together(
    filters: Sequence[UnscentedKalmanFilter],
    sigma_values: np.ndarray,
    z: np.ndarray,
    noises: np.ndarray,
    period: float | None = None,
) -> list[int]:
    """Update predicted ``filters`` (one set of weights) with one measurement ``z`` as a batch, each as its own
    :meth:`UnscentedKalmanFilter.update` would: the model's values at each filter's sigma points ``sigma_values``
    (H, S, 2), each filter's R ``noises`` (H, 2, 2), the RD innovation modulo ``period`` where given. The indices of
    those that updated; a filter whose innovation covariance has no positive determinant is left as it was."""
    if not filters:
        return []
    first = filters[0]
    results = kernels.unscented_updates(
        stacked([f.sigmas_f for f in filters]),  # type: ignore[misc]  # set by predict()
        sigma_values, stacked([f.x for f in filters]), stacked([f.P for f in filters]), first.Wm, first.Wc,
        noises, z, period,
    )  # fmt: skip
    return [i for i, (f, *result) in enumerate(zip(filters, *results)) if f._take_update(*result)]


def whole_periods(
    measured: float, sigma_values: np.ndarray, ukf: UnscentedKalmanFilter, noise_variance: float, period: float
) -> float | None:
    """Whole periods between a value measured modulo ``period`` (unwrapped from an unknown start) and
    ``ukf``'s unscented prediction of it (the value at each sigma point, ``sigma_values``, plus
    ``noise_variance``); None where that prediction's sd exceeds a quarter period, too wide to tell."""
    mean = ukf.Wm @ sigma_values
    variance = ukf.Wc @ (sigma_values - mean) ** 2 + noise_variance
    if variance > (0.25 * period) ** 2:
        return None
    return float(np.round((measured - mean) / period))


class UnscentedKalmanFilter:
    """UKF with Merwe scaled sigma points, vectorized over the sigma points.

    ``model.transition(X, dt)`` and the ``hx`` given to :meth:`update` take all sigma points at once,
    ``X`` of shape (2n+1, n). Notation follows filterpy (x, P, Q, R, K, S, Wm, Wc).
    """

    def __init__(self, model: MotionModel, alpha: float = 0.5, beta: float = 2.0, kappa: float = 0.0):
        self.model = model
        self.dim_x = model.dim
        self.Wm, self.Wc, self.spread = merwe_weights(model.dim, alpha, beta, kappa)
        self.x = np.zeros(model.dim)
        self.P = np.eye(model.dim)
        self.sigmas_f: np.ndarray | None = None
        self.y = np.zeros(2)  # last innovation
        self.S = np.eye(2)  # last innovation covariance
        self.nis = 0.0  # normalized innovation squared of the last update (chi-square, 2 dof)
        self.log_likelihood = 0.0  # log N(y; 0, S) of the last update

    def initialize(self, x: np.ndarray, covariance: np.ndarray) -> None:
        self.x = np.array(x, dtype=float)
        self.P = np.array(covariance, dtype=float)
        self.sigmas_f = None

    def predict(self, dt: float) -> None:
        """Predict ``dt`` seconds on (:func:`predict_together` of this filter alone). Raises
        ``numpy.linalg.LinAlgError`` where the covariance is not positive definite."""
        if not predict_together([self], dt):
            raise np.linalg.LinAlgError("the covariance is not positive definite")

    def update(
        self,
        z: np.ndarray,
        R: np.ndarray,
        hx: Callable[[np.ndarray], np.ndarray],
        period: float | None = None,
    ) -> None:
        """Update with an [RD, RRD] measurement ``z`` and its noise R (2 x 2); the RD's innovation is taken modulo
        ``period`` (m) where given (filterpy's ``residual_z`` for a wrapped component). The sums over the sigma
        points, the gain and the new moments run compiled (:func:`aasl_gym.kernels.unscented_update`)."""
        if self.sigmas_f is None:
            raise RuntimeError("predict() must run before update()")
        sigmas_h = hx(self.sigmas_f)
        result = kernels.unscented_update(self.sigmas_f, sigmas_h, self.x, self.P, self.Wm, self.Wc, R, z, period)
        if not self._take_update(*result):
            raise np.linalg.LinAlgError("innovation covariance is not positive definite")

    def _take_update(
        self,
        det: float,
        x: np.ndarray,
        covariance: np.ndarray,
        nis: float,
        innovation: np.ndarray,
        innovation_covariance: np.ndarray,
    ) -> bool:
        """Take an update's results (:func:`aasl_gym.kernels.unscented_update`'s) where det S is positive; whether
        it was."""
        if not det > 0:
            return False
        self.x, self.P, self.nis, self.y, self.S = x, covariance, float(nis), innovation, innovation_covariance
        self.log_likelihood = -0.5 * (self.nis + math.log(det) + LOG_NORMALIZER_2D)
        return True

    def update_stacked(self, innovation: np.ndarray, deviations: np.ndarray, R: np.ndarray) -> float:
        """Update with a measurement of any size m, given its innovation (m,), the predicted measurement at
        the sigma points ``sigmas_f`` less its mean (2n+1, m) and its noise covariance R (m, m); returns the
        NIS. Leaves ``y``, ``S``, ``nis`` and ``log_likelihood`` (:meth:`update`'s) as they were. Raises
        ``numpy.linalg.LinAlgError`` when the innovation covariance is not positive definite."""
        if self.sigmas_f is None:
            raise RuntimeError("predict() must run before update_stacked()")
        covariance = (deviations.T * self.Wc) @ deviations + R
        covariance = 0.5 * (covariance + covariance.T)  # R may be a Schur complement, symmetric to rounding
        factor = np.linalg.cholesky(covariance)
        cross = ((self.sigmas_f - self.x).T * self.Wc) @ deviations
        gain = linalg.cho_solve((factor, True), cross.T).T
        self.x = self.x + gain @ innovation
        self.P = self.P - gain @ covariance @ gain.T
        self.P = 0.5 * (self.P + self.P.T)
        return float(innovation @ linalg.cho_solve((factor, True), innovation))
