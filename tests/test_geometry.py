"""Geometry against hand-worked cases, finite differences, an independent phasor sum and Doppler."""

import numpy as np
import pytest

from aasl_gym import geometry

C, F0 = 1500.0, 1000.0
K = 2 * np.pi * F0 / C


def random_geometry(rng, n=200):
    source = rng.uniform([-30, -30, -50], [30, 30, -1], (n, 3))
    mobile = rng.uniform([-20, -20, -15], [20, 20, -1], (n, 3))
    fixed = np.array([0.0, 0.0, -0.96])
    return source, rng.normal(0, 1, (n, 3)), mobile, rng.normal(0, 1, (n, 3)), fixed


def test_hand_worked_range_difference():
    fixed, mobile, source = np.array([0.0, 0, -1]), np.array([6.0, 0, -1]), np.array([0.0, 8, -1])
    assert geometry.range_difference(source, mobile, fixed) == pytest.approx(10.0 - 8.0)


def test_range_difference_never_exceeds_baseline(rng):
    source, _, mobile, _, fixed = random_geometry(rng, 5000)
    rd = geometry.range_difference(source, mobile, fixed)
    assert np.all(np.abs(rd) <= np.linalg.norm(mobile - fixed, axis=1) + 1e-12)


def test_rrd_is_time_derivative_of_rd(rng):
    source, vs, mobile, vm, fixed = random_geometry(rng)
    h = 1e-6
    forward = geometry.range_difference(source + h * vs, mobile + h * vm, fixed)
    backward = geometry.range_difference(source - h * vs, mobile - h * vm, fixed)
    np.testing.assert_allclose(
        geometry.range_rate_difference(source, vs, mobile, vm, fixed), (forward - backward) / (2 * h), atol=1e-7
    )


def test_jacobian_matches_finite_differences(rng):
    source, vs, mobile, vm, fixed = random_geometry(rng, 20)
    jac = geometry.direct_jacobian(source, vs, mobile, vm, fixed)
    h = 1e-6
    for i in range(6):
        step = np.zeros(6)
        step[i] = h

        def z(delta):
            p, v = source + delta[:3], vs + delta[3:]
            return np.stack(
                [geometry.range_difference(p, mobile, fixed), geometry.range_rate_difference(p, v, mobile, vm, fixed)],
                -1,
            )

        np.testing.assert_allclose(jac[..., i], (z(step) - z(-step)) / (2 * h), atol=1e-6)


def test_fdoa_sign_matches_doppler():
    """A receiver moving away from a static source hears a lower tone: f_fixed - f_mobile > 0."""
    source, fixed = np.array([0.0, 0, -10]), np.array([0.0, 0, -0.96])
    mobile, mobile_velocity = np.array([10.0, 0, -10]), np.array([1.0, 0, 0])
    rrd = geometry.range_rate_difference(source, np.zeros(3), mobile, mobile_velocity, fixed)
    assert rrd == pytest.approx(1.0)
    # Exact Doppler of a moving receiver and a static source: f = f0 (1 - range_rate / c)
    f_mobile, f_fixed = F0 * (1 - 1.0 / C), F0
    assert f_fixed - f_mobile > 0
    assert geometry.fdoa_from_rrd(rrd, F0, C) == pytest.approx(f_fixed - f_mobile, rel=1e-12)


def test_image_sources_give_reflected_path_lengths():
    source, receiver, depth = np.array([3.0, -2.0, -7.0]), np.array([15.0, 4.0, -3.0]), 20.0
    (surface, _), (bed, _) = geometry.image_sources(source, np.zeros(3), depth)
    # Surface bounce: the specular point splits the horizontal distance in the ratio of the depths.
    horizontal = np.linalg.norm(receiver[:2] - source[:2])
    d_s, d_r = -source[2], -receiver[2]
    along = horizontal * d_s / (d_s + d_r)
    point = source + np.r_[(receiver[:2] - source[:2]) / horizontal * along, d_s]
    assert np.linalg.norm(surface - receiver) == pytest.approx(
        np.linalg.norm(point - source) + np.linalg.norm(receiver - point)
    )
    h_s, h_r = depth - d_s, depth - d_r  # heights above the bed
    along = horizontal * h_s / (h_s + h_r)
    point = source + np.r_[(receiver[:2] - source[:2]) / horizontal * along, -h_s]
    assert np.linalg.norm(bed - receiver) == pytest.approx(
        np.linalg.norm(point - source) + np.linalg.norm(receiver - point)
    )


