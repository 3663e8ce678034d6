"""Property-based tests (Hypothesis) of the geometry and the filter's measurement models on random
states: the triangle inequality, the Jacobians against central differences, RRD as the time derivative
of RD, the sign conventions of the contract. Derandomized (``conftest.py``): the same cases every run."""

from functools import partial

import numpy as np
from hypothesis import assume, given, strategies as st

from aasl_gym import geometry
from aasl_gym.fisher import measurement_jacobian
from aasl_gym.measurement_models import (
    FrameAveragedPhasor,
    Propagation,
    direct_measurement,
    frame_averaged,
    frame_offsets,
    multipath_measurement,
    phasor_range_difference,
    receiver_jacobian,
)

FIXED = np.array([0.0, 0.0, -0.96])
PROPAGATION = Propagation(60.0, -0.9, 0.3, 2 * np.pi / 1.5)
PHASOR = partial(multipath_measurement, "phasor", PROPAGATION)


def vectors(low, high):
    """3-vectors with each coordinate in [low, high] (scalars or per-axis lists)."""
    low, high = np.broadcast_to(low, 3), np.broadcast_to(high, 3)
    return st.tuples(*(st.floats(float(a), float(b), allow_nan=False) for a, b in zip(low, high))).map(np.array)


SOURCES = vectors([-60, -60, -58], [60, 60, -1.5])  # in the 60 m water column, below the surface
MOBILES = vectors([-30, -30, -20], [30, 30, -2])
VELOCITIES = vectors(-2, 2)


def apart(*points, distance=1.0) -> bool:
    """Every pair of ``points`` at least ``distance`` metres apart (the models are singular at a receiver)."""
    return all(np.linalg.norm(a - b) >= distance for i, a in enumerate(points) for b in points[i + 1 :])


@given(SOURCES, MOBILES)
def test_range_difference_is_bounded_by_the_baseline(source, mobile):
    """Triangle inequality: |RD| = ||p - p_m| - |p - p_f|| <= |p_m - p_f|."""
    assume(apart(source, mobile, FIXED))
    rd = geometry.range_difference(source, mobile, FIXED)
    assert abs(rd) <= np.linalg.norm(mobile - FIXED) + 1e-9


@given(SOURCES, VELOCITIES, MOBILES, VELOCITIES)
def test_swapping_the_hydrophones_negates_rd_and_rrd(source, velocity, mobile, mobile_velocity):
    """RD and RRD are differences mobile minus fixed: exchanging the receivers (with their velocities)
    changes their sign."""
    assume(apart(source, mobile, FIXED))
    forward = geometry.range_rate_difference(source, velocity, mobile, mobile_velocity, FIXED)
    backward = geometry.range_rate_difference(source, velocity, FIXED, np.zeros(3), mobile, mobile_velocity)
    assert np.isclose(forward, -backward, atol=1e-12)
    assert np.isclose(
        geometry.range_difference(source, mobile, FIXED), -geometry.range_difference(source, FIXED, mobile)
    )


@given(SOURCES, VELOCITIES, MOBILES, VELOCITIES)
def test_rrd_is_the_time_derivative_of_rd(source, velocity, mobile, mobile_velocity):
    """Source and robot moving straight on, the fixed hydrophone still: RRD = d RD / dt (central
    difference over +-1 ms)."""
    assume(apart(source, mobile, FIXED))
    step = 1e-3

    def rd(time):
        return geometry.range_difference(source + velocity * time, mobile + mobile_velocity * time, FIXED)

    derivative = (rd(step) - rd(-step)) / (2 * step)
    rrd = geometry.range_rate_difference(source, velocity, mobile, mobile_velocity, FIXED)
    assert np.isclose(rrd, derivative, atol=1e-5)


@given(SOURCES, VELOCITIES, MOBILES, VELOCITIES)
def test_the_direct_jacobian_matches_central_differences(source, velocity, mobile, mobile_velocity):
    """d[RD, RRD] / d[p, v] in closed form against central differences of the direct model."""
    assume(apart(source, mobile, FIXED))
    state = np.concatenate([source, velocity])
    step = 1e-5
    numeric = np.empty((2, 6))
    for i in range(6):
        plus, minus = state.copy(), state.copy()
        plus[i] += step
        minus[i] -= step
        numeric[:, i] = (
            direct_measurement(plus[:3], plus[3:], mobile, mobile_velocity, FIXED)
            - direct_measurement(minus[:3], minus[3:], mobile, mobile_velocity, FIXED)
        ) / (2 * step)
    closed = geometry.direct_jacobian(source, velocity, mobile, mobile_velocity, FIXED)
    np.testing.assert_allclose(closed, numeric, atol=1e-6)
    # The information's Jacobian adds the two biases, each with unit gain.
    full = measurement_jacobian(source, velocity, mobile, mobile_velocity, FIXED)
    np.testing.assert_allclose(full[:, :6], closed)
    np.testing.assert_array_equal(full[:, 6:], np.eye(2))


