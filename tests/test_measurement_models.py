"""The filter's measurement models against independent truths: the direct path's closed-form receiver
Jacobian, a Monte Carlo of navigation errors, and a Monte Carlo of the unscented transform."""

from functools import partial

import numpy as np
import pytest

from aasl_gym import geometry
from aasl_gym.config import EnvConfig
from aasl_gym.estimator import SourceTracker
from aasl_gym.filters import merwe_sigma_points, merwe_weights
from aasl_gym.measurement_models import (
    PhasorModel,
    Propagation,
    direct_measurement,
    multipath_measurement,
    multipath_spread,
    receiver_jacobian,
    receiver_noise,
)
from aasl_gym.motion import receiver_region, source_region

FIXED = np.array([0.0, 0.0, -0.96])
PHASOR = partial(multipath_measurement, "phasor", Propagation(60.0, -0.9, 0.3, 2 * np.pi / 1.5))


def scenes(rng, n):
    source = rng.uniform([-30, -30, -50], [30, 30, -2], (n, 3))
    mobile = rng.uniform([-20, -20, -12], [20, 20, -2], (n, 3))
    return source, rng.normal(0, 1, (n, 3)), mobile, rng.normal(0, 1, (n, 3))


def test_receiver_jacobian_of_the_direct_path_is_the_closed_form(rng):
    """dRD/dp_m = -u_m, dRD/dv_m = 0, dRRD/dv_m = -u_m, dRRD/dp_m = -(I - u u^T)(v_s - v_m) / d_m."""
    source, velocity, mobile, mobile_velocity = scenes(rng, 50)
    # Wrapped, the direct path is differenced like any model; given itself, it takes the closed form.
    differenced = receiver_jacobian(lambda *a: direct_measurement(*a), source, velocity, mobile, mobile_velocity, FIXED)
    np.testing.assert_allclose(
        receiver_jacobian(direct_measurement, source, velocity, mobile, mobile_velocity, FIXED), differenced, atol=1e-6
    )
    jacobian = differenced
    distance, unit = geometry.ranges(source, mobile)
    relative = velocity - mobile_velocity
    along = np.einsum("ni,ni->n", relative, unit)
    np.testing.assert_allclose(jacobian[:, 0, :3], -unit, atol=1e-7)
    np.testing.assert_allclose(jacobian[:, 0, 3:], 0.0, atol=1e-12)
    np.testing.assert_allclose(jacobian[:, 1, 3:], -unit, atol=1e-9)
    np.testing.assert_allclose(jacobian[:, 1, :3], -(relative - unit * along[:, None]) / distance[:, None], atol=1e-6)


@pytest.mark.parametrize("model", [PHASOR, PhasorModel(PHASOR.args[1])], ids=["differenced", "linearized"])
def test_navigation_term_matches_a_monte_carlo_of_receiver_errors(rng, model):
    """Under multipath the apparent RD and RRD move with the receiver far more than the direct path's;
    H_r Sigma_r H_r^T must match the spread of the model over sampled navigation errors (small errors:
    3 mm, 1.2 mm/s, where first order holds), with H_r by differences of the model or from its own
    linearization (a geometric world's tracker's)."""
    source, velocity = np.array([-6.8, 11.5, -21.5]), np.array([0.3, 0.02, -0.15])
    mobile, mobile_velocity = np.array([15.0, 0, -7.0]), np.array([0.0, 1.0, 0.0])
    position_sd, velocity_sd = 0.003, 0.0012
    expected = receiver_noise(
        receiver_jacobian(model, source, velocity, mobile, mobile_velocity, FIXED), position_sd, velocity_sd
    )
    samples = 20000
    z = PHASOR(
        source,
        velocity,
        mobile + position_sd * rng.normal(size=(samples, 3)),
        mobile_velocity + velocity_sd * rng.normal(size=(samples, 3)),
        FIXED,
    )
    sampled = np.cov(z.T)
    np.testing.assert_allclose(np.diag(sampled), np.diag(expected), rtol=0.06)
    correlation = sampled[0, 1] / np.sqrt(sampled[0, 0] * sampled[1, 1])
    assert correlation == pytest.approx(expected[0, 1] / np.sqrt(expected[0, 0] * expected[1, 1]), abs=0.03)
    # The direct path's isotropic approximation diag(sigma_p^2, sigma_v^2) is far off here (why R_eff needs H_r).
    assert expected[0, 0] > 3 * position_sd**2 and expected[1, 1] > 30 * velocity_sd**2


def phasor_tracker() -> SourceTracker:
    config = EnvConfig()
    return SourceTracker(config, source_region(config.world, config.source), np.eye(2))


