"""Sliding-window MAP: the source state that best explains a whole window of measurements.

The tracker's unscented filters are the fast path; they commit to one Gaussian each. Where they need
a start, or stop explaining the data, :func:`fit_window` solves the window at once from several
starts: the state of the filter's own motion model at the window's *last* sample, run back along the
model over every sample, is fitted by Levenberg-Marquardt (batched over the starts) to

    sum_k rho(|W_k (z_k - h(x(t_k)) - b)|^2) + |(x - m) / s|^2

with ``W_k`` the whitener of R_eff at sample k for that start's own trajectory (the navigation term of
the model's receiver Jacobian), ``rho`` the identity or, for data the model explains only roughly
(multipath treated as noise), the soft-L1 loss ``2 (sqrt(1 + r^2) - 1)``, which lets a few samples
near an interference null disagree without dragging the fit. The RD residual is taken modulo the
wavelength where the burst says so (``Burst.residual_period``). The prior (mean ``m``, sd ``s``, an
infinite sd for none) keeps the velocity, the turn rate or acceleration and the biases plausible.

The Jacobian chains the measurement model's own (the direct path's and the frame-averaged phasor model's closed
forms; the geometric worlds' phasor model's, whose RRD's position columns are a central difference in time of the
RD's gradients) with the motion model's trajectory; a model without one (the first-order ``linear`` model) is
differenced over the whole window (a few dozen model evaluations per step, and 0.1 mm steps blur an interference
null). The information ``J^T W J`` at the solution is the covariance a filter restarts with.

Three routes, one algorithm. Under the direct path and the phasor models (frame-averaged, and a geometric world's
instantaneous one) one compiled pass per start gives the loss and the normal equations
(:func:`aasl_gym.kernels.fit_terms`); for a motion model whose free motion is one matrix for every state (CV, CA
without a speed limit) the pass also runs and folds the trajectories and the whole fit is compiled
(:func:`aasl_gym.kernels.fit`). The frame-averaged phasor model with fewer starts than one vector's worth
(``kernels.LANES``) and a model without a Jacobian of its own take NumPy's Levenberg-Marquardt and LAPACK's solve,
the phasor models' per-sample terms and chained Jacobian compiled (:func:`aasl_gym.kernels.window_terms`,
:func:`aasl_gym.kernels.whitened_chain`). The routes agree to rounding (``tests/test_window.py``). (Until session 32
the direct path kept the NumPy route, to keep the free-field studies' bits; compiled, a one-start re-seed fit on 260
samples takes 0.9 ms against 2.2. Until session 50 the geometric worlds' phasor model kept it too; compiled, the
geometric default world's fits take a quarter less time and its whole episodes run some 18 % faster.)

References: K. Madsen, H. B. Nielsen, O. Tingleff, "Methods for non-linear least squares problems",
2004 (the damping schedule); B. Triggs et al., "Bundle adjustment - a modern synthesis", 2000
(robust costs by iteratively reweighted least squares).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aasl_gym import kernels
from aasl_gym.filters import MotionModel
from aasl_gym.initializers import (
    Burst,
    periodic_residual,
    robust_loss,
    robust_weights,
    trajectory_whitener,
    whiten,
)
from aasl_gym.measurement_models import (
    FrameAveragedPhasor,
    PhasorModel,
    direct_measurement,
    state_jacobian_function,
)

STEP = 1e-4  # central-difference step in every state component (m, m/s, rad/s, m/s^2)
MAX_POSITION_STEP = 5.0  # m: far from its basin a linearization is poor; no step moves further


@dataclass(frozen=True)
class WindowFit:
    """Fitted states (C, n) at the window's last sample, their costs (C,) and information (C, n, n)."""

    states: np.ndarray
    costs: np.ndarray
    information: np.ndarray


def _trajectory(burst: Burst, model: MotionModel, states: np.ndarray) -> np.ndarray:
    """Each state (C, n), given at the burst's last sample, run back to every sample: (C, K, n), with the
    source's own velocity in 3:6 (:meth:`~aasl_gym.filters.MotionModel.source_trajectory`)."""
    return model.source_trajectory(states, burst.times - burst.times[-1])


def _measure(burst: Burst, trajectory: np.ndarray) -> np.ndarray:
    """h along trajectories (C, K, n), without their biases: (C, K, 2)."""
    mobile, mobile_velocity = burst.receiver_positions[None], burst.receiver_velocities[None]
    return burst.measurement_function(
        trajectory[..., 0:3], trajectory[..., 3:6], mobile, mobile_velocity, burst.fixed_position
    )


