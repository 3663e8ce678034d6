"""The compiled loops (:mod:`aasl_gym.kernels`) against NumPy: the sine and cosine against the C library's,
the phasor model's batched shapes against one point at a time, a window fit's per-sample terms against
their NumPy forms, and the tone's compiled envelope against its NumPy form (to the last bit)."""

import numba
import numpy as np
import pytest

from aasl_gym import geometry, kernels, synthesis
from aasl_gym.config import FilterConfig
from aasl_gym.filters import ConstantVelocity, merwe_weights
from aasl_gym.initializers import inverse_cholesky, whiten
from aasl_gym.measurement_models import (
    FrameAveragedPhasor,
    Propagation,
    direct_measurement,
    direct_receiver_jacobian,
    frame_offsets,
    receiver_noise,
)

PROPAGATION = Propagation(60.0, -0.9, 0.3, 2 * np.pi / 1.5)
FIXED = np.array([0.0, 0.0, -0.96])


@pytest.mark.parametrize("bound", [1.0, 800.0, kernels.SINCOS_LIMIT])
def test_sincos_is_within_two_units_in_the_last_place_of_numpy(bound):
    """Polynomial sine and cosine against ``np.sin`` and ``np.cos`` (the C library's) over [-bound, bound]:
    an absolute error of at most 2^-53 * 2, which is 2 ulp at values near 1 and less below."""
    angles = np.random.default_rng(0).uniform(-bound, bound, 200_000)
    sine, cosine = kernels.sincos(angles)
    assert np.max(np.abs(sine - np.sin(angles))) <= 2.3e-16
    assert np.max(np.abs(cosine - np.cos(angles))) <= 2.3e-16


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")  # sin(inf) is NaN, as it should be
def test_sincos_keeps_the_shape_and_hands_what_it_cannot_reduce_to_numpy():
    """Beyond ``SINCOS_LIMIT`` (where the three-part reduction stops being exact) and for NaN or inf, the
    result is NumPy's to the last bit."""
    angles = np.array([[0.0, 1e7, -3e9], [np.pi, np.nan, np.inf]])
    sine, cosine = kernels.sincos(angles)
    assert sine.shape == cosine.shape == angles.shape
    np.testing.assert_array_equal(sine, np.sin(angles))
    np.testing.assert_array_equal(cosine, np.cos(angles))
    assert kernels.sincos(np.zeros((0, 3)))[0].shape == (0, 3)


