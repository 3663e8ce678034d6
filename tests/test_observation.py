"""The observation's layout, its encoder and decoder: the decoder undoes the encoder, and what the agents
decode from the env's observation is what the env's info reports."""

import gymnasium as gym
import numpy as np
import pytest

from aasl_gym.config import EnvConfig
from aasl_gym.observation import (
    OBSERVATION_LAYOUT,
    OBSERVATION_SIZE,
    OBSERVATION_SLICES,
    Observation,
    decode_observation,
    encode_observation,
)

CONFIG = EnvConfig()


def test_the_layout_is_laid_end_to_end():
    assert OBSERVATION_SIZE == 21
    ends = [0] + [OBSERVATION_SLICES[name].stop for name, _, _ in OBSERVATION_LAYOUT]
    for (name, length, _), start in zip(OBSERVATION_LAYOUT, ends):
        assert OBSERVATION_SLICES[name] == slice(start, start + length)


def test_decoding_undoes_encoding_to_float32_precision(rng):
    known = Observation(
        time=37.4,
        receiver_position=rng.uniform(-30, 0, 3),
        receiver_velocity=rng.uniform(-1, 1, 3),
        measurement=np.array([3.2, -0.4]),
        innovation=np.array([0.7, -1.9]),
        initialized=True,
        estimate_position=rng.uniform(-30, 0, 3),
        estimate_velocity=rng.uniform(-1, 1, 3),
        position_variance=np.array([0.3, 2.0, 0.01]),
    )
    vector = encode_observation(known, CONFIG)
    assert vector.dtype == np.float32 and vector.shape == (OBSERVATION_SIZE,)
    seen = decode_observation(vector, CONFIG)
    assert seen.initialized and seen.time == pytest.approx(known.time, rel=1e-6)
    for name in (
        "receiver_position",
        "receiver_velocity",
        "measurement",
        "innovation",
        "estimate_position",
        "estimate_velocity",
        "position_variance",
    ):
        np.testing.assert_allclose(getattr(seen, name), getattr(known, name), rtol=1e-5, atol=1e-5)


def test_before_the_filter_starts_there_is_no_estimate_to_decode():
    known = Observation(1.0, np.array([5.0, 0, -5]), np.zeros(3), np.zeros(2), np.zeros(2), initialized=False)
    vector = encode_observation(known, CONFIG)
    for name in ("relative_estimate", "estimate_velocity", "log_variance", "initialized"):
        assert not vector[OBSERVATION_SLICES[name]].any()
    seen = decode_observation(vector, CONFIG)
    assert not seen.initialized and seen.estimate_position is None and seen.position_variance is None


def test_the_decoded_env_observation_is_what_info_reports():
    env = gym.make("AASL-Helix-v0", measurement="geometric", source_motion="cv")
    env.reset(seed=2)
    for _ in range(30):
        obs, *_, info = env.step(np.zeros(3))
        seen = decode_observation(obs, env.unwrapped.config)
        assert seen.time == pytest.approx(info["time"])
        np.testing.assert_allclose(seen.receiver_position, info["receiver_position_reported"], atol=1e-4)
        np.testing.assert_allclose(seen.measurement, info["measurement"], atol=1e-4)
        if seen.initialized:
            np.testing.assert_allclose(seen.estimate_position, info["estimate_position"], atol=1e-4)
    assert info["initialized"] and seen.initialized
