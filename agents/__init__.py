"""Policies that answer ``predict(obs, state=None, episode_start=None, deterministic=True)`` like SB3 models.

``make_policy(name, config)`` builds one by name: ``helix``, ``spiral``, ``circle``, ``lawnmower``,
``greedy`` (the information-greedy planner of :mod:`agents.greedy`), ``random`` or ``zero``. Trained Stable-Baselines3 models load with :func:`agents.sb3.load_model`.
"""

from agents.scripted import POLICIES, PatrolPolicy, RandomPolicy, ZeroPolicy, make_policy

__all__ = ["POLICIES", "PatrolPolicy", "RandomPolicy", "ZeroPolicy", "make_policy"]
