"""One episode of a policy on an env: the loop that evaluation, training's periodic evaluation and the
benchmarks share."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np


def play_episode(
    env, policy, seed: int, on_step: Callable[[float, dict[str, Any]], None] | None = None
) -> dict[str, Any]:
    """Run ``policy`` (anything with SB3's ``predict``, deterministic, its recurrent state carried) on
    ``env`` from ``reset(seed=seed)`` to the end; ``on_step(reward, info)`` sees every step. Returns the
    last step's info (which carries the episode's metrics)."""
    obs, _ = env.reset(seed=seed)
    state, episode_start, done = None, np.ones(1, dtype=bool), False
    while not done:
        action, state = policy.predict(obs, state=state, episode_start=episode_start, deterministic=True)
        episode_start = np.zeros(1, dtype=bool)
        obs, reward, terminated, truncated, info = env.step(action)
        if on_step is not None:
            on_step(reward, info)
        done = terminated or truncated
    return info
