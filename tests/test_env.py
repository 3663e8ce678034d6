"""Registry-wide checks over every id, plus the env's contract: info keys, seeding, actions, rendering."""

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import aasl_gym
from aasl_gym.fisher import information_prior
from aasl_gym.measurement_models import model_snr
from aasl_gym.observation import OBSERVATION_SIZE
from agents import PatrolPolicy

IDS = list(aasl_gym.ALL_IDS)
INFO_KEYS = {
    "time",
    "source_position",
    "source_velocity",
    "receiver_position",
    "receiver_velocity",
    "receiver_position_reported",
    "fixed_position",
    "estimate_position",
    "estimate_velocity",
    "position_error",
    "position_covariance",
    "measurement",
    "measured",
    "measurement_true",
    "snr_db",
    "initialized",
    "converged",
    "reinitialized",
    "fim_logdet",
    "reward_terms",
}
LAST_KEYS = {"convergence_time", "rmse", "final_error", "success", "time_to_first_estimate", "reinitializations"}


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasium_env_checker_with_the_defaults(env_id):
    """The checker compares two seeded first steps with np.allclose (NaN != NaN): it passes only
    because the estimate before the filter starts is the prior and the measurement before the first
    frame (the facility's, before its attack) is the observation's zeros - never NaN."""
    env = gym.make(env_id, render_mode="rgb_array")
    gym_check_env(env.unwrapped)


def test_before_the_filter_starts_the_estimate_is_the_finite_prior():
    env = gym.make("AASL-v0", measurement="geometric").unwrapped
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(3))
    assert not info["initialized"]
    mean, covariance = information_prior(env.config)
    np.testing.assert_array_equal(info["estimate_position"], mean[:3])
    np.testing.assert_array_equal(info["position_covariance"], covariance[:3, :3])
    assert info["position_error"] == pytest.approx(np.linalg.norm(mean[:3] - info["source_position"]))
    assert all(np.all(np.isfinite(value)) for value in info.values() if isinstance(value, (float, np.ndarray)))


@pytest.mark.parametrize("env_id", IDS)
def test_sb3_env_checker(env_id):
    sb3_check_env(gym.make(env_id).unwrapped, warn=True)


def rollout(env, seed, steps, action=None):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        a = rng.uniform(-1, 1, 3) if action is None else action
        obs, reward, _, _, info = env.step(a)
        out.append((obs, reward, info["estimate_position"], info["measurement"]))
    return out


def same(a, b):
    return pickle.dumps(a) == pickle.dumps(b)


@pytest.mark.parametrize("env_id", IDS)
def test_same_seed_same_episode_bit_for_bit(env_id):
    early = {"config": {"facility": {"onset_range": [0.5, 2.0]}}} if env_id == aasl_gym.FACILITY_ID else {}
    env = gym.make(env_id, source_motion="mixed", **early)  # the facility's attack early: past the hand-over
    assert same(rollout(env, 7, 40), rollout(env, 7, 40))
    assert not same(rollout(env, 7, 40), rollout(env, 8, 40))


@pytest.mark.parametrize("env_id", IDS)
def test_pickles_and_runs_after_unpickling(env_id):
    env = gym.make(env_id)
    env.reset(seed=1)
    env.step(np.zeros(3))
    clone = pickle.loads(pickle.dumps(env))
    a = clone.step(np.zeros(3))
    b = env.step(np.zeros(3))
    assert np.array_equal(a[0], b[0])


def test_async_vector_env():
    envs = gym.vector.AsyncVectorEnv([lambda: gym.make("AASL-Helix-v0") for _ in range(2)])
    obs, _ = envs.reset(seed=[1, 2])
    assert obs.shape == (2, OBSERVATION_SIZE)
    for _ in range(15):
        obs, *_ = envs.step(np.zeros((2, 3), dtype=np.float32))
    assert np.all(np.isfinite(obs))
    envs.close()


def test_sb3_subproc_vec_env():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    envs = make_vec_env("aasl_gym:AASL-v0", n_envs=2, seed=0, vec_env_cls=SubprocVecEnv)
    envs.reset()
    obs, *_ = envs.step(np.zeros((2, 3), dtype=np.float32))
    assert obs.shape == (2, OBSERVATION_SIZE)
    envs.close()


def test_info_contract_over_a_whole_episode():
    env = gym.make("AASL-Helix-v0", source_motion="cv", reflections=False, multipath="none")
    env.reset(seed=3)
    done, step = False, 0
    while not done:
        obs, reward, terminated, truncated, info = env.step(np.zeros(3))
        done = terminated or truncated
        step += 1
        assert set(info) >= INFO_KEYS
        for key in (
            "source_position",
            "receiver_position",
            "estimate_position",
            "measurement",
            "measurement_true",
            "position_covariance",
        ):
            assert info[key].dtype == np.float64
        assert info["position_covariance"].shape == (3, 3)
        assert reward == pytest.approx(sum(info["reward_terms"].values()))
        assert info["position_error"] == pytest.approx(
            np.linalg.norm(info["estimate_position"] - info["source_position"])
        )
        assert LAST_KEYS.isdisjoint(info) or done
        assert obs.shape == (OBSERVATION_SIZE,) and np.all(np.abs(obs) <= 10)
    assert step == 600 and truncated and set(info) >= LAST_KEYS
    assert info["time"] == pytest.approx(120.0)


def test_geometric_track_is_truth_plus_a_whole_number_of_wavelengths():
    env = gym.make("AASL-v0", measurement="geometric", reflections=False, config={"receiver": {"nav_position_sd": 0.0}})
    env.reset(seed=5)
    offsets = []
    for _ in range(200):
        *_, info = env.step(np.array([0.5, 0.3, 0.0]))
        offsets.append(info["measurement"][0] - info["measurement_true"][0])
    offsets = np.array(offsets) / 1.5
    k = np.round(np.median(offsets))
    assert np.all(np.abs(offsets - k) < 0.2)  # sigma_R = 5 cm = 0.033 wavelengths: 6 sigma


