"""Stable-Baselines3 glue: the only module that imports stable_baselines3 (and sb3_contrib)."""

from __future__ import annotations

import zipfile
from pathlib import Path

ALGORITHMS = ("ppo", "sac", "td3", "a2c", "recurrent-ppo")


def algorithm_class(name: str):
    """The SB3 class for ``name`` (``recurrent-ppo`` needs sb3-contrib)."""
    if name not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {name!r}; allowed: {list(ALGORITHMS)}")
    if name == "recurrent-ppo":
        try:
            from sb3_contrib import RecurrentPPO
        except ImportError as exc:
            raise ImportError("recurrent-ppo needs sb3-contrib: pip install 'aasl-gym[extra]'") from exc
        return RecurrentPPO
    import stable_baselines3

    return getattr(stable_baselines3, name.upper())


def load_model(spec: str, device: str = "cpu"):
    """Load ``ALGO:PATH`` (e.g. ``ppo:runs/x/model.zip``) with a clear error if it is missing or corrupt."""
    algo, sep, path = spec.partition(":")
    if not sep or not path:
        raise ValueError(f"model {spec!r}: expected ALGO:PATH, e.g. ppo:models/ppo_default.zip")
    cls = algorithm_class(algo)
    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f"model {spec!r}: no file at {file}")
    if not zipfile.is_zipfile(file):
        raise ValueError(f"model {spec!r}: {file} is not a Stable-Baselines3 model (not a zip archive)")
    try:
        return cls.load(file, device=device)
    except Exception as exc:  # SB3 raises many kinds on a damaged archive
        raise ValueError(f"model {spec!r}: {file} could not be loaded ({type(exc).__name__}: {exc})") from exc
