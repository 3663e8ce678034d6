"""The EKF-form Fisher information against independent truths: the information-form update, a linear
Kalman filter's covariance, and a lost frame."""

import numpy as np
import pytest

from aasl_gym import kernels
from aasl_gym.config import EnvConfig
from aasl_gym.filters import ConstantVelocity
from aasl_gym.fisher import (
    InformationTracker,
    cv_transition_matrix,
    information_prior,
    measurement_jacobian,
    position_information_logdet,
    updated_covariance,
)
from aasl_gym.measurement_models import direct_measurement

FIXED = np.array([0.0, 0.0, -0.96])


def test_the_covariance_update_is_the_information_form(rng):
    """P - P H^T (H P H^T + R)^-1 H P = (P^-1 + H^T R^-1 H)^-1 (the matrix inversion lemma)."""
    root = rng.normal(size=(8, 8))
    covariance = root @ root.T + 8 * np.eye(8)
    jacobian = rng.normal(size=(2, 8))
    noise = np.diag([0.05**2, 0.02**2])
    information = np.linalg.inv(covariance) + jacobian.T @ np.linalg.inv(noise) @ jacobian
    np.testing.assert_allclose(
        updated_covariance(covariance, jacobian, noise), np.linalg.inv(information), rtol=1e-8, atol=1e-12
    )


def test_the_measurement_jacobian_is_the_derivative_of_the_measurement(rng):
    """Central differences of [RD + b_p, RRD + b_v] in every state component."""
    state = np.concatenate([rng.uniform(-20, 20, 3), rng.normal(0, 1, 3), [0.3, 0.01]])
    mobile, mobile_velocity = np.array([12.0, -3, -7]), np.array([0.5, 0.8, 0.0])

    def measure(x):
        return direct_measurement(x[0:3], x[3:6], mobile, mobile_velocity, FIXED) + x[6:8]

    step = 1e-6
    numeric = np.stack(
        [(measure(state + step * e) - measure(state - step * e)) / (2 * step) for e in np.eye(8)], axis=1
    )
    np.testing.assert_allclose(
        measurement_jacobian(state[0:3], state[3:6], mobile, mobile_velocity, FIXED), numeric, atol=1e-7
    )


def test_the_tracker_is_a_kalman_filter_covariance_and_a_lost_frame_only_predicts():
    """Along fixed Jacobians the tracker's covariance is a linear Kalman filter's (predict with F and Q,
    update with H and R), its fim_logdet is -log det of the position block, and a step without a
    measurement adds no information."""
    config = EnvConfig()
    process_noise = ConstantVelocity(config.filter).process_noise(0.2)
    _, prior = information_prior(config)
    tracker = InformationTracker(process_noise)
    tracker.reset(prior)
    covariance = prior.copy()
    noise = np.diag([0.05**2, 0.02**2])
    f = cv_transition_matrix(0.2)
    for k in range(30):
        angle = 0.1 * k
        mobile = np.array([15 * np.cos(angle), 15 * np.sin(angle), -7.0])
        jacobian = measurement_jacobian(
            np.array([5.0, 2, -10]), np.zeros(3), mobile, np.array([-np.sin(angle), np.cos(angle), 0.0]), FIXED
        )
        covariance = f @ covariance @ f.T + process_noise
        gain = covariance @ jacobian.T @ np.linalg.inv(jacobian @ covariance @ jacobian.T + noise)
        covariance = (np.eye(8) - gain @ jacobian) @ covariance
        logdet = tracker.step(0.2, jacobian, noise)
        np.testing.assert_allclose(tracker.covariance, covariance, rtol=1e-6, atol=1e-12)
        assert logdet == pytest.approx(-np.linalg.slogdet(covariance[:3, :3])[1], rel=1e-6)
    before = tracker.covariance.copy()
    tracker.step(0.2, None, noise)
    np.testing.assert_allclose(tracker.covariance, f @ before @ f.T + process_noise)
    assert position_information_logdet(tracker.covariance) < position_information_logdet(before)


def test_the_compiled_step_is_the_numpy_forms(rng):
    """kernels.information_step against F P F^T + Q, updated_covariance and position_information_logdet (a second
    implementation), with a measurement and without; a position block that is not positive definite gives inf."""
    root = rng.normal(size=(8, 8))
    covariance = root @ root.T + np.eye(8)
    process_noise = ConstantVelocity(EnvConfig().filter).process_noise(0.2)
    jacobian, noise = rng.normal(size=(2, 8)), np.array([[0.003, 0.001], [0.001, 0.002]])
    f = cv_transition_matrix(0.2)
    predicted = f @ covariance @ f.T + process_noise
    for measured, expected in ((jacobian, updated_covariance(predicted, jacobian, noise)), (None, predicted)):
        updated, logdet = kernels.information_step(covariance, 0.2, process_noise, measured, noise)
        np.testing.assert_allclose(updated, 0.5 * (expected + expected.T), rtol=1e-10, atol=1e-13)
        assert logdet == pytest.approx(position_information_logdet(expected), rel=1e-10)
    singular = np.diag([1.0, -1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0])
    assert kernels.information_step(singular, 0.0, np.zeros((8, 8)), None, noise)[1] == np.inf