def test_actions_nonfinite_rejected_and_out_of_box_clipped():
    env = gym.make("AASL-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0, 0]))
    for action, message in (
        (np.zeros((1, 3)), r"shape \(3,\), got \(1, 3\)"),  # not flattened: a batch of one is a caller's mistake
        (None, r"shape \(3,\), got \(\)"),
        (["a", "b", "c"], "three real numbers, got <U1"),
        (np.zeros(3, complex), "three real numbers, got complex128"),
    ):
        with pytest.raises(ValueError, match=message):
            env.step(action)
    env.step(np.zeros(3, int))  # integers are numbers
    a = gym.make("AASL-v0")
    b = gym.make("AASL-v0")
    a.reset(seed=4)
    b.reset(seed=4)
    oa = a.step(np.array([5.0, -3.0, 0.2]))
    ob = b.step(np.array([1.0, -1.0, 0.2]))
    assert np.array_equal(oa[0], ob[0])


def test_patrol_policy_on_aasl_v0_flies_the_patrol_env():
    plain, patrol = gym.make("AASL-v0"), gym.make("AASL-Helix-v0")
    policy = PatrolPolicy("helix", plain.unwrapped.config)
    obs, _ = plain.reset(seed=2)
    patrol.reset(seed=2)
    for _ in range(100):
        action, _ = policy.predict(obs)
        obs, *_, info_a = plain.step(action)
        *_, info_b = patrol.step(np.zeros(3))
        np.testing.assert_allclose(info_a["receiver_position"], info_b["receiver_position"], atol=1e-3)


def test_rgb_array_render_headless():
    env = gym.make("AASL-Helix-v0", render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(20):
        env.step(np.zeros(3))
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8 and frame.std() > 0
    env.close()


def test_terminate_on_convergence_option():
    env = gym.make(
        "AASL-Helix-v0",
        source_motion="static",
        reflections=False,
        multipath="none",
        config={"episode": {"terminate_on_convergence": True, "convergence_threshold": 30.0}},
    )
    env.reset(seed=0)
    for _ in range(600):
        *_, terminated, _, info = env.step(np.zeros(3))
        if terminated:
            assert info["position_error"] < 30.0 and "convergence_time" in info
            break
    assert terminated


SIGNAL = {"measurement": {"mode": "signal"}, "initializer": {"burst_duration": 0.2}}


@pytest.mark.parametrize("path", ["fast", "hardware"])
def test_signal_mode_passes_the_env_checkers_and_repeats_bit_for_bit(path):
    config = {**SIGNAL, "signal": {"path": path}}
    gym_check_env(gym.make("AASL-Helix-v0", config=config).unwrapped)
    env = gym.make("AASL-Helix-v0", config=config, source_motion="cv")
    assert same(rollout(env, 3, 15), rollout(env, 3, 15))


def test_signal_mode_measures_the_geometry_up_to_whole_wavelengths():
    """Free field: the front end's RD (info['measurement']) is the geometry's (info['measurement_true'])
    plus one fixed whole number of wavelengths, within a few sd of the R it hands the filter, and no part
    of a period on average (the initializer study's filter takes b_p as whole periods); its RRD matches
    likewise; the measured SNR is the model's within 1 dB."""
    env = gym.make("AASL-Helix-v0", config=SIGNAL, source_motion="cv", reflections=False, multipath="none").unwrapped
    env.reset(seed=11)
    wavelength = env.config.wavelength
    offsets, rd_errors, rrd_errors = [], [], []
    for _ in range(50):
        *_, info = env.step(np.zeros(3))
        sd = np.sqrt(np.diag(env.sensor.covariance()))
        periods = (info["measurement"][0] - info["measurement_true"][0]) / wavelength
        assert abs(periods - round(periods)) * wavelength < 5 * sd[0]
        offsets.append(round(periods))
        rd_errors.append((periods - round(periods)) * wavelength / sd[0])
        rrd_errors.append((info["measurement"][1] - info["measurement_true"][1]) / sd[1])
        receivers = np.array([info["receiver_position"], info["fixed_position"]])
        model_snr_db = 10 * np.log10(np.min(model_snr(env.config, info["source_position"], receivers)))
        assert info["snr_db"] == pytest.approx(model_snr_db, abs=1.0)
    assert len(set(offsets)) == 1
    assert abs(np.mean(rd_errors)) < 4 / np.sqrt(len(rd_errors))  # in sd: a bias of 0.57 sd would fail
    assert np.std(rrd_errors) < 1.5  # the R handed to the filter is not too small


@pytest.mark.parametrize("waveform", ["sweep", "hop"])
def test_wideband_signal_mode_is_not_unwrapped(waveform):
    """A sweep's or hop's delay is unambiguous: the env hands its RD on as measured, so it matches the
    geometry itself (no whole-wavelength offset) within a few sd of the R the filter is told, plus the
    2e-3 |RD| of two Doppler-scaled copies."""
    config = {**SIGNAL, "source": {"waveform": waveform}}
    env = gym.make("AASL-Helix-v0", config=config, source_motion="cv", reflections=False, multipath="none").unwrapped
    env.reset(seed=3)
    for _ in range(40):
        *_, info = env.step(np.zeros(3))
        sd = np.sqrt(np.diag(env.sensor.covariance()))
        error = info["measurement"] - info["measurement_true"]
        assert abs(error[0]) < 5 * sd[0] + 2e-3 * abs(info["measurement_true"][0])
        assert abs(error[1]) < 5 * sd[1] + 0.03
