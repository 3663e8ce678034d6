"""Config loading and validation: every error names the offending key and what is allowed."""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import aasl_gym  # noqa: F401  (registers the ids)
from aasl_gym.config import ConfigError, EnvConfig, from_dict, load_config, to_dict

# training.yaml holds SB3 hyperparameters, not an env config
CONFIGS = sorted(
    p for p in (Path(__file__).resolve().parent.parent / "configs").glob("*.yaml") if p.name != "training.yaml"
)


def test_defaults_round_trip():
    assert from_dict(to_dict(EnvConfig())) == EnvConfig()


@pytest.mark.parametrize("path", CONFIGS, ids=[p.name for p in CONFIGS])
def test_shipped_configs_load(path):
    load_config(path)


def test_default_yaml_is_the_default():
    assert load_config(Path(__file__).resolve().parent.parent / "configs" / "default.yaml") == EnvConfig()


def _field_names(section: dict, prefix: str = "") -> set[str]:
    """Dotted names of a config tree's leaves (a field whose value is a non-empty mapping is a section)."""
    names = set()
    for key, value in section.items():
        nested = isinstance(value, dict) and value
        names |= _field_names(value, f"{prefix}{key}.") if nested else {prefix + key}
    return names


def test_default_yaml_names_every_field():
    """The README sends users to configs/default.yaml for every field: loading it fills missing ones with their
    defaults, so the test above cannot see a field the file leaves out."""
    written = yaml.safe_load((Path(__file__).resolve().parent.parent / "configs" / "default.yaml").read_text())
    assert _field_names(written) == _field_names(to_dict(EnvConfig()))


@pytest.mark.parametrize(
    "data,match",
    [
        ({"world": {"depth": 3}}, r"world\.depth: unknown key; allowed keys are"),
        ({"bogus": {}}, r"bogus: unknown key"),
        (
            {"source": {"motion": "zigzag"}},
            r"source\.motion: 'zigzag' is not one of \['static', 'cv', 'ca', 'ctrv', 'uturn', 'mixed'\]",
        ),
        ({"world": {"water_depth": -5}}, r"world\.water_depth: must be a finite number > 0"),
        ({"world": {"reflections": "yes"}}, r"world\.reflections: must be true or false"),
        ({"receiver": {"start_position": [1, 2]}}, r"receiver\.start_position: must have 3 entries"),
        ({"measurement": {"rate": "fast"}}, r"measurement\.rate: must be a number"),
        ({"filter": {"alpha": 2.0}}, r"filter\.alpha: must lie in \(0, 1\]"),
        ({"source": {"speed_range": [1.0, 0.5]}}, r"source\.speed_range: must satisfy"),
        ({"source": {"confined": "no"}}, r"source\.confined: must be true or false"),
        ({"initializer": {"hypotheses": 0}}, r"initializer\.hypotheses: must be an integer >= 1"),
        ({"filter": {"prune_log_ratio": 0}}, r"filter\.prune_log_ratio: must be a finite number > 0"),
        ({"initializer": {"turn_rate_steps": 0}}, r"initializer\.turn_rate_steps: must be an integer >= 1"),
        ({"initializer": {"max_turn_rate": -0.1}}, r"initializer\.max_turn_rate: must be a finite number > 0"),
        (
            {"initializer": {"acceleration_prior_sd": 0}},
            r"initializer\.acceleration_prior_sd: must be a finite number > 0",
        ),
        (
            {"fault": {"kind": "noisy"}},
            r"fault\.kind: 'noisy' is not one of \['none', 'silent', 'clipped', 'dropped'\]",
        ),
        ({"fault": {"channel": "left"}}, r"fault\.channel: 'left' is not one of"),
        (
            {"fault": {"kind": "silent"}, "measurement": {"mode": "geometric"}},
            r"fault\.kind: 'silent' corrupts a synthesized frame",
        ),
        ({"fault": {"duration": float("nan")}}, r"fault\.duration: must be a finite number >= 0"),
        ({"signal": {"detection_snr_db": float("inf")}}, r"signal\.detection_snr_db: must be finite"),
        ({"filter": {"sheet_check_interval": -1}}, r"filter\.sheet_check_interval: must be a finite number >= 0"),
        ({"filter": {"track_fit": "yes"}}, r"filter\.track_fit: must be true or false, got 'yes'"),
        ({"filter": {"track_search": 1}}, r"filter\.track_search: must be true or false, got 1"),
        ({"filter": {"speed_limit": "fast"}}, r"filter\.speed_limit: must be 'matched', a finite speed > 0"),
        ({"filter": {"speed_limit": 0}}, r"filter\.speed_limit: must be 'matched', a finite speed > 0"),
        ({"filter": {"speed_limit": [1.5]}}, r"filter\.speed_limit: must be a float or str, got \[1\.5\]"),
        ({"initializer": {"search_spacing": 0.1}}, r"initializer\.search_spacing: must be 0 \(no search\) or a finite"),
        ({"initializer": {"search_spacing": -2}}, r"initializer\.search_spacing: must be 0 \(no search\)"),
        ({"initializer": {"reseed_search_quantile": 1.0}}, r"initializer\.reseed_search_quantile: must be in \[0, 1\)"),
        ({"world": {"noise_level_db": float("nan")}}, r"world\.noise_level_db: must be finite, got nan"),
        ({"reward": {"success_bonus": float("inf")}}, r"reward\.success_bonus: must be finite"),
        ({"receiver": {"start_position": [15.0, float("nan"), -7.0]}}, r"receiver\.start_position: must be finite"),
        (
            {"filter": {"multipath": "exact"}},
            r"filter\.multipath: 'exact' is not one of \['matched', 'none', 'linear', 'phasor'\]",
        ),
    ],
)
def test_bad_values_are_named(data, match):
    with pytest.raises(ConfigError, match=match):
        from_dict(data)


