"""The information-greedy planner and the noise model it plans with."""

import numpy as np
import pytest

from aasl_gym.config import EnvConfig
from aasl_gym.env import AASLEnv
from aasl_gym.fisher import position_information_logdet, updated_covariance
from aasl_gym.measurement_models import expected_noise_covariance, navigation_covariance
from aasl_gym.planning import GreedyPlanner, candidate_directions
from agents import make_policy


def test_expected_noise_is_what_the_front_end_tells_the_filter():
    """Signal mode: R planned from the SNR model at the true geometry against the R the sensor derives
    from a frame's *measured* SNRs - within 15 % in sd (the measured SNR is the model's within 1 dB).
    Geometric mode: the configured sd, plus the navigation term in both."""
    env = AASLEnv(None, source_motion="cv", reflections=False, multipath="none").unwrapped
    env.reset(seed=4)
    for _ in range(20):
        *_, info = env.step(np.zeros(3))
        planned = expected_noise_covariance(env.config, info["source_position"], info["receiver_position"])
        told = env.sensor.covariance() + env.navigation_covariance
        np.testing.assert_allclose(np.sqrt(np.diag(planned)), np.sqrt(np.diag(told)), rtol=0.15)
    geometric = EnvConfig().replace(measurement={"mode": "geometric"})
    planned = expected_noise_covariance(geometric, np.zeros((4, 3)), np.ones((4, 3)))
    m = geometric.measurement
    expected = np.diag([m.range_difference_sd**2, m.range_rate_difference_sd**2]) + navigation_covariance(geometric)
    assert planned.shape == (4, 2, 2)
    np.testing.assert_allclose(planned, np.broadcast_to(expected, (4, 2, 2)))


def test_candidates_are_unit_commands_and_the_zero_command():
    for surface, count in ((False, 27), (True, 9)):
        commands = candidate_directions(surface)
        assert commands.shape == (count, 3)
        norms = np.linalg.norm(commands, axis=1)
        assert np.allclose(norms[:-1], 1.0) and norms[-1] == 0.0
        assert not surface or np.all(commands[:, 2] == 0)


def test_scores_are_the_information_after_the_horizon():
    """The planner's score for a command equals an independent step-by-step recursion along that
    command's straight path (here: the first candidate, five steps)."""
    config = EnvConfig().replace(measurement={"mode": "geometric"})
    planner = GreedyPlanner(config, horizon=1.0)
    receiver, estimate, velocity = np.array([15.0, 0.0, -7.0]), np.array([3.0, -4.0, -10.0]), np.array([0.2, 0.1, 0.0])
    start = np.diag([4.0, 4, 4, 0.5, 0.5, 0.5, 1.0, 1e-3])
    scores = planner.scores(start, estimate, velocity, receiver)
    from aasl_gym.fisher import cv_transition_matrix, measurement_jacobian

    f = cv_transition_matrix(config.dt)
    for index in (0, 13, len(planner.commands) - 1):  # a diagonal, a straight and the zero command
        command, covariance = planner.commands[index], start
        for k in range(1, 6):
            at = receiver + command * k * config.dt
            source = estimate + velocity * k * config.dt
            jacobian = measurement_jacobian(source, velocity, at, command, planner.fixed)
            covariance = updated_covariance(
                f @ covariance @ f.T + planner.process_noise, jacobian, expected_noise_covariance(config, source, at)
            )
        assert scores[index] == pytest.approx(float(position_information_logdet(covariance)), rel=1e-9)
    planner.information.reset(start)
    assert np.all(planner.command(estimate, velocity, receiver) == planner.commands[np.argmax(scores)])


def test_greedy_gathers_more_information_than_random_on_a_fixed_seed():
    """Same seed, 30 s: the greedy planner ends with more position information (the env's own
    fim_logdet, at the filter's estimate) than uniformly random commands."""
    final = {}
    for name in ("greedy", "random"):
        env = AASLEnv({"episode": {"duration": 30.0}}, source_motion="static", reflections=False, multipath="none")
        policy = make_policy(name, env.config, seed=0)
        obs, _ = env.reset(seed=1001)
        done = False
        while not done:
            action, _ = policy.predict(obs)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        final[name] = info["fim_logdet"]
    assert final["greedy"] > final["random"] + 1.0  # nats: e times more information at least


def test_greedy_env_with_zero_action_flies_the_greedy_policy():
    """AASL-Greedy-v0's planner (inside the env, from the tracker's estimate) and the obs-only greedy
    policy on AASL-v0 carry the same information and choose the same commands: same seed, same path."""
    import gymnasium as gym

    config = {"world": {"reflections": False}, "filter": {"multipath": "none"}}
    residual = gym.make("AASL-Greedy-v0", config=config, source_motion="cv").unwrapped
    plain = AASLEnv(config, source_motion="cv")
    policy = make_policy("greedy", plain.config)
    residual.reset(seed=7)
    obs, _ = plain.reset(seed=7)
    for _ in range(60):
        *_, info_residual = residual.step(np.zeros(3))
        action, _ = policy.predict(obs)
        obs, *_, info_plain = plain.step(action)
        np.testing.assert_allclose(info_residual["receiver_position"], info_plain["receiver_position"], atol=1e-4)
    assert info_plain["initialized"]