def _predictions(burst: Burst, trajectory: np.ndarray) -> np.ndarray:
    """h along trajectories (C, K, n) plus their biases: (C, K, 2)."""
    return _measure(burst, trajectory) + trajectory[..., -2:]


def _whiteners(burst: Burst, trajectory: np.ndarray) -> np.ndarray:
    return trajectory_whitener(burst, trajectory[..., 0:3], trajectory[..., 3:6])


def whitened_residuals(
    burst: Burst, model: MotionModel, states: np.ndarray, white: np.ndarray | None = None
) -> np.ndarray:
    """W_k (z_k - h(x(t_k)) - b) of each state (C, n) at every sample: (C, K, 2), the RD taken as the
    burst says (:func:`~aasl_gym.initializers.periodic_residual`), ``white`` each trajectory's own
    R_eff whitener. Without ``white`` they are the residuals a fit weighs its trial states with
    (:func:`_evaluate`)."""
    if white is None:
        return _evaluate(burst, model, states)[1].reshape(len(states), -1, 2)
    return _whitened(burst, white, _predictions(burst, _trajectory(burst, model, states)))


def _whitened(burst: Burst, white: np.ndarray, predictions: np.ndarray) -> np.ndarray:
    """W_k (z_k - prediction_k) (C, K, 2) for predictions (C, K, 2) with their biases, RD as the burst says."""
    return whiten(white, periodic_residual(burst.measurements[None] - predictions, burst))


def _evaluate(burst: Burst, model: MotionModel, states: np.ndarray):
    """At states (C, n): the R_eff whiteners (C, K, 2, 2), the whitened measurement residuals (C, 2K)
    and, where the measurement model hands them over with its values (a ``linearize`` method, which
    shares one set of multipath factors between the three), d[RD, RRD]/d[p, v] along each
    trajectory (C, K, 2, 6); else None, and :func:`_jacobian` evaluates the model again.

    A model with a ``linearize`` method (the phasor models) takes the compiled per-sample terms
    (:func:`aasl_gym.kernels.window_terms`); the direct path keeps the NumPy form here. A fit of the direct path or of
    the phasor models takes the compiled pass instead (:func:`_compiled_model`); this form serves the window chi-square
    (:func:`whitened_residuals`), the few-start frame-model fits and the tests' reference route."""
    trajectory = _trajectory(burst, model, states)
    linearize = getattr(burst.measurement_function, "linearize", None)
    if linearize is None:
        white, predictions = _whiteners(burst, trajectory), _predictions(burst, trajectory)
        return white, _whitened(burst, white, predictions).reshape(len(states), -1), None
    mobile, mobile_velocity = burst.receiver_positions[None], burst.receiver_velocities[None]
    values, local, receiver = linearize(
        trajectory[..., 0:3], trajectory[..., 3:6], mobile, mobile_velocity, burst.fixed_position
    )
    white, residual = kernels.window_terms(
        values,
        receiver,
        states[:, -2:],  # the biases stay constant along a trajectory
        burst.measurements,
        burst.noise_covariance,
        burst.navigation_sd,
        burst.residual_period,
    )
    return white, residual.reshape(len(states), -1), local


def _jacobian(burst, model, states, white, local=None) -> np.ndarray:
    """d(whitened prediction) / d state: (C, 2K, n), chained from the measurement model's own closed
    form where it has one (``local``, if already evaluated along the trajectories; :func:`_chained_jacobian`),
    else by differences (:func:`_difference_jacobian`)."""
    if local is None:
        local_jacobian = state_jacobian_function(burst.measurement_function)
        if local_jacobian is None:
            return _difference_jacobian(burst, model, states, white)
        centre = _trajectory(burst, model, states)
        local = local_jacobian(
            centre[..., 0:3],
            centre[..., 3:6],
            burst.receiver_positions[None],
            burst.receiver_velocities[None],
            burst.fixed_position,
        )  # (C, K, 2, 6)
    return _chained_jacobian(burst, model, states, white, local)


def _chained_jacobian(burst, model, states, white, local) -> np.ndarray:
    """The measurement model's d[RD, RRD]/d[p, v] along each trajectory (``local``, (C, K, 2, 6), closed
    form), chained with d[p, v](t_k)/d state of the motion model (its
    :meth:`~aasl_gym.filters.MotionModel.trajectory_jacobian`), whitened: (C, 2K, n). The biases add to
    the prediction and stay constant along a trajectory: their columns are unit vectors. Compiled
    (:func:`aasl_gym.kernels.whitened_chain`) for a model with a ``linearize`` method, as in :func:`_evaluate`."""
    count, dim = states.shape
    moving = dim - 2
    motion = model.trajectory_jacobian(states, burst.times - burst.times[-1])  # (C, K, 6, moving)
    if hasattr(burst.measurement_function, "linearize"):
        return kernels.whitened_chain(local, motion, white).reshape(count, -1, dim)
    jacobian = np.zeros(local.shape[:-1] + (dim,))
    jacobian[..., :moving] = local @ motion
    jacobian[..., 0, dim - 2] = jacobian[..., 1, dim - 1] = 1.0
    return (white @ jacobian).reshape(count, -1, dim)  # W_k J_k


