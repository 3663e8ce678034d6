"""Reward terms: small functions, combined with the weights of :class:`~aasl_gym.config.RewardConfig`.

Each term is reported *weighted* in ``info["reward_terms"]``, so the step's reward is their sum.

* ``information_gain``: increase of ``fim_logdet`` (nats) since the last step.
* ``error_shrinkage``: decrease of the true position error (m) since the last step (privileged:
  it uses ground truth, which is fine for training and is never part of the observation).
* ``control_effort``: minus the squared norm of the (clipped) action.
* ``constraint_penalty``: minus one on a step where the robot hit the keep-out zone, the region edge,
  the surface or the bed limit.
* ``success_bonus``: one, on the first step the error falls below ``success_threshold``.

Scale over a 120 s episode with the default weights (free field, signal mode, seeds 2000-2003 of each
of static / CV / CA / CTRV; mean [min, max] of the weighted sums over 16 episodes per policy;
``python benchmarks/reward_scale.py``):

| term | helix | greedy | random |
|---|---|---|---|
| information_gain (weight 1 per nat) | 24.6 [19.6, 29.7] | 32.8 [22.9, 45.8] | 23.3 [15.1, 34.0] |
| error_shrinkage (0.1 per m) | 0.4 [-12.6, 2.9] | 1.2 [-0.2, 3.1] | 0.4 [-1.6, 2.3] |
| control_effort (0.01 per unit of abs(action)^2 per step) | -4.2 | -5.8 [-6.0, -3.9] | -5.9 [-6.0, -5.9] |
| constraint_penalty (1 per step at a limit) | 0 | 0 | -1.5 [-6, 0] |
| success_bonus (10, once) | 10 | 10 | 9.4 [0, 10] |

So the information gain carries the return; the bonus is worth about a third of it, the effort a
fifth (flying at full speed all episode costs 6), and the privileged error term, whose sum telescopes
to (first error - last error) / 10, matters little. The information gain itself telescopes too: an
episode's sum is the final ``fim_logdet`` minus the prior's, so a policy is paid for where the
information ends, spread over the steps that earned it.
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
