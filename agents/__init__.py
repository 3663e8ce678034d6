"""Policies that answer ``predict(obs, state=None, episode_start=None, deterministic=True)`` like SB3 models.

``make_policy(name, config)`` builds one by name: ``helix``, ``spiral``, ``circle``, ``lawnmower``,
``greedy`` (the information-greedy planner of :mod:`agents.greedy`), ``random`` or ``zero``. Trained
Stable-Baselines3 models load with :func:`agents.sb3.load_model`. The policies decode observations with
:mod:`aasl_gym.observation`; ``scripted`` and ``greedy`` do not import each other, and
:mod:`agents.policies` builds either by name.
"""

from agents.policies import POLICIES, make_policy
from agents.scripted import PatrolPolicy, RandomPolicy, ZeroPolicy

__all__ = ["POLICIES", "PatrolPolicy", "RandomPolicy", "ZeroPolicy", "make_policy"]
