"""Reward terms: small functions, combined with the weights of :class:`~aasl_gym.config.RewardConfig`.

Each term is reported *weighted* in ``info["reward_terms"]``, so the step's reward is their sum.

* ``information_gain``: increase of ``fim_logdet`` (nats) since the last step.
* ``error_shrinkage``: decrease of the true position error (m) since the last step (privileged:
  it uses ground truth, which is fine for training and is never part of the observation).
* ``control_effort``: minus the squared norm of the (clipped) action.
* ``constraint_penalty``: minus one on a step where the robot hit the keep-out zone, the region edge,
  the surface or the bed limit.
* ``success_bonus``: one, on the first step the error falls below ``success_threshold``.
"""

from __future__ import annotations

import math

import numpy as np

from aasl_gym.config import RewardConfig

TERMS = ("information_gain", "error_shrinkage", "control_effort", "constraint_penalty", "success_bonus")


def information_gain(previous_logdet: float, logdet: float) -> float:
    return logdet - previous_logdet if math.isfinite(previous_logdet) and math.isfinite(logdet) else 0.0


def error_shrinkage(previous_error: float, error: float) -> float:
    return previous_error - error if math.isfinite(previous_error) and math.isfinite(error) else 0.0


def control_effort(action: np.ndarray) -> float:
    return -float(action @ action)


def constraint_penalty(hit: bool) -> float:
    return -1.0 if hit else 0.0


def success_bonus(first_success: bool) -> float:
    return 1.0 if first_success else 0.0


def weighted_terms(config: RewardConfig, raw: dict[str, float]) -> dict[str, float]:
    """Multiply each raw term by its configured weight."""
    return {name: getattr(config, name) * raw[name] for name in TERMS}