@given(SOURCES, VELOCITIES, MOBILES, VELOCITIES)
def test_the_receiver_jacobian_matches_central_differences(source, velocity, mobile, mobile_velocity):
    """d[RD, RRD] / d[p_m, v_m] of the direct path (closed form) against central differences of the model."""
    assume(apart(source, mobile, FIXED))
    step = 1e-5
    numeric = np.empty((2, 6))
    for i in range(6):
        offset = np.zeros(6)
        offset[i] = step
        plus = direct_measurement(source, velocity, mobile + offset[:3], mobile_velocity + offset[3:], FIXED)
        minus = direct_measurement(source, velocity, mobile - offset[:3], mobile_velocity - offset[3:], FIXED)
        numeric[:, i] = (plus - minus) / (2 * step)
    np.testing.assert_allclose(
        receiver_jacobian(direct_measurement, source, velocity, mobile, mobile_velocity, FIXED), numeric, atol=1e-6
    )


@given(SOURCES, VELOCITIES, MOBILES, VELOCITIES)
def test_the_phasor_rrd_is_the_time_derivative_of_its_rd(source, velocity, mobile, mobile_velocity):
    """With reflections the apparent RRD is still d RD_app / dt: the RD's central difference over
    +-0.1 ms, taken modulo one wavelength (the phasor RD is continuous only up to whole periods)."""
    assume(apart(source, mobile, FIXED, distance=2.0))
    step = 1e-4

    def rd(time):
        return PHASOR(source + velocity * time, velocity, mobile + mobile_velocity * time, mobile_velocity, FIXED)[0]

    difference = geometry.wrap_to_period(rd(step) - rd(-step), 1.5)
    rrd = PHASOR(source, velocity, mobile, mobile_velocity, FIXED)[1]
    # Near an interference null the apparent RD curves sharply: allow a share of the rate's size.
    assert np.isclose(rrd, difference / (2 * step), atol=1e-3, rtol=1e-2)


@given(SOURCES, VELOCITIES, MOBILES, VELOCITIES)
def test_without_images_every_model_is_the_direct_path(source, velocity, mobile, mobile_velocity):
    """Reflection coefficients of zero: the phasor and linear models are the direct path, and so is the
    frame average of a model that is linear in time to the eye of a 0.2 s frame."""
    assume(apart(source, mobile, FIXED))
    silent = Propagation(60.0, 0.0, 0.0, PROPAGATION.wavenumber)
    direct = direct_measurement(source, velocity, mobile, mobile_velocity, FIXED)
    for model in ("phasor", "linear"):
        np.testing.assert_allclose(
            multipath_measurement(model, silent, source, velocity, mobile, mobile_velocity, FIXED), direct, atol=1e-9
        )
    averaged = frame_averaged(
        partial(phasor_range_difference, silent),
        frame_offsets(0.2, 3),
        PROPAGATION.wavenumber,
        source,
        velocity,
        mobile,
        mobile_velocity,
        FIXED,
    )
    # Over +-0.1 s the direct RD curves by at most (relative speed)^2 t^2 / range: millimetres.
    np.testing.assert_allclose(averaged, direct, atol=2e-2)


@given(SOURCES, VELOCITIES, MOBILES, VELOCITIES)
def test_the_compiled_rd_is_the_phasor_models_rd(source, velocity, mobile, mobile_velocity):
    """The RD-only phasor model (a compiled loop, :mod:`aasl_gym.kernels`) against the full model written with
    NumPy's complex-free array arithmetic (:func:`geometry.phasor_multipath`): two implementations of one
    formula. Modulo a wavelength: where a receiver's phase sits on its branch cut (+-pi) the two may round to
    either side of it."""
    assume(apart(source, mobile, FIXED))
    full = PHASOR(source, velocity, mobile, mobile_velocity, FIXED)[0]
    difference = geometry.wrap_to_period(phasor_range_difference(PROPAGATION, source, mobile, FIXED) - full, 1.5)
    assert abs(difference) < 1e-9


FRAME = FrameAveragedPhasor(PROPAGATION, frame_offsets(0.2, 3))


def central_differences(model, arguments, index, step):
    """d model / d arguments[index:index + 2] (a position and its rate, six columns) by central
    differences, the RD's taken modulo one wavelength: (2, 6); None across a branch of the wrapped phase
    (a difference of a sizeable share of a wavelength)."""
    columns = []
    for i in range(6):
        plus, minus = list(arguments), list(arguments)
        which, axis = index + i // 3, i % 3
        plus[which], minus[which] = arguments[which].copy(), arguments[which].copy()
        plus[which][axis] += step
        minus[which][axis] -= step
        difference = model(*plus) - model(*minus)
        difference[0] = geometry.wrap_to_period(difference[0], 1.5)
        if np.any(np.abs(difference) > 0.1):
            return None
        columns.append(difference / (2 * step))
    return np.stack(columns, axis=-1)


