"""Initializers: the locus in closed form, feasible offsets, and LC-MAP on a clean burst."""

import itertools
from dataclasses import replace

import numpy as np
import pytest

from aasl_gym import geometry
from aasl_gym.config import InitializerConfig
from aasl_gym.initializers import (
    Burst,
    CandidateMotion,
    LCMAPInitializer,
    _predicted,
    feasible_offsets,
    fibonacci_directions,
    locus_points,
    make_initializer,
)
from aasl_gym.measurement_models import direct_measurement
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


def turning_truth(position, velocity, turn_rate, times, substeps=400):
    """Positions and velocities of a horizontal turn, by trapezoidal integration of v(t) = R(omega t) v0
    between the sample times (independent of the closed form the code uses)."""

    def turned(t):
        angle = turn_rate * t
        return np.stack(
            [
                np.cos(angle) * velocity[0] - np.sin(angle) * velocity[1],
                np.sin(angle) * velocity[0] + np.cos(angle) * velocity[1],
                np.full_like(t, velocity[2]),
            ],
            -1,
        )

    positions, current = [np.asarray(position, float)], np.asarray(position, float)
    for start, end in itertools.pairwise(times):
        fine = np.linspace(start, end, substeps + 1)
        vel = turned(fine)
        current = current + np.sum(np.diff(fine)[:, None] * 0.5 * (vel[1:] + vel[:-1]), axis=0)
        positions.append(current)
    return np.array(positions), turned(np.asarray(times, float))


def test_turn_terms_follow_an_integrated_turn():
    tau = np.linspace(0.0, 40.0, 9)
    position, velocity = np.array([3.0, -4.0, -10.0]), np.array([0.8, -0.5, 0.05])
    for rate in (0.0, 0.07, -0.11, 1e-6):
        trajectory, trajectory_velocity = CandidateMotion(tau, np.array([rate])).trajectory(
            position[None], velocity[None]
        )
        truth_p, truth_v = turning_truth(position, velocity, rate, tau)
        np.testing.assert_allclose(trajectory[0], truth_p, atol=1e-3)
        np.testing.assert_allclose(np.broadcast_to(trajectory_velocity[0], truth_v.shape), truth_v, atol=1e-9)


@pytest.mark.parametrize("rate", [0.0, 0.06])
def test_turn_terms_chain_rule_matches_finite_differences(rate):
    """d[RD, RRD]_k / d[p(t0), v(t0)] through the turn, against central differences of the prediction."""
    burst, _ = helix_burst(np.array([7.0, -5, -11]), np.zeros(3), offset=0.0, duration=20.0)
    tau = burst.times - burst.times[0]
    turns = CandidateMotion(tau, np.array([rate]))
    theta = np.array([7.0, -5, -11, 0.6, 0.4, -0.05])

    analytic = LCMAPInitializer._jacobians(burst, theta[None, :3], theta[None, 3:], turns)[0]
    numeric = np.zeros_like(analytic)
    for i in range(6):
        step = np.zeros(6)
        step[i] = 1e-6
        ahead = _predicted(burst, (theta + step)[None, :3], (theta + step)[None, 3:], turns)[0]
        behind = _predicted(burst, (theta - step)[None, :3], (theta - step)[None, 3:], turns)[0]
        numeric[..., i] = (ahead - behind) / 2e-6
    np.testing.assert_allclose(analytic, numeric, atol=1e-7)


def test_turn_terms_propagate_the_state_and_covariance_linearly(rng):
    tau = np.array([0.0, 25.0])
    rates = np.array([0.0, 0.09])
    states = np.concatenate([rng.normal(size=(2, 6)), rng.normal(size=(2, 2))], axis=1)
    root = rng.normal(size=(2, 8, 8))
    covariances = root @ root.transpose(0, 2, 1)
    terms = CandidateMotion(tau, rates)
    moved, moved_covariance = terms.propagate(states, covariances)
    end_p, end_v = terms.trajectory(states[:, :3], states[:, 3:6])
    np.testing.assert_allclose(moved[:, :3], end_p[:, -1], atol=1e-12)
    np.testing.assert_allclose(moved[:, 3:6], np.broadcast_to(end_v[:, -1], (2, 3)), atol=1e-12)
    np.testing.assert_allclose(moved[:, 6:], states[:, 6:])
    # The trajectory is linear in (p, v): the covariance map is its Jacobian, checked on samples.
    samples = states[1] + rng.normal(size=(20000, 8)) @ np.linalg.cholesky(covariances[1]).T
    one = CandidateMotion(tau, np.full(len(samples), rates[1]))
    p, v = one.trajectory(samples[:, :3], samples[:, 3:6])
    empirical = np.cov(np.concatenate([p[:, -1], np.broadcast_to(v[:, -1], p[:, -1].shape), samples[:, 6:]], axis=1).T)
    np.testing.assert_allclose(empirical, moved_covariance[1], rtol=0.1, atol=0.1 * np.abs(moved_covariance[1]).max())