def test_exponent_floats_read_as_numbers(tmp_path):
    """YAML 1.2's floats without a dot or an exponent sign (``1e-7``), which PyYAML alone reads as strings, load
    as numbers; quoted, they stay strings and are refused by name; YAML 1.1's forms and other scalars keep their
    types."""
    from aasl_gym.io import read_yaml

    path = tmp_path / "exponent.yaml"
    path.write_text("filter:\n  acceleration_psd: 1e-7\n  jerk_psd: 2.5E+3\n  turn_rate_psd: .5e-2\n")
    config = load_config(path)
    assert (config.filter.acceleration_psd, config.filter.jerk_psd, config.filter.turn_rate_psd) == (1e-7, 2500.0, 5e-3)
    path.write_text("filter:\n  acceleration_psd: '1e-7'\n")
    with pytest.raises(ConfigError, match=r"filter\.acceleration_psd: must be a number, got '1e-7'"):
        load_config(path)
    values = read_yaml("[1e5, -3e-4, 1.0e-05, 7, 0x1F, 1e, e5, 1e-7x, 2026-11-28, .inf, yes]")
    assert values[:5] == [1e5, -3e-4, 1e-5, 7, 31] and isinstance(values[0], float)
    assert values[5:8] == ["1e", "e5", "1e-7x"] and str(values[8]) == "2026-11-28"
    assert values[9] == float("inf") and values[10] is True


def test_bad_yaml_file_names_the_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("world: {water_depth: [unclosed\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml: not valid YAML"):
        load_config(bad)
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text("filter:\n  multipath: echo\n")
    with pytest.raises(ConfigError, match=r"wrong.yaml: filter\.multipath: 'echo' is not one of"):
        load_config(wrong)
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "missing.yaml")
    with pytest.raises(ConfigError, match="is a folder"):
        load_config(tmp_path)
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(bytes(range(128, 256)))
    with pytest.raises(ConfigError, match=r"binary\.yaml: not valid YAML \('utf-8' codec"):
        load_config(binary)
    twice = tmp_path / "twice.yaml"
    twice.write_text("world:\n  water_depth: 40.0\nsource:\n  frequency: 900.0\nworld:\n  reflections: false\n")
    with pytest.raises(ConfigError, match=r"(?s)twice\.yaml: not valid YAML .*found key 'world' twice"):
        load_config(twice)  # PyYAML alone keeps the second and drops the water depth without a word


def test_a_hardware_path_that_cannot_sample_the_tone_is_refused():
    """Real samples at 200 kHz hold tones below 100 kHz: a 150 kHz tone would fold over and never be heard."""
    hardware = {"measurement": {"mode": "signal"}, "signal": {"path": "hardware"}}
    with pytest.raises(ConfigError, match=r"signal\.sample_rate: samples up to 100000 Hz .* 135000-165000 Hz"):
        from_dict({**hardware, "source": {"frequency": 150_000.0}})
    assert from_dict({**hardware, "source": {"frequency": 80_000.0}}).source.frequency == 80_000.0
    assert from_dict({"source": {"frequency": 150_000.0}}).signal.path == "fast"  # the envelope is taken at the tone


