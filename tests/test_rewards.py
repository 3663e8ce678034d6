"""Reward terms: the information gain and the error shrinkage telescope over an episode, every term is
weighted as configured, and the step's reward is their sum."""

import math

import numpy as np
import pytest

from aasl_gym import rewards
from aasl_gym.config import EnvConfig, RewardConfig
from aasl_gym.env import AASLEnv


def test_the_shaping_terms_telescope_and_the_reward_is_their_weighted_sum():
    """Summed over an episode, the information gain is the last fim_logdet minus the prior's and the
    error shrinkage the first tracked error minus the last, each times its weight."""
    config = EnvConfig().replace(
        measurement={"mode": "geometric"},
        world={"reflections": False},
        episode={"duration": 30.0},
        reward={"information_gain": 0.5, "error_shrinkage": 2.0},
    )
    env = AASLEnv(config, patrol="helix")
    _, _ = env.reset(seed=3)
    prior_logdet = env.information.logdet
    infos, total = [], 0.0
    done = False
    while not done:
        _, reward, terminated, truncated, info = env.step(np.zeros(3))
        assert reward == pytest.approx(sum(info["reward_terms"].values()))
        total += reward
        infos.append(info)
        done = terminated or truncated
    gain = sum(i["reward_terms"]["information_gain"] for i in infos)
    assert gain == pytest.approx(0.5 * (infos[-1]["fim_logdet"] - prior_logdet))
    tracked = [i["position_error"] for i in infos if i["initialized"]]
    shrinkage = sum(i["reward_terms"]["error_shrinkage"] for i in infos)
    assert shrinkage == pytest.approx(2.0 * (tracked[0] - tracked[-1]))


def test_terms_ignore_what_is_not_yet_defined_and_are_weighted():
    assert rewards.information_gain(math.nan, 3.0) == 0.0 and rewards.error_shrinkage(math.nan, 1.0) == 0.0
    assert rewards.control_effort(np.array([0.6, 0.8, 0.0])) == pytest.approx(-1.0)
    raw = {
        "information_gain": 2.0,
        "error_shrinkage": 1.0,
        "control_effort": -1.0,
        "constraint_penalty": -1.0,
        "success_bonus": 1.0,
    }
    weights = RewardConfig()
    weighted = rewards.weighted_terms(weights, raw)
    assert weighted == {name: getattr(weights, name) * value for name, value in raw.items()}
