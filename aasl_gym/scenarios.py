"""Named scenarios (SPEC section 8): the worlds of the reference paper's studies, one YAML file each.

A scenario is a config file that sets some fields (the rest keep their defaults) and says in its
``description`` which study it reproduces. ``gym.make(..., scenario="shallow-water")`` and ``--scenario``
in ``evaluate.py`` and ``train.py`` select one by name; a ``config`` (a mapping or a YAML file) and the
keyword overrides then change its fields, in that order.

The files live in the checkout's ``configs/scenarios/``; a wheel carries them as ``aasl_gym/_scenarios/``
(``pyproject.toml`` maps the one onto the other).
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from aasl_gym.config import ConfigError, EnvConfig, from_dict, load_config, merge, read_config_file

_PACKAGE = Path(__file__).resolve().parent
_LOCATIONS = (_PACKAGE / "_scenarios", _PACKAGE.parent / "configs" / "scenarios")  # wheel, checkout


def scenario_directory() -> Path:
    """The directory holding the scenario files."""
    for location in _LOCATIONS:
        if location.is_dir():
            return location
    raise FileNotFoundError(f"no scenario directory: looked in {[str(p) for p in _LOCATIONS]}")


def scenario_names() -> tuple[str, ...]:
    """Every scenario's name, sorted: the stems of ``configs/scenarios/*.yaml``."""
    return tuple(sorted(path.stem for path in scenario_directory().glob("*.yaml")))


def _read(name: str) -> dict[str, Any]:
    names = scenario_names()
    if name not in names:
        raise ConfigError(f"scenario: {name!r} is not one of {list(names)}")
    return read_config_file(scenario_directory() / f"{name}.yaml", extra_keys=("description",))


def scenario_description(name: str) -> str:
    """What the scenario is and which study of the reference paper it reproduces."""
    return str(_read(name).get("description", "")).strip()


def scenario_fields(name: str) -> dict[str, Any]:
    """The config fields the scenario sets (nested plain values; its ``description`` left out)."""
    data = _read(name)
    data.pop("description", None)
    return data


def scenario_config(name: str, changes: Mapping[str, Any] | None = None) -> EnvConfig:
    """The scenario's :class:`EnvConfig`, with ``changes`` (nested plain values) over its fields."""
    try:
        return from_dict(merge(scenario_fields(name), changes or {}))
    except ConfigError as exc:
        raise ConfigError(f"scenario {name!r}: {exc}") from exc


def add_scenario_arguments(parser: argparse.ArgumentParser) -> None:
    """The CLIs' ``--scenario`` and ``--config`` (read by :func:`command_line_config`)."""
    parser.add_argument("--scenario", choices=scenario_names(), default=None, help="a named world (configs/scenarios/)")
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="YAML config; with --scenario, the fields to change (default: configs/default.yaml or the scenario)",
    )


def command_line_config(scenario: str | None, config_file: str | Path | None, default_file: str | Path) -> EnvConfig:
    """The config a CLI runs with: ``--config FILE``'s fields over ``--scenario NAME``'s; with neither
    option, ``default_file``. A :class:`ConfigError` names the option at fault."""
    try:
        fields = {} if scenario is None else scenario_fields(scenario)
    except ConfigError as exc:
        raise ConfigError(f"--scenario: {exc}") from exc
    if config_file is None and scenario is not None:
        return from_dict(fields)  # checked as it was read
    try:
        return load_config(config_file or default_file, base=fields)
    except ConfigError as exc:
        raise ConfigError(f"--config: {exc}") from exc