def test_numpy_scalars_are_numbers_and_bools_are_not():
    config = from_dict({"signal": {"windows": np.int64(12)}, "episode": {"duration": np.float32(30.0)}})
    assert config.signal.windows == 12 and type(config.signal.windows) is int
    assert config.episode.duration == 30.0 and type(config.episode.duration) is float
    with pytest.raises(ConfigError, match=r"signal\.windows: must be an integer, got True"):
        from_dict({"signal": {"windows": True}})


def test_gym_make_refuses_a_facility_it_would_not_fly():
    """An id that flies one pod refuses a config with several, and the facility's id one with a single pod, by name
    (as the CLIs do), where they would have run and dropped the other pods without a word."""
    with pytest.raises(ConfigError, match=r"config: AASL-Helix-v0 flies one pod .* facility of 8 pods"):
        gym.make("AASL-Helix-v0", scenario="facility")
    with pytest.raises(ConfigError, match="config: AASL-Facility-v0 needs a facility"):
        gym.make("AASL-Facility-v0", scenario=None)
    with pytest.raises(ConfigError, match="patrol: AASL-Facility-v0 flies its own patrol"):
        gym.make("AASL-Facility-v0", patrol="helix")


OVERRIDES = [
    ("source_motion", "ctrv", lambda c: c.source.motion),
    ("measurement", "geometric", lambda c: c.measurement.mode),
    ("initializer", "tdoa-ls", lambda c: c.initializer.name),
    ("reflections", False, lambda c: c.world.reflections),
    ("multipath", "linear", lambda c: c.filter.multipath),
    ("filter_model", "ca", lambda c: c.filter.motion_model),
]


@pytest.mark.parametrize("keyword,value,read", OVERRIDES, ids=[o[0] for o in OVERRIDES])
def test_gym_make_overrides_take_effect(keyword, value, read, tmp_path):
    env = gym.make("AASL-v0", **{keyword: value})
    assert read(env.unwrapped.config) == value
    # ... also on top of a config file, where the keyword wins
    path = tmp_path / "c.yaml"
    path.write_text("initializer:\n  name: naive\nworld:\n  water_depth: 40.0\n")
    env = gym.make("AASL-Helix-v0", config=str(path), **{keyword: value})
    assert read(env.unwrapped.config) == value
    assert env.unwrapped.config.world.water_depth == 40.0


def test_config_file_keyword_takes_effect(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("world:\n  water_depth: 20.0\n")
    assert gym.make("AASL-v0", config=str(path)).unwrapped.config.world.water_depth == 20.0


def test_bad_override_names_the_keyword():
    with pytest.raises(ConfigError, match=r"source_motion='spiral': source\.motion: 'spiral' is not one of"):
        gym.make("AASL-v0", source_motion="spiral")
    with pytest.raises(ConfigError, match=r"reflections='no'"):
        gym.make("AASL-v0", reflections="no")


def test_bad_signal_settings_are_named():
    with pytest.raises(ConfigError, match=r"signal\.path: 'slow' is not one of \['fast', 'hardware'\]"):
        gym.make("AASL-v0", measurement="signal", config={"signal": {"path": "slow"}})
    with pytest.raises(ConfigError, match=r"signal\.frame_duration: must not exceed one step"):
        gym.make("AASL-v0", config={"signal": {"frame_duration": 0.5}})


@pytest.mark.parametrize("limit,expected", [("matched", 1.2), (2.5, 2.5), (None, None)])
def test_the_ca_filter_stops_at_the_world_sources_top_speed_unless_told_otherwise(limit, expected):
    """``filter.speed_limit: matched`` (the default) is the world's ``source.max_speed``, where its CA sources
    stop accelerating; a speed is kept, null means none. Only the CA model uses it."""
    config = {"source": {"max_speed": 1.2, "speed_range": [0.2, 1.0]}, "filter": {"speed_limit": limit}}
    env = gym.make("AASL-Helix-v0", measurement="geometric", source_motion="ca", filter_model="ca", config=config)
    assert env.unwrapped.config.filter_speed_limit == expected
    assert env.unwrapped.tracker.model.speed_limit == expected


@pytest.mark.parametrize("reflections,expected", [(True, "phasor"), (False, "none")])
def test_the_filter_matches_the_world_unless_told_otherwise(reflections, expected):
    """``filter.multipath: matched`` (the default) is the exact model where the world has reflections and
    the direct path where it has none; an explicit model is kept (for ablations)."""
    env = gym.make("AASL-Helix-v0", measurement="geometric", reflections=reflections)
    assert env.unwrapped.config.filter_multipath == expected
    assert env.unwrapped.tracker.ripple == (expected == "phasor")
    explicit = gym.make("AASL-Helix-v0", reflections=reflections, multipath="linear")
    assert explicit.unwrapped.config.filter_multipath == "linear"