def test_lcmap_with_a_turn_grid_recovers_a_turning_source(rng):
    """30 s of a source turning at 0.07 rad/s: the turn-aware fit lands within 1 m and finds the rate;
    the straight-line fit of the same burst does not."""
    times = np.arange(0, 30.0, 0.2)
    angle = times / 15.0
    mobile = np.stack([15 * np.cos(angle), 15 * np.sin(angle), -7 - 5 * np.sin(2 * np.pi * times / 30)], -1)
    mobile_velocity = np.gradient(mobile, times, axis=0)
    truth_p, truth_v = turning_truth(np.array([9.0, -6, -10]), np.array([0.7, 0.3, 0.0]), 0.07, times)
    z = direct_measurement(truth_p, truth_v, mobile, mobile_velocity, FIXED)
    z[:, 0] += 2 * 1.5
    burst = Burst(times, z, mobile, mobile_velocity, FIXED, np.diag([0.05**2, 0.02**2]), 1.5, direct_measurement)
    config = InitializerConfig(hypotheses=1)
    turning = make_initializer("lcmap", config, REGION, "ctrv")(burst, rng)
    assert np.linalg.norm(turning.state[:3] - truth_p[-1]) < 1.0
    assert turning.state[6] == pytest.approx(3.0)
    assert turning.turn_rates[0] == pytest.approx(0.07, abs=0.01)
    straight = make_initializer("lcmap", config, REGION)(burst, rng)
    assert np.linalg.norm(straight.state[:3] - truth_p[-1]) > 2.0


@pytest.mark.parametrize("robust", [False, True])
def test_a_turn_grid_shares_its_first_linearization_without_changing_the_fit(robust, rng):
    """The NumPy grid's velocity solve (LC-MAP's for a model other than the direct path) linearizes its copies (one per
    turn rate) at rest once: its velocities and Jacobians are those of linearizing every copy on its own, to the last
    bit (robust bursts, whose whiteners carry per-residual weights, too)."""
    burst = turning_burst(np.arange(0, 20.0, 0.2), rng, robust=robust)
    initializer = make_initializer("lcmap", InitializerConfig(), REGION, "ctrv")
    positions, biases, motion = turn_grid(initializer, burst)
    copies = len(initializer.turn_rates)
    shared = initializer._solve_velocities(burst, positions, biases, motion, copies)
    separate = initializer._solve_velocities(burst, positions, biases, motion)
    for got, expected in zip(shared, separate):
        np.testing.assert_array_equal(got, expected)


def turning_burst(times: np.ndarray, rng, **fields) -> Burst:
    """A noisy direct-path burst at ``times`` (s) of a source turning at 0.05 rad/s, heard from a helix-like path;
    ``fields`` go to the :class:`Burst` (its residual period, navigation sd, robust loss)."""
    angle = times / 15.0
    mobile = np.stack([15 * np.cos(angle), 15 * np.sin(angle), -7 - 5 * np.sin(2 * np.pi * times / 30)], -1)
    mobile_velocity = np.gradient(mobile, times, axis=0)
    truth_p, truth_v = turning_truth(np.array([9.0, -6, -10]), np.array([0.7, 0.3, 0.0]), 0.05, times)
    z = direct_measurement(truth_p, truth_v, mobile, mobile_velocity, FIXED)
    z += rng.normal(0, [0.05, 0.02], z.shape)
    noise = np.diag([0.05**2, 0.02**2])
    return Burst(times, z, mobile, mobile_velocity, FIXED, noise, 1.5, direct_measurement, **fields)


def turn_grid(initializer, burst):
    """The grid's candidates at every turn rate of ``initializer`` and their motion, as LC-MAP builds them."""
    positions, biases = initializer.candidates(burst)
    copies = len(initializer.turn_rates)
    turn_rates = np.repeat(initializer.turn_rates, len(positions))
    motion = CandidateMotion(burst.times - burst.times[0], turn_rates)
    return np.tile(positions, (copies, 1)), np.tile(biases, copies), motion