def test_the_phasor_loops_broadcast_like_one_point_at_a_time():
    """A batch (sources (4, 5, 3) against one mobile) gives each point what it gives alone."""
    rng = np.random.default_rng(1)
    sources, mobile = rng.uniform([-30, -30, -59], [30, 30, -1], (4, 5, 3)), np.array([12.0, -3.0, -7.0])
    arguments = (PROPAGATION.water_depth, PROPAGATION.surface_reflection, PROPAGATION.bed_reflection)
    batch = geometry.phasor_range_difference_linearized(sources, mobile, FIXED, *arguments, PROPAGATION.wavenumber)
    for index in np.ndindex(4, 5):
        alone = geometry.phasor_range_difference_linearized(
            sources[index], mobile, FIXED, *arguments, PROPAGATION.wavenumber
        )
        for batched, single in zip(batch, alone):
            np.testing.assert_allclose(batched[index], single, rtol=0, atol=1e-12)
    frame = FrameAveragedPhasor(PROPAGATION, frame_offsets(0.2, 3))
    velocities = rng.uniform(-1.5, 1.5, (4, 5, 3))
    values, state_jacobian, _ = frame.linearize(sources, velocities, mobile, np.array([1.0, 0.0, 0.0]), FIXED)
    assert values.shape == (4, 5, 2) and state_jacobian.shape == (4, 5, 2, 6)
    one = frame.linearize(sources[2, 3], velocities[2, 3], mobile, np.array([1.0, 0.0, 0.0]), FIXED)
    np.testing.assert_allclose(values[2, 3], one[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(state_jacobian[2, 3], one[1], rtol=0, atol=1e-12)


@pytest.mark.parametrize("shape", [(), (300,), (6, 50)], ids=["point", "batch", "grid"])
def test_the_compiled_phasor_measurement_is_the_numpy_model(shape):
    """The phasor model's [RD, RRD] from the compiled pass (the RRD as the RD's gradients along both velocities)
    against NumPy's, which differentiates each receiver's phase in time: two forms of one model, to rounding (the RD
    modulo a wavelength: a receiver's phase can round to either side of its branch cut)."""
    rng = np.random.default_rng(5)
    source, mobile = rng.uniform([-30, -30, -58], [30, 30, -1], (2,) + shape + (3,))
    velocity, mobile_velocity = rng.uniform(-1.5, 1.5, (2,) + shape + (3,))
    p = PROPAGATION
    channel = (p.water_depth, p.surface_reflection, p.bed_reflection, p.wavenumber)
    measured = kernels.phasor_measurement(source, velocity, mobile, mobile_velocity, FIXED, *channel)
    rd, rrd = geometry.phasor_multipath(source, velocity, mobile, mobile_velocity, FIXED, *channel)
    assert measured.shape == shape + (2,)
    wavelength = 2 * np.pi / p.wavenumber
    np.testing.assert_allclose(geometry.wrap_to_period(measured[..., 0] - rd, wavelength), 0.0, atol=1e-11)
    np.testing.assert_allclose(measured[..., 1], rrd, rtol=1e-9, atol=1e-11)


def test_the_compiled_phasor_rrd_is_the_rate_of_its_rd():
    """The source and the robot moved +-1 us along their velocities: the compiled RRD is the central difference of the
    compiled RD (an independent check of the rate's formula, the fixed hydrophone still); a source and a robot at rest
    give no rate; one source against many robots gives each robot what it gives alone."""
    rng = np.random.default_rng(6)
    source, mobile = rng.uniform([-30, -30, -58], [30, 30, -1], (2, 200, 3))
    velocity, mobile_velocity = rng.uniform(-1.5, 1.5, (2, 200, 3))
    p = PROPAGATION
    channel = (p.water_depth, p.surface_reflection, p.bed_reflection, p.wavenumber)

    def rd(step):
        return kernels.phasor_measurement(
            source + step * velocity, velocity, mobile + step * mobile_velocity, mobile_velocity, FIXED, *channel
        )[..., 0]

    step = 1e-6
    rate = kernels.phasor_measurement(source, velocity, mobile, mobile_velocity, FIXED, *channel)[..., 1]
    difference = geometry.wrap_to_period(rd(step) - rd(-step), 2 * np.pi / p.wavenumber) / (2 * step)
    np.testing.assert_allclose(rate, difference, atol=2e-5)
    still = kernels.phasor_measurement(source, 0 * velocity, mobile, 0 * mobile_velocity, FIXED, *channel)
    np.testing.assert_array_equal(still[..., 1], 0.0)
    one = kernels.phasor_measurement(source[0], velocity[0], mobile, mobile_velocity, FIXED, *channel)
    np.testing.assert_array_equal(
        one[7], kernels.phasor_measurement(source[0], velocity[0], mobile[7], mobile_velocity[7], FIXED, *channel)
    )


@pytest.mark.parametrize("shape", [(), (400,), (8, 50)], ids=["point", "batch", "grid"])
def test_the_phasor_models_jacobians_are_its_differences(shape):
    """:func:`kernels.phasor_linearized`: the values are the compiled model's to the last bit, and both Jacobians are
    central differences of that model (1e-6 m or m/s in each of p, v, p_m, v_m apart; the RD taken modulo a
    wavelength) - an independent check of the RRD's position columns, which the function takes as the time
    derivative of the RD's gradients. Near an interference null the RD's curvature makes both differences err;
    elsewhere they agree to 1e-6 or better."""
    rng = np.random.default_rng(8)
    source, mobile = rng.uniform([-30, -30, -58], [30, 30, -1], (2,) + shape + (3,))
    velocity, mobile_velocity = rng.uniform(-1.5, 1.5, (2,) + shape + (3,))
    p = PROPAGATION
    channel = (p.water_depth, p.surface_reflection, p.bed_reflection, p.wavenumber)
    values, local, receiver = kernels.phasor_linearized(source, velocity, mobile, mobile_velocity, FIXED, *channel)
    assert values.shape == shape + (2,) and local.shape == receiver.shape == shape + (2, 6)
    measured = kernels.phasor_measurement(source, velocity, mobile, mobile_velocity, FIXED, *channel)
    assert np.array_equal(values, measured)
    state = [source, velocity, mobile, mobile_velocity]
    step = 1e-6
    for jacobian, first in ((local, 0), (receiver, 2)):
        for column in range(6):
            ahead, behind = [list(state), list(state)]
            shift = step * np.eye(3)[column % 3]
            moved = first + column // 3
            ahead[moved], behind[moved] = state[moved] + shift, state[moved] - shift
            difference = kernels.phasor_measurement(*ahead, FIXED, *channel) - kernels.phasor_measurement(
                *behind, FIXED, *channel
            )
            difference[..., 0] = geometry.wrap_to_period(difference[..., 0], 2 * np.pi / p.wavenumber)
            error = np.abs(jacobian[..., column] - difference / (2 * step))
            assert np.median(error) < 1e-6 and np.quantile(error, 0.99) < 1e-3 and error.max() < 1e-2, column
    still = kernels.phasor_linearized(source, 0 * velocity, mobile, 0 * mobile_velocity, FIXED, *channel)
    np.testing.assert_array_equal(still[1][..., 1, 0:3], 0.0)  # no motion, no rate to move
    np.testing.assert_array_equal(still[2][..., 1, 0:3], 0.0)


def test_the_phasor_loops_take_one_fixed_hydrophone():
    with pytest.raises(ValueError, match=r"fixed must be one hydrophone position of shape \(3,\)"):
        kernels.phasor_paths(np.zeros(3), np.ones(3), np.zeros((2, 3)), 60.0, -0.9, 0.3, 4.0)


@pytest.mark.parametrize("offsets", [[0.0], [0.0, 0.1], [[-0.1, 0.1]]])
def test_the_frame_model_refuses_offsets_that_give_no_centred_slope(offsets):
    with pytest.raises(ValueError, match="frame offsets must be two or more times about the frame's centre"):
        FrameAveragedPhasor(PROPAGATION, np.array(offsets))


def test_one_point_gives_a_scalar_rd():
    arguments = (PROPAGATION.water_depth, PROPAGATION.surface_reflection, PROPAGATION.bed_reflection)
    rd = geometry.phasor_range_difference(np.array([3.0, 4.0, -10.0]), np.zeros(3) - 5, FIXED, *arguments, 4.0)
    assert isinstance(rd, float)


def test_the_frame_model_in_blocks_is_the_frame_model_at_once():
    """More states than one block (:data:`aasl_gym.kernels.CHUNK`) give, state by state, what each block gives
    alone: the blocks are stitched in order."""
    rng = np.random.default_rng(4)
    count = 2 * kernels.CHUNK + 7
    sources, velocities = rng.uniform([-30, -30, -59], [30, 30, -1], (count, 3)), rng.uniform(-1.5, 1.5, (count, 3))
    mobile, mobile_velocity = np.array([12.0, -3.0, -7.0]), np.array([1.0, 0.0, 0.0])
    frame = FrameAveragedPhasor(PROPAGATION, frame_offsets(0.2, 3))
    whole = frame.linearize(sources, velocities, mobile, mobile_velocity, FIXED)
    for start in (0, kernels.CHUNK - 3, 2 * kernels.CHUNK):
        part = slice(start, start + 10)
        alone = frame.linearize(sources[part], velocities[part], mobile, mobile_velocity, FIXED)
        for stitched, block in zip(whole, alone):
            np.testing.assert_array_equal(stitched[part], block)


@pytest.mark.parametrize("phase", [1.234, 3.0e6])  # the second puts every angle beyond the polynomial's range
def test_the_compiled_tone_envelope_is_the_numpy_one_to_the_last_bit(phase, monkeypatch):
    """Three paths (reflections on) of a moving source at a moving and a fixed receiver: the compiled envelope
    against :func:`aasl_gym.synthesis.received_pressure`'s NumPy form, bit for bit; out of the sine's range the
    kernel declines and the NumPy form (with NumPy's sine) runs."""
    waveform = synthesis.Waveform("tone", 1000.0, phase=phase)
    times = synthesis.frame_times(57.3, 0.24, 4000.0)
    paths = synthesis.path_sources(np.array([5.0, 3.0, -10.0]), np.array([0.3, 0.1, 0.0]), True, 60.0, -0.9, 0.3)
    receivers, velocities = np.array([[20.0, -4.0, -6.0], FIXED]), np.array([[1.0, 0.5, 0.0], [0.0, 0.0, 0.0]])
    arguments = (waveform, times, 57.3, paths, receivers, velocities, 1500.0, 1.0e3, True, 1000.0)
    original, took = kernels.tone_envelope, []

    def spy(*values):
        envelope = original(*values)
        took.append(envelope is not None)
        return envelope

    monkeypatch.setattr(kernels, "tone_envelope", spy)
    compiled = synthesis.received_pressure(*arguments)
    assert took == [phase <= kernels.SINCOS_LIMIT]  # the kernel ran, and declined only out of range
    assert compiled.shape == (2, len(times)) and compiled.dtype == complex
    monkeypatch.setattr(kernels, "tone_envelope", lambda *_: None)
    np.testing.assert_array_equal(compiled, synthesis.received_pressure(*arguments))


def test_the_window_terms_are_the_numpy_whitener_and_residual():
    """R_eff's whitener and the whitened, wrapped residual against NumPy's receiver noise, 2 x 2 inverse
    Cholesky factor and wrap, for random Jacobians and a residual that crosses the wrap; W^T W is R_eff^-1."""
    rng = np.random.default_rng(3)
    values, receiver = rng.normal(0, 2.0, (4, 7, 2)), rng.normal(0, 1.0, (4, 7, 2, 6))
    biases, measured = rng.normal(0, 0.5, (4, 2)), rng.normal(0, 2.0, (7, 2))
    noise, navigation_sd, period = np.array([[0.01, 0.002], [0.002, 0.004]]), (0.05, 0.02), 1.5
    white, residual = kernels.window_terms(values, receiver, biases, measured, noise, navigation_sd, period)
    effective = noise + receiver_noise(receiver, *navigation_sd)
    np.testing.assert_allclose(white, inverse_cholesky(effective), rtol=1e-13)
    np.testing.assert_allclose(np.swapaxes(white, -1, -2) @ white, np.linalg.inv(effective), rtol=1e-10)
    error = measured - (values + biases[:, None])
    error[..., 0] = geometry.wrap_to_period(error[..., 0], period)
    np.testing.assert_allclose(residual, whiten(inverse_cholesky(effective), error), rtol=0, atol=1e-12)
    _, unwrapped = kernels.window_terms(values, receiver, biases, measured, noise, navigation_sd, None)
    raw = measured - (values + biases[:, None])
    np.testing.assert_allclose(unwrapped, whiten(inverse_cholesky(effective), raw), rtol=0, atol=1e-12)


def test_the_whitened_chain_is_the_numpy_product():
    """W [local @ motion | I_2] against NumPy's batched products, a broadcast motion Jacobian included (the
    linear models hand one over)."""
    rng = np.random.default_rng(4)
    local, white = rng.normal(size=(3, 5, 2, 6)), np.tril(rng.normal(size=(3, 5, 2, 2)))
    motion = np.broadcast_to(rng.normal(size=(5, 6, 6)), (3, 5, 6, 6))
    chain = kernels.whitened_chain(local, motion, white)
    unwhitened = np.concatenate([local @ motion, np.broadcast_to(np.eye(2), (3, 5, 2, 2))], axis=-1)
    np.testing.assert_allclose(chain, white @ unwhitened, rtol=1e-12, atol=1e-12)


def test_every_loop_is_compiled():
    """A loop that lost its decorator still gives the right numbers, a hundred times slower: the tests above
    cannot tell."""
    loops = ("_sincos_loop", "_phasor_loop", "_frame_combine", "_tone_angles", "_add_phasors")
    compiled = (
        "_window_terms",
        "_whitened_chain",
        "_atan2_loop",
        "_block_terms",
        "_fit_terms",
        "_fit",
        "_damped_steps",
        "_direct_loop",
        "_lcmap_grid",
        "_peak_counts",
        "_peak_over_median",
        "_sigma_points",
        "_sigma_moments",
        "_unscented_update",
        "_frame_and_direct_paths",
        "_ripple_measurements",
        "_constant_velocity_prediction",
        "_unscented_updates",
        "_rate_loop",
    )
    for name in loops + compiled:
        assert isinstance(getattr(kernels, name), numba.core.dispatcher.Dispatcher), name


def test_arctan2_is_within_three_units_in_the_last_place_of_numpy():
    """The branch-free arctangent against ``np.arctan2`` (the C library's): at most 3 ulp of pi off, over
    magnitudes from 1e-3 to 1e3, on the octants' edges (|y| = |x| and |y| = tan(pi/8) |x|), and the same to the
    last bit at the signed zeros and on the axes."""
    rng = np.random.default_rng(6)
    x = rng.normal(size=200_000) * 10.0 ** rng.uniform(-3, 3, 200_000)
    y = rng.normal(size=200_000) * 10.0 ** rng.uniform(-3, 3, 200_000)
    edges = np.tile([1.0, -1.0, np.tan(np.pi / 8), -np.tan(np.pi / 8), np.tan(3 * np.pi / 8)], 1000)
    x, y = np.concatenate([x, rng.normal(size=edges.size)]), np.concatenate([y, np.zeros(edges.size)])
    y[-edges.size :] = x[-edges.size :] * edges
    assert np.max(np.abs(kernels.arctan2(y, x) - np.arctan2(y, x))) <= 3 * np.spacing(np.pi)
    signed = np.array([0.0, -0.0, 0.0, -0.0, 1.0, -1.0, 0.0, 0.0, np.inf, 2.0])
    across = np.array([0.0, 0.0, -0.0, -0.0, 0.0, 0.0, 1.0, -1.0, 1.0, np.inf])
    np.testing.assert_array_equal(kernels.arctan2(signed, across), np.arctan2(signed, across))


def test_damped_steps_solve_what_numpy_solves():
    """Marquardt's damped steps against ``np.linalg.solve`` of N + lambda diag(N), for normal matrices from
    random Jacobians and dampings from 1e-4 to 1e2, one of them needing a row swap (a zero leading pivot)."""
    rng = np.random.default_rng(7)
    jacobian = rng.normal(size=(300, 30, 8))
    normal, gradient = np.swapaxes(jacobian, 1, 2) @ jacobian, rng.normal(size=(300, 8))
    damping = 10.0 ** rng.uniform(-4, 2, 300)
    normal[0, 0, :], normal[0, :, 0], damping[0] = 0.0, 0.0, 1.0  # no first pivot: it must be swapped in
    normal[0, 0, 1] = normal[0, 1, 0] = 1.0
    scale = np.diagonal(normal, axis1=1, axis2=2)
    expected = -np.linalg.solve(normal + damping[:, None, None] * scale[:, None, :] * np.eye(8), gradient[..., None])
    np.testing.assert_allclose(kernels.damped_steps(normal, damping, gradient), expected[..., 0], rtol=1e-9, atol=1e-12)


def _solve_alone(matrix: list[list[float]], right: list[float]) -> list[float]:
    """matrix^-1 right for one system, by Gaussian elimination with partial pivoting in Python floats: the operations
    ``kernels._lane_solves`` takes on each lane, one system at a time."""
    dim = len(right)
    for a in range(dim):
        pivot = a
        for r in range(a + 1, dim):
            if abs(matrix[r][a]) > abs(matrix[pivot][a]):
                pivot = r
        matrix[a], matrix[pivot] = matrix[pivot], matrix[a]
        right[a], right[pivot] = right[pivot], right[a]
        for r in range(a + 1, dim):
            factor = matrix[r][a] / matrix[a][a]
            for b in range(a, dim):
                matrix[r][b] -= factor * matrix[a][b]
            right[r] -= factor * right[a]
    out = [0.0] * dim
    for a in range(dim - 1, -1, -1):
        total = right[a]
        for b in range(a + 1, dim):
            total -= matrix[a][b] * out[b]
        out[a] = total / matrix[a][a]
    return out


@pytest.mark.parametrize("dim", [3, 8], ids=["grid-velocity", "window-fit"])
def test_the_lanes_solve_as_each_system_alone_to_the_last_bit(dim):
    """Every lane's system solved at once (``_lane_solves``: the window fit's, LC-MAP's grid's and ``damped_steps``'
    steps) is each system solved alone to the last bit, row swaps included, so that a start's fit does not depend on
    the block or lane it ran in; and both are what NumPy solves, to rounding."""
    rng = np.random.default_rng(8)
    lanes = 13  # not a multiple of the vector width
    matrices, rights = rng.normal(size=(lanes, dim, dim)), rng.normal(size=(lanes, dim))
    matrices[::2] += 10 * np.eye(dim)  # diagonally dominant: no row swap; the others swap rows
    matrices[1, 0, 0] = 0.0  # no first pivot: a swap for certain
    alone = np.array([_solve_alone(matrices[i].tolist(), rights[i].tolist()) for i in range(lanes)])
    together = np.empty((dim, lanes))
    kernels._lane_solves(
        np.ascontiguousarray(matrices.transpose(1, 2, 0)), np.ascontiguousarray(rights.T), lanes,
        np.empty(lanes, dtype=np.int64), np.empty((2, lanes)), together,
    )  # fmt: skip
    np.testing.assert_array_equal(together.T, alone)
    np.testing.assert_allclose(alone, np.linalg.solve(matrices, rights[..., None])[..., 0], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("shape", [(), (4, 17)], ids=["point", "sigma-points"])
def test_the_compiled_direct_path_is_the_numpy_one(shape):
    """The direct path's values and both Jacobians from one compiled pass against the NumPy forms, to rounding, for one
    point (the env's, the reward's information) and a bank's sigma points against one receiver."""
    rng = np.random.default_rng(3)
    position, velocity = rng.normal(0, 10, shape + (3,)), rng.normal(0, 0.5, shape + (3,))
    mobile, mobile_velocity, fixed = rng.normal(0, 10, 3), rng.normal(0, 0.5, 3), np.array([0.0, 0.0, -0.96])
    values, state, receiver = kernels.direct_path(position, velocity, mobile, mobile_velocity, fixed)
    assert values.shape == shape + (2,) and state.shape == receiver.shape == shape + (2, 6)
    expected_values = direct_measurement(position, velocity, mobile, mobile_velocity, fixed)
    np.testing.assert_allclose(values, expected_values, rtol=1e-13)
    expected_state = geometry.direct_jacobian(position, velocity, mobile, mobile_velocity, fixed)
    np.testing.assert_allclose(state, expected_state, rtol=1e-12, atol=1e-15)
    expected_receiver = direct_receiver_jacobian(position, velocity, mobile, mobile_velocity)
    np.testing.assert_allclose(receiver, expected_receiver, rtol=1e-12, atol=1e-15)


def test_peak_counts_count_each_part_at_its_own_peak():
    """The samples at each channel's largest magnitude, a complex channel's real and imaginary parts apart, against
    NumPy's count; integer and real input alike."""
    rng = np.random.default_rng(4)
    samples = rng.normal(size=(2, 3, 50)) + 1j * rng.normal(size=(2, 3, 50))
    samples.real[0, 1, [3, 7, 9]] = -2 * np.abs(samples.real[0, 1]).max()  # three samples share the real peak
    parts = np.stack([samples.real, samples.imag], axis=-1)
    expected = np.count_nonzero(np.abs(parts) >= np.abs(parts).max(axis=-2, keepdims=True), axis=-2)
    counts = kernels.peak_counts(samples)
    np.testing.assert_array_equal(counts, expected)
    assert counts[0, 1, 0] == 3
    np.testing.assert_array_equal(kernels.peak_counts(np.array([[1, -3, 3, 2]])), [[2]])


@pytest.mark.parametrize("bank", [1, 5], ids=["one-filter", "five-filters"])
def test_the_frame_model_and_the_direct_path_in_one_pass_are_the_two_passes_to_the_last_bit(bank):
    """A bank's sigma points (bank x 17) through :func:`kernels.frame_and_direct` against :func:`kernels.frame_phasor`
    and :func:`kernels.direct_path` called apart: every number equal."""
    rng = np.random.default_rng(5)
    position = rng.normal([5.0, -8.0, -12.0], 3.0, (bank, 17, 3))
    velocity = rng.normal(0, 0.5, (bank, 17, 3))
    mobile, mobile_velocity = np.array([12.0, 3.0, -4.0]), np.array([0.3, -0.9, 0.1])
    offsets = frame_offsets(0.2, 3)
    state = (position, velocity, mobile, mobile_velocity, FIXED)
    frame, frame_receiver, direct, direct_receiver = kernels.frame_and_direct(*state, offsets, PROPAGATION)
    expected_frame, _, expected_frame_receiver = kernels.frame_phasor(*state, offsets, PROPAGATION)
    expected_direct, _, expected_direct_receiver = kernels.direct_path(*state)
    for got, expected in [
        (frame, expected_frame),
        (frame_receiver, expected_frame_receiver),
        (direct, expected_direct),
        (direct_receiver, expected_direct_receiver),
    ]:
        assert got.shape == expected.shape
        np.testing.assert_array_equal(got, expected)
    with pytest.raises(ValueError, match="share one shape"):
        kernels.frame_and_direct(position, velocity[..., 0, :], mobile, mobile_velocity, FIXED, offsets, PROPAGATION)


def test_the_six_term_sum_is_numpys_einsum_to_the_last_bit(einsum_sums_even_odd):
    """R_eff's navigation term sums six products in einsum's order: rows of every magnitude, as
    :func:`receiver_noise` takes them; to rounding on a NumPy build whose einsum sums in another order."""
    rng = np.random.default_rng(6)
    jacobian = rng.normal(size=(400, 2, 6)) * 10.0 ** rng.uniform(-4, 4, (400, 2, 6))
    expected = receiver_noise(jacobian, 0.05, 0.02)
    scales = np.array((0.05,) * 3 + (0.02,) * 3)
    got = np.array(
        [[kernels._pair_dot6(row[a], row[b]) for a, b in ((0, 0), (1, 1), (0, 1))] for row in jacobian * scales]
    )
    wanted = expected[:, [0, 1, 0], [0, 1, 1]]
    if einsum_sums_even_odd:
        np.testing.assert_array_equal(got, wanted)
    else:
        np.testing.assert_allclose(got, wanted, rtol=1e-14)


def test_the_ripple_measurements_are_the_numpy_route_to_the_last_bit(einsum_sums_even_odd):
    """:func:`kernels.ripple_measurements` against the NumPy spelling of the tracker's route (the correction within
    half a period of the central point's, the offsets added, :func:`receiver_noise` at the mean), corrections that
    cross the period's edges included."""
    rng = np.random.default_rng(7)
    period = 1.5
    direct = rng.normal(0, 20, (4, 17, 2))
    frame = direct + rng.uniform(-3 * period, 3 * period, (4, 17, 2))
    receiver, offsets = rng.normal(size=(4, 2, 6)), rng.normal(0, 5, (4, 17, 2))
    values, noise = kernels.ripple_measurements(frame, direct, receiver, offsets, period, (0.05, 0.02))
    correction = frame - direct
    centre = correction[:, :1]
    correction[..., 0] = centre[..., 0] + geometry.wrap_to_period(correction[..., 0] - centre[..., 0], period)
    np.testing.assert_array_equal(values, (direct + correction) + offsets)
    expected_noise = np.zeros((4, 2, 2)) + receiver_noise(receiver, 0.05, 0.02)
    if einsum_sums_even_odd:
        np.testing.assert_array_equal(noise, expected_noise)
    else:
        np.testing.assert_allclose(noise, expected_noise, rtol=1e-14)


def test_the_constant_velocity_prediction_in_one_call_is_the_three_calls_to_the_last_bit():
    """A bank of CV filters predicted in one compiled call against :func:`kernels.sigma_points`, the model's own
    transition, :func:`kernels.sigma_moments` and :func:`kernels.sigma_points` again: every number equal, and a filter
    whose covariance is not positive definite flagged as the three calls flag it."""
    model = ConstantVelocity(FilterConfig())
    wm, wc, spread = merwe_weights(model.dim, 0.5, 2.0, 0.0)
    rng = np.random.default_rng(9)
    means = rng.normal(0, 5, (4, model.dim))
    roots = rng.normal(0, 0.3, (4, model.dim, model.dim))
    covariances = roots @ np.swapaxes(roots, 1, 2) + 1e-3 * np.eye(model.dim)
    covariances[2, 0, 0] = -1.0  # not positive definite
    noise = model.process_noise(0.2)
    predicted_means, predicted_covariances, points, valid = kernels.constant_velocity_prediction(
        means, covariances, spread, 0.2, wm, wc, noise
    )
    sigmas, first_valid = kernels.sigma_points(means, covariances, spread)
    expected_means, expected_covariances = kernels.sigma_moments(model.transition(sigmas, 0.2), wm, wc, noise)
    expected_points, second_valid = kernels.sigma_points(expected_means, expected_covariances, spread)
    np.testing.assert_array_equal(valid, first_valid & second_valid)
    assert valid.tolist() == [True, True, False, True]
    np.testing.assert_array_equal(predicted_means, expected_means)
    np.testing.assert_array_equal(predicted_covariances, expected_covariances)
    np.testing.assert_array_equal(points[valid], expected_points[valid])
    # A predicted covariance that breaks, after the first filter's (a negative Q takes the smallest P below zero).
    covariances = np.array([np.eye(model.dim) * scale for scale in (10.0, 10.0, 0.01, 10.0)])
    broken_noise = -np.eye(model.dim)
    valid = kernels.constant_velocity_prediction(means, covariances, spread, 0.0, wm, wc, broken_noise)[3]
    sigmas, first_valid = kernels.sigma_points(means, covariances, spread)
    moved_means, moved_covariances = kernels.sigma_moments(model.transition(sigmas, 0.0), wm, wc, broken_noise)
    second_valid = kernels.sigma_points(moved_means, moved_covariances, spread)[1]
    assert valid.tolist() == (first_valid & second_valid).tolist() == [True, True, False, True]