@pytest.mark.parametrize("seed", range(3))
def test_unscented_transform_of_the_phasor_model_matches_monte_carlo(seed):
    """The tracker's h (the phasor model, its multipath correction kept continuous across the sigma
    points) through Merwe sigma points gives the mean and covariance of z that a Monte Carlo of the
    same Gaussian does, within the Monte Carlo's error plus a small share of the spread."""
    rng = np.random.default_rng(seed)
    tracker = phasor_tracker()
    state = np.zeros(8)
    state[0:3], state[3:6] = rng.uniform([-20, -20, -30], [20, 20, -3]), rng.normal(0, 0.5, 3)
    covariance = np.diag([0.05**2] * 3 + [0.02**2] * 3 + [0.01**2] * 2)
    mobile, mobile_velocity = np.array([15.0, 0.0, -7.0]), np.array([0.0, 1.0, 0.0])

    def h(points):  # row 0, the mean, anchors the multipath correction as in the UKF; resolved: the ripple is modelled
        return tracker._sigma_measurements(points[None], np.array([0.05]), np.array([True]), mobile, mobile_velocity)[
            0
        ][0]

    f = tracker.config.filter
    wm, wc, spread = merwe_weights(8, f.alpha, f.beta, f.kappa)
    sigma_z = h(merwe_sigma_points(state, covariance, spread))
    mean = wm @ sigma_z
    deviation = sigma_z - mean
    ut_covariance = (deviation.T * wc) @ deviation
    z = h(np.vstack([state, rng.multivariate_normal(state, covariance, 20000)]))[1:]
    mc_mean, mc_covariance = z.mean(axis=0), np.cov(z.T)
    mc_error = np.sqrt(np.diag(mc_covariance) / len(z))
    np.testing.assert_array_less(np.abs(mean - mc_mean), 4 * mc_error + 0.05 * np.sqrt(np.diag(mc_covariance)))
    np.testing.assert_allclose(np.diag(ut_covariance), np.diag(mc_covariance), rtol=0.1)


def test_an_unresolved_hypothesis_takes_the_ripple_as_noise():
    """Wider than the ripple: every sigma point gets the correction at the mean, and the correction's
    spread over the sigma points (computed here from the phasor and direct models) is added to R."""
    tracker = phasor_tracker()
    state = np.zeros(8)
    state[0:3], state[3:6] = [12.0, -6.0, -9.0], [0.3, 0.1, 0.0]
    wide = np.diag([2.0**2] * 3 + [0.2**2] * 3 + [0.01**2] * 2)
    f = tracker.config.filter
    _, _, spread = merwe_weights(8, f.alpha, f.beta, f.kappa)
    sigmas = merwe_sigma_points(state, wide, spread)
    mobile, mobile_velocity = np.array([15.0, 0.0, -7.0]), np.array([0.0, 1.0, 0.0])
    z, noise = tracker._sigma_measurements(sigmas[None], np.array([2.0]), np.array([False]), mobile, mobile_velocity)
    direct = direct_measurement(sigmas[:, 0:3], sigmas[:, 3:6], mobile, mobile_velocity, FIXED)
    # The tracker's phasor model: averaged over the frame, as its signal-mode front end measures.
    correction = tracker.measurement_function(sigmas[:, 0:3], sigmas[:, 3:6], mobile, mobile_velocity, FIXED) - direct
    correction[:, 0] = correction[0, 0] + geometry.wrap_to_period(correction[:, 0] - correction[0, 0], 1.5)
    np.testing.assert_allclose(z[0] - sigmas[:, -2:], direct + correction[0], atol=1e-9)
    deviation = correction[1:] - correction[0]
    navigation = receiver_noise(
        receiver_jacobian(direct_measurement, state[0:3], state[3:6], mobile, mobile_velocity, FIXED), 0.05, 0.02
    )
    np.testing.assert_allclose(noise[0], deviation.T @ deviation / (2 * spread) + navigation, rtol=1e-6)


def test_the_multipath_spread_vanishes_without_reflections_and_is_bounded_with_them():
    """The ripple's spread over the volume: zero when no image reflects, and an RD sd no larger than a
    correction uniform over a wavelength (lambda / sqrt(12)) when they do."""
    config = EnvConfig()
    sources, receivers = source_region(config.world, config.source), receiver_region(config.world, config.receiver)
    silent = Propagation(60.0, 0.0, 0.0, 2 * np.pi / 1.5)
    np.testing.assert_allclose(multipath_spread(silent, sources, receivers, FIXED, 1.5, 1.5), 0.0, atol=1e-20)
    spread = multipath_spread(Propagation(60.0, -0.9, 0.3, 2 * np.pi / 1.5), sources, receivers, FIXED, 1.5, 1.5)
    assert 0.01 < np.sqrt(spread[0, 0]) <= 1.5 / np.sqrt(12) and spread[1, 1] > 0.01