def _difference_jacobian(burst, model, states, white) -> np.ndarray:
    """d(whitened prediction) / d state by central differences: (C, 2K, n). Differences of the RD are
    taken modulo the wavelength, so that a branch cut of the phasor model is no slope.

    Every shifted state goes through the model in one batch. A shift of a bias (the last two
    components) moves no trajectory, so h there is h at the states themselves, evaluated once."""
    count, dim = states.shape
    moving = dim - 2  # the components that move the trajectory
    shift = STEP * np.eye(dim)[:moving, None, :]  # (moving, 1, n)
    shifted = np.concatenate([(states + shift).reshape(-1, dim), (states - shift).reshape(-1, dim), states])
    trajectory = _trajectory(burst, model, shifted)
    z = _measure(burst, trajectory)
    predicted = (z + trajectory[..., -2:])[: 2 * moving * count].reshape(2, moving, count, -1, 2)
    differences = list(predicted[0] - predicted[1])
    unbiased = z[2 * moving * count :]
    for j in range(moving, dim):
        bias_shift = STEP * np.eye(dim)[j]
        ahead, behind = (unbiased + _trajectory(burst, model, states + sign * bias_shift)[..., -2:] for sign in (1, -1))
        differences.append(ahead - behind)
    columns = [
        whiten(white, periodic_residual(difference, burst) / (2 * STEP)).reshape(count, -1)
        for difference in differences
    ]
    return np.stack(columns, axis=-1)


def _numpy_terms(burst: Burst, model: MotionModel, states: np.ndarray, robust: bool):
    """At states (C, n): the loss sum_k rho(|W_k r_k|^2) (C,) and a function of a selection of the states that gives
    their J^T V J (., n, n) and J^T V W r (., n), V the IRLS weights of the current residuals (soft-L1's, or ones),
    from :func:`_evaluate` and :func:`_jacobian`. A fit needs the Jacobian only where it accepts a step."""
    white, measurement, local = _evaluate(burst, model, states)

    def normal_equations(rows):
        jacobian = _jacobian(burst, model, states[rows], white[rows], None if local is None else local[rows])
        weights = robust_weights(measurement[rows], robust)
        # A batched matrix product: numpy's three-operand einsum does not reach BLAS and costs ten times more.
        normal = np.swapaxes(jacobian * weights[..., None], 1, 2) @ jacobian
        return normal, ((weights * measurement[rows])[:, None, :] @ jacobian)[:, 0]

    return np.sum(robust_loss(measurement**2, robust), axis=1), normal_equations


def _compiled_model(burst: Burst, count: int) -> bool:
    """Whether a fit of ``count`` starts on ``burst`` takes the compiled pass: the direct path and a geometric world's
    phasor model always, the frame-averaged phasor model from one vector's worth of starts (``kernels.LANES``). With
    fewer, NumPy, which vectorises across the samples too, runs the frame model faster (two starts along a 500-sample
    track: 0.35 against 0.6 ms a pass). The direct path is cheap enough, and the instantaneous phasor model's NumPy
    form (three passes of the model and their arrays) dear enough, that the pass wins even for one start, which then
    runs alone, unpadded (:func:`aasl_gym.kernels.fit`, or :func:`aasl_gym.kernels.fit_terms` for CTRV and a
    speed-limited CA; session 50, timers on seeds 0-3 with a study running beside them: the geometric default world's
    track checks, whose fits have one or two starts, 583 -> 324 us a step against the pass from eight starts only)."""
    model = burst.measurement_function
    if model is direct_measurement or isinstance(model, PhasorModel):
        return True
    return isinstance(model, FrameAveragedPhasor) and count >= kernels.LANES


def _model_data(burst: Burst, robust: bool) -> tuple:
    """What the compiled pass (:func:`aasl_gym.kernels.fit_terms`) reads of a burst, in its order."""
    model = burst.measurement_function
    offsets, propagation = None, None  # the direct path's
    if isinstance(model, FrameAveragedPhasor):
        offsets, propagation = model.offsets, model.propagation
    elif isinstance(model, PhasorModel):  # an instantaneous model: no frame offsets
        propagation = model.propagation
    else:
        assert model is direct_measurement  # the models the pass knows
    return (
        (burst.receiver_positions, burst.receiver_velocities),
        burst.fixed_position,
        offsets,
        propagation,
        burst.measurements,
        burst.noise_covariance,
        burst.navigation_sd,
        burst.residual_period,
        robust,
    )