@given(SOURCES, VELOCITIES, MOBILES, VELOCITIES)
def test_the_phasor_rd_gradients_match_central_differences(source, velocity, mobile, mobile_velocity):
    """The apparent RD's gradients in the source's and the mobile's position (closed form, through the
    images' phases) against central differences of :func:`geometry.phasor_range_difference`."""
    assume(apart(source, mobile, FIXED, distance=2.0))
    p = PROPAGATION
    arguments = (p.water_depth, p.surface_reflection, p.bed_reflection, p.wavenumber)
    _, source_gradient, mobile_gradient = geometry.phasor_range_difference_linearized(source, mobile, FIXED, *arguments)
    step = 1e-6
    for gradient, moved in ((source_gradient, 0), (mobile_gradient, 1)):
        for axis in range(3):
            points = [source.copy(), mobile.copy()]
            points[moved][axis] += step
            ahead = geometry.phasor_range_difference(*points, FIXED, *arguments)
            points[moved][axis] -= 2 * step
            behind = geometry.phasor_range_difference(*points, FIXED, *arguments)
            difference = geometry.wrap_to_period(ahead - behind, 1.5)
            assume(abs(difference) < 0.1)
            assert np.isclose(gradient[axis], difference / (2 * step), atol=1e-5, rtol=1e-4)


@given(SOURCES, VELOCITIES, MOBILES, VELOCITIES)
def test_the_frame_models_jacobians_match_central_differences(source, velocity, mobile, mobile_velocity):
    """The frame model's d[RD, RRD]/d[p, v] and d[RD, RRD]/d[p_m, v_m] in closed form against central
    differences of the model itself (a frame carries both across 0.2 s, so the velocities enter both)."""
    assume(apart(source, mobile, FIXED, distance=2.0))
    arguments = (source, velocity, mobile, mobile_velocity, FIXED)
    for closed, index in ((FRAME.state_jacobian(*arguments), 0), (receiver_jacobian(FRAME, *arguments), 2)):
        numeric = central_differences(FRAME, arguments, index, 1e-6)
        assume(numeric is not None)
        np.testing.assert_allclose(closed, numeric, atol=1e-4, rtol=1e-4)


@given(SOURCES, VELOCITIES, MOBILES, VELOCITIES)
def test_the_compiled_frame_model_is_frame_averaged(source, velocity, mobile, mobile_velocity):
    """The measurement-function class (one compiled pass, :func:`aasl_gym.kernels.frame_phasor`) against
    :func:`frame_averaged` (the frame's unwrapping, mean and slope written with NumPy) of the RD-only phasor
    model; the RD modulo a wavelength (a sample on a branch cut may round to either side). Its values, state
    Jacobian and receiver Jacobian are the three arrays of one linearization."""
    assume(apart(source, mobile, FIXED))
    generic = partial(
        frame_averaged, partial(phasor_range_difference, PROPAGATION), FRAME.offsets, PROPAGATION.wavenumber
    )
    arguments = (source, velocity, mobile, mobile_velocity, FIXED)
    difference = FRAME(*arguments) - generic(*arguments)
    difference[0] = geometry.wrap_to_period(difference[0], 1.5)
    np.testing.assert_allclose(difference, 0.0, atol=1e-8)
    values, state_jacobian, mobile_jacobian = FRAME.linearize(*arguments)
    np.testing.assert_array_equal(values, FRAME(*arguments))
    np.testing.assert_array_equal(state_jacobian, FRAME.state_jacobian(*arguments))
    np.testing.assert_array_equal(mobile_jacobian, FRAME.receiver_jacobian(*arguments))


@given(SOURCES, VELOCITIES, MOBILES, VELOCITIES)
def test_receiver_differences_agree_with_the_frame_models_closed_form(source, velocity, mobile, mobile_velocity):
    """The receiver Jacobian by differences (what models without a closed form get, with its 1 mm and
    1 mm/s steps) against the frame model's closed form: two implementations of one derivative."""
    assume(apart(source, mobile, FIXED, distance=2.0))
    generic = partial(
        frame_averaged, partial(phasor_range_difference, PROPAGATION), FRAME.offsets, PROPAGATION.wavenumber
    )
    arguments = (source, velocity, mobile, mobile_velocity, FIXED)
    assume(central_differences(FRAME, arguments, 2, 1e-3) is not None)  # not across a branch at the wider step
    np.testing.assert_allclose(
        receiver_jacobian(generic, *arguments), receiver_jacobian(FRAME, *arguments), atol=2e-3, rtol=2e-2
    )