@pytest.mark.parametrize("motion_model", ["cv", "ctrv"])
@pytest.mark.parametrize("robust", [False, True], ids=["plain", "robust"])
@pytest.mark.parametrize("period", [None, 1.5], ids=["unwrapped", "wrapped"])
def test_the_compiled_grid_is_the_numpy_grid(motion_model, robust, period, rng, monkeypatch):
    """LC-MAP's grid - the velocity solve from rest and the score with the last linearization's information - compiled
    (:func:`aasl_gym.kernels.lcmap_grid`, which a direct-path burst takes) against NumPy (``_solve_velocities`` and
    ``_score``, which a burst of any other model takes), to rounding: straight and turning candidates, plain and
    soft-L1 losses, RD residuals taken modulo the wavelength or not, an acoustic R with correlated RD and RRD errors
    (a whitener with a cross term), on a noisy burst of a turning source whose grid holds candidates near and far
    off it."""
    burst = turning_burst(
        np.arange(0, 20.0, 1.0), rng, residual_period=period, navigation_sd=(0.05, 0.02), robust=robust
    )
    burst = replace(burst, noise_covariance=np.array([[0.05**2, 0.6 * 0.05 * 0.02], [0.6 * 0.05 * 0.02, 0.02**2]]))
    initializer = make_initializer("lcmap", InitializerConfig(), REGION, motion_model)
    positions, biases, motion = turn_grid(initializer, burst)
    copies = len(initializer.turn_rates)
    with monkeypatch.context() as patched:  # the direct path must not fall back to NumPy
        patched.setattr(LCMAPInitializer, "_solve_velocities", None)
        velocities, score = initializer._grid(burst, positions, biases, motion, copies)
    # Any other model takes NumPy's grid: the direct path's own function, wrapped, stands in for one.
    wrapped = replace(burst, measurement_function=lambda *state: direct_measurement(*state))
    expected_velocities, expected_score = initializer._grid(wrapped, positions, biases, motion, copies)
    assert len(positions) > 500
    np.testing.assert_allclose(velocities, expected_velocities, rtol=0, atol=1e-9)
    # Sums of a few hundred squares in another order: 1.2e-10 apart on an AVX-512 machine (OpenBLAS's SkylakeX kernels).
    np.testing.assert_allclose(score, expected_score, rtol=1e-9, atol=1e-8)


def test_lcmap_with_a_ca_filter_fits_the_acceleration(rng):
    """60 s of a source accelerating at 0.02 m/s^2: the acceleration-aware fit lands within 1 m and
    recovers a; the straight-line fit of the same burst does not."""
    times = np.arange(0, 60.0, 0.2)
    angle = times / 15.0
    mobile = np.stack([15 * np.cos(angle), 15 * np.sin(angle), -7 - 5 * np.sin(2 * np.pi * times / 30)], -1)
    mobile_velocity = np.gradient(mobile, times, axis=0)
    position, velocity, acceleration = (
        np.array([9.0, -6, -10]),
        np.array([0.3, 0.2, 0.0]),
        np.array([-0.016, 0.012, 0.0]),
    )
    truth_p = position + velocity * times[:, None] + 0.5 * acceleration * times[:, None] ** 2
    truth_v = velocity + acceleration * times[:, None]
    z = direct_measurement(truth_p, truth_v, mobile, mobile_velocity, FIXED)
    z[:, 0] -= 1.5
    burst = Burst(times, z, mobile, mobile_velocity, FIXED, np.diag([0.05**2, 0.02**2]), 1.5, direct_measurement)
    config = InitializerConfig(hypotheses=1)
    accelerating = make_initializer("lcmap", config, REGION, "ca")(burst, rng)
    assert np.linalg.norm(accelerating.state[:3] - truth_p[-1]) < 1.0
    assert accelerating.state[6] == pytest.approx(-1.5)
    np.testing.assert_allclose(accelerating.accelerations[0], acceleration, atol=0.004)
    straight = make_initializer("lcmap", config, REGION)(burst, rng)
    assert np.linalg.norm(straight.state[:3] - truth_p[-1]) > 2.0


@pytest.mark.parametrize("name", ["lcmap", "random"])
def test_an_rd_beyond_every_period_of_a_short_baseline_falls_back_to_naive(name, rng):
    """A robot 0.6 m from the fixed hydrophone (as reported) cannot measure an RD of 0.7 m modulo 1.5 m:
    no whole-period sheet has a locus, and the initializer starts naive instead of failing."""
    burst, _ = helix_burst(np.array([5.0, 8, -12]), np.zeros(3), offset=0.0, duration=2.0)
    near = FIXED + np.array([0.6, 0.0, 0.0])
    measurements = burst.measurements.copy()
    measurements[:, 0] = 0.7
    assert len(feasible_offsets(0.7, 0.6, 1.5)) == 0
    short = Burst(
        burst.times,
        measurements,
        np.tile(near, (len(burst.times), 1)),
        burst.receiver_velocities,
        FIXED,
        burst.noise_covariance,
        1.5,
        direct_measurement,
    )
    estimate = make_initializer(name, InitializerConfig(), REGION)(short, rng)
    naive = make_initializer("naive", InitializerConfig(), REGION)(short, rng)
    np.testing.assert_array_equal(estimate.state, naive.state)