def phasor_sum(source, receiver, depth, gains):
    (surface, _), (bed, _) = geometry.image_sources(source, np.zeros(3), depth)
    total = 0j
    for point, gain in ((source, 1.0), (surface, gains[0]), (bed, gains[1])):
        r = np.linalg.norm(point - receiver)
        total += gain / r * np.exp(-1j * K * r)
    return total


def test_phasor_model_matches_an_independent_phasor_sum(rng):
    depth, gains = 20.0, (-0.9, 0.3)
    fixed = np.array([0.0, 0, -0.96])
    for _ in range(50):
        source = rng.uniform([-20, -20, -18], [20, 20, -2])
        mobile = rng.uniform([-15, -15, -15], [15, 15, -2])
        rd, _ = geometry.phasor_multipath(source, np.zeros(3), mobile, np.zeros(3), fixed, depth, *gains, K)
        expected = (
            -np.angle(phasor_sum(source, mobile, depth, gains) * np.conj(phasor_sum(source, fixed, depth, gains))) / K
        )
        wavelength = 2 * np.pi / K
        assert geometry.wrap_to_period(rd - expected, wavelength) == pytest.approx(0.0, abs=1e-9)


def test_multipath_rrd_is_time_derivative_of_multipath_rd(rng):
    source, vs, mobile, vm, fixed = random_geometry(rng, 50)
    args = (60.0, -0.9, 0.3)
    h = 1e-6
    rd_plus, _ = geometry.phasor_multipath(source + h * vs, vs, mobile + h * vm, vm, fixed, *args, K)
    rd_minus, _ = geometry.phasor_multipath(source - h * vs, vs, mobile - h * vm, vm, fixed, *args, K)
    _, rrd = geometry.phasor_multipath(source, vs, mobile, vm, fixed, *args, K)
    np.testing.assert_allclose(rrd, (rd_plus - rd_minus) / (2 * h), atol=2e-5)
    lin_plus, _ = geometry.linear_multipath(source + h * vs, vs, mobile + h * vm, vm, fixed, *args)
    lin_minus, _ = geometry.linear_multipath(source - h * vs, vs, mobile - h * vm, vm, fixed, *args)
    _, lin_rrd = geometry.linear_multipath(source, vs, mobile, vm, fixed, *args)
    np.testing.assert_allclose(lin_rrd, (lin_plus - lin_minus) / (2 * h), atol=1e-6)


def test_multipath_models_reduce_to_direct_path_without_reflections(rng):
    source, vs, mobile, vm, fixed = random_geometry(rng, 50)
    direct = geometry.range_difference(source, mobile, fixed)
    np.testing.assert_allclose(geometry.linear_multipath(source, vs, mobile, vm, fixed, 60.0, 0.0, 0.0)[0], direct)
    np.testing.assert_allclose(geometry.phasor_multipath(source, vs, mobile, vm, fixed, 60.0, 0.0, 0.0, K)[0], direct)


def test_linear_model_sign_conventions():
    """The first-order model adds a_surf * delta_surf with a_surf < 0: check against a hand computation."""
    source, mobile, fixed = np.array([5.0, 0, -4]), np.array([12.0, 3, -6]), np.array([0.0, 0, -0.96])
    surface = source * [1, 1, -1]
    bed = np.array([5.0, 0, -2 * 30 + 4])
    expected = (
        geometry.range_difference(source, mobile, fixed)
        - 0.9 * geometry.range_difference(surface, mobile, fixed)
        + 0.3 * geometry.range_difference(bed, mobile, fixed)
    )
    rd, _ = geometry.linear_multipath(source, np.zeros(3), mobile, np.zeros(3), fixed, 30.0, -0.9, 0.3)
    assert rd == pytest.approx(expected)


def test_unwrap_to_period_agrees_with_numpys_unwrap(rng):
    """A wrapped random walk unwrapped in its own unit equals numpy's unwrap of the same phases."""
    walk = np.cumsum(rng.normal(0.0, 0.15, (200, 12)), axis=-1)  # m, steps well under half a period
    period = 1.5
    wrapped = geometry.wrap_to_period(walk, period)
    expected = np.unwrap(wrapped * 2 * np.pi / period, axis=-1) * period / (2 * np.pi)
    np.testing.assert_allclose(geometry.unwrap_to_period(wrapped, period), expected, atol=1e-12)
    # The walk comes back, offset by the whole periods its first value was wrapped by.
    offset = np.broadcast_to((wrapped - walk)[:, :1], walk.shape)
    np.testing.assert_allclose(geometry.unwrap_to_period(wrapped, period) - walk, offset, atol=1e-12)
