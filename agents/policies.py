"""Every non-learned policy by name: :data:`POLICIES` and :func:`make_policy` (what ``evaluate.py`` and the
benchmarks build their planners with; trained models load with :func:`agents.sb3.load_model`)."""

from __future__ import annotations

from aasl_gym.config import PATROLS, EnvConfig
from agents.greedy import GreedyInformationPolicy
from agents.scripted import PatrolPolicy, RandomPolicy, ZeroPolicy

POLICIES = (*PATROLS, "greedy", "random", "zero")


def make_policy(name: str, config: EnvConfig, seed: int | None = None):
    """The policy called ``name`` (one of :data:`POLICIES`) for envs built from ``config``; ``seed`` seeds
    the random policy."""
    if name in PATROLS:
        return PatrolPolicy(name, config)
    if name == "greedy":
        return GreedyInformationPolicy(config)
    if name == "random":
        return RandomPolicy(seed)
    if name == "zero":
        return ZeroPolicy()
    raise ValueError(f"unknown policy {name!r}; allowed: {list(POLICIES)} or ALGO:PATH")