def _compiled_terms(burst: Burst, model: MotionModel, states: np.ndarray, robust: bool):
    """:func:`_numpy_terms` in one compiled pass (:func:`aasl_gym.kernels.fit_terms`) for the direct path or a phasor
    model (:func:`_compiled_model`): the normal equations come with the loss, for every state."""
    lags = burst.times - burst.times[-1]
    motion, trajectory = model.free_motion_matrix(lags), None
    if motion is None:  # the pass cannot run the states along the model itself
        trajectory, motion = model.trajectory_terms(states, lags)
    loss, normal, pull = kernels.fit_terms(states, motion, trajectory, model.fold_bounds, *_model_data(burst, robust))
    return loss, lambda rows: (normal[rows], pull[rows])


def _lapack_steps(normal: np.ndarray, damping: np.ndarray, gradient: np.ndarray) -> np.ndarray:
    """:func:`aasl_gym.kernels.damped_steps` by ``np.linalg.solve``."""
    scale = np.diagonal(normal, axis1=1, axis2=2)
    return -np.linalg.solve(
        normal + damping[:, None, None] * scale[:, None, :] * np.eye(normal.shape[-1]), gradient[..., None]
    )[..., 0]


def fit_window(
    burst: Burst,
    model: MotionModel,
    states: np.ndarray,
    prior_mean: np.ndarray,
    prior_sd: np.ndarray,
    robust: bool = False,
    iterations: int = 8,
) -> WindowFit:
    """Levenberg-Marquardt from each of ``states`` (C, n), the filter's layout at ``burst.times[-1]``.

    ``prior_mean`` (C, n) or (n,), ``prior_sd`` (n,), ``np.inf`` where a component has no prior. The
    whiteners follow each start's trajectory and are recomputed every iteration; the robust weights
    (soft-L1) are those of the current residuals (iteratively reweighted least squares). The route (see the
    module's note) follows the burst's measurement model, the motion model and the number of starts.
    """
    compiled = _compiled_model(burst, len(states))
    motion = model.free_motion_matrix(burst.times - burst.times[-1]) if compiled else None
    if motion is not None:  # the pass runs the states along the model itself: the whole fit is compiled
        prior_mean = np.broadcast_to(prior_mean, np.shape(states))
        data = _model_data(burst, robust)
        return WindowFit(
            *kernels.fit(states, prior_mean, prior_sd, motion, model.fold_bounds, data, iterations, MAX_POSITION_STEP)
        )
    return _fit_loop(burst, model, states, prior_mean, prior_sd, robust, iterations, compiled)


def _fit_loop(burst, model, states, prior_mean, prior_sd, robust, iterations, compiled) -> WindowFit:
    """:func:`fit_window`'s Levenberg-Marquardt in NumPy over the compiled pass's terms (``compiled``) or NumPy's."""
    terms = _compiled_terms if compiled else _numpy_terms
    damped_steps = kernels.damped_steps if compiled else _lapack_steps
    states = np.array(states, dtype=float)
    prior_mean = np.broadcast_to(prior_mean, states.shape)
    prior_information = np.diag(1 / prior_sd**2)
    damping = np.full(len(states), 1e-3)
    loss, normal_equations = terms(burst, model, states, robust)
    data, pull = normal_equations(slice(None))
    prior = (states - prior_mean) / prior_sd
    cost = loss + np.sum(prior**2, axis=1)
    for _ in range(iterations):
        normal = data + prior_information
        # The residuals fall as the predictions rise: their gradient carries -J.
        gradient = prior / prior_sd - pull
        step = damped_steps(normal, damping, gradient)
        step *= np.minimum(1.0, MAX_POSITION_STEP / np.maximum(np.linalg.norm(step[:, 0:3], axis=1), 1e-12))[:, None]
        trial = states + step
        trial_loss, trial_normal_equations = terms(burst, model, trial, robust)
        trial_prior = (trial - prior_mean) / prior_sd
        trial_cost = trial_loss + np.sum(trial_prior**2, axis=1)
        better = trial_cost < cost
        states[better], cost[better], prior[better] = trial[better], trial_cost[better], trial_prior[better]
        damping = np.where(better, damping / 3, damping * 4)
        if better.any():
            data[better], pull[better] = trial_normal_equations(better)
    return WindowFit(states, cost, data + prior_information)
