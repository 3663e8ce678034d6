"""Initializers: the locus in closed form, feasible offsets, and LC-MAP on a clean burst."""

import numpy as np
import pytest

from aasl_gym import geometry
from aasl_gym.config import InitializerConfig
from aasl_gym.initializers import Burst, feasible_offsets, fibonacci_directions, locus_points, make_initializer
from aasl_gym.measurements import direct_measurement
from aasl_gym.motion import Box

FIXED = np.array([0.0, 0, -0.96])
REGION = Box(38.0, -58.0, -2.0)


def test_locus_points_satisfy_the_range_difference(rng):
    mobile = np.array([9.0, 3, -6])
    directions = fibonacci_directions(500)
    for rd in (-8.0, -1.3, 0.0, 2.2, 9.4):
        points = locus_points(mobile, FIXED, rd, directions)
        valid = np.isfinite(points[:, 0])
        assert valid.sum() > 10
        np.testing.assert_allclose(geometry.range_difference(points[valid], mobile, FIXED), rd, atol=1e-9)


def test_fibonacci_directions_are_unit_and_spread():
    d = fibonacci_directions(1000)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.abs(d.mean(axis=0)).max() < 0.01


def test_feasible_offsets_contain_the_truth_and_respect_the_baseline(rng):
    wavelength = 1.5
    for _ in range(200):
        baseline = rng.uniform(3, 30)
        true_rd = rng.uniform(-baseline, baseline)
        k = rng.integers(-20, 20)
        measured = true_rd + k * wavelength
        offsets = feasible_offsets(measured, baseline, wavelength)
        assert np.any(np.isclose(offsets, k * wavelength))
        assert np.all(np.abs(measured - offsets) <= baseline + 1e-9)
    assert np.array_equal(feasible_offsets(0.3, 10.0, None), [0.0])


def helix_burst(source, velocity, offset, duration=10.0, rate=5.0):
    times = np.arange(0, duration, 1 / rate)
    angle = times / 10.0
    mobile = np.stack([10 * np.cos(angle), 10 * np.sin(angle), -7 - 5 * np.sin(2 * np.pi * times / 40)], -1)
    mobile_velocity = np.gradient(mobile, times, axis=0)
    truth = source + velocity * times[:, None]
    z = direct_measurement(truth, velocity, mobile, mobile_velocity, FIXED)
    z[:, 0] += offset
    R = np.diag([0.05**2, 0.02**2])
    return Burst(times, z, mobile, mobile_velocity, FIXED, R, 1.5, direct_measurement), truth[-1]


def test_lcmap_finds_the_source_and_its_whole_period_offset_on_a_clean_burst(rng):
    source, velocity = np.array([12.0, -6, -9]), np.array([0.4, 0.3, 0.0])
    burst, end = helix_burst(source, velocity, offset=4 * 1.5, duration=30.0)  # 10 s leaves the sheets ambiguous
    estimate = make_initializer("lcmap", InitializerConfig(candidate_directions=2000), REGION)(burst, rng)
    assert estimate.state[6] == pytest.approx(6.0)
    assert np.linalg.norm(estimate.state[:3] - end) < 1.0
    assert np.linalg.norm(estimate.state[3:6] - velocity) < 0.2


@pytest.mark.parametrize("name", ["lcmap", "naive", "random", "tdoa-ls"])
def test_every_initializer_returns_a_valid_gaussian(name, rng):
    burst, _ = helix_burst(np.array([5.0, 8, -12]), np.zeros(3), offset=-3.0, duration=2.0)
    estimate = make_initializer(name, InitializerConfig(), REGION)(burst, rng)
    assert estimate.state.shape == (8,) and np.all(np.isfinite(estimate.state))
    np.linalg.cholesky(estimate.covariance)  # positive definite
    np.testing.assert_allclose(estimate.covariance, estimate.covariance.T)


def test_lcmap_keeps_distinct_hypotheses_best_first_and_the_true_sheet_among_them(rng):
    """A 2 s burst cannot tell the whole-period sheets apart: LC-MAP keeps the best of every sheet."""
    offset = 3 * 1.5
    burst, _ = helix_burst(np.array([5.0, 8, -12]), np.array([0.3, -0.2, 0.0]), offset=offset, duration=2.0)
    config = InitializerConfig(hypotheses=12)
    estimate = make_initializer("lcmap", config, REGION)(burst, rng)
    count = len(estimate.states)
    assert 2 <= count <= config.hypotheses
    assert estimate.log_weights.max() == 0.0 and np.all(estimate.log_weights <= 0)
    sheets = estimate.states[:, 6]
    assert np.allclose(sheets / 1.5, np.round(sheets / 1.5))  # whole periods
    assert np.any(np.isclose(sheets, offset))
    feasible = feasible_offsets(burst.measurements[0, 0], np.linalg.norm(burst.receiver_positions[0] - FIXED), 1.5)
    assert len(feasible) > config.hypotheses  # so the first pass (one per sheet) fills the bank
    assert len(np.unique(sheets)) == count
    for covariance in estimate.covariances:
        np.linalg.cholesky(covariance)
    true_sheet = estimate.states[np.isclose(sheets, offset)][0]
    rd = geometry.range_difference(true_sheet[:3], burst.receiver_positions[-1], FIXED)
    assert abs(rd + offset - burst.measurements[-1, 0]) < 3 * 0.05  # on the locus of the last RD
    single = make_initializer("lcmap", InitializerConfig(hypotheses=1), REGION)(burst, rng)
    assert len(single.states) == 1
    np.testing.assert_allclose(single.state, estimate.state)  # the bank leads with the paper's pick


def test_tdoa_ls_lands_on_the_principal_sheet(rng):
    burst, _ = helix_burst(np.array([5.0, 8, -12]), np.zeros(3), offset=0.0, duration=2.0)
    estimate = make_initializer("tdoa-ls", InitializerConfig(), REGION)(burst, rng)
    rd = geometry.range_difference(estimate.state[:3], burst.receiver_positions[-1], FIXED)
    assert rd == pytest.approx(burst.measurements[-1, 0], abs=1e-6)


def test_unknown_initializer_is_named():
    with pytest.raises(ValueError, match="bogus"):
        make_initializer("bogus", InitializerConfig(), REGION)
