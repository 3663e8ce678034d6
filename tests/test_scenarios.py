"""Named scenarios: what each sets (against the reference paper's numbers), how keywords and configs
override them, the world's first-order reflection model, and a source centred on a submerged pod."""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import evaluate
import train
from aasl_gym.config import ConfigError, EnvConfig, from_dict, load_config
from aasl_gym.env import resolve_config
from aasl_gym.fisher import information_prior
from aasl_gym.initializers import Burst, make_initializer
from aasl_gym.measurement_models import direct_measurement
from aasl_gym.motion import sample_source, source_region
from aasl_gym.scenarios import scenario_config, scenario_description, scenario_names
from aasl_gym.sensors import GeometricSensor

ROOT = Path(__file__).resolve().parents[1]


def test_the_papers_scenarios_are_there_and_say_what_they_reproduce():
    assert {"default", "paper-monte-carlo", "shallow-water", "submerged-pod"} <= set(scenario_names())
    for name in scenario_names():
        assert len(scenario_description(name)) > 40, name
        assert isinstance(scenario_config(name), EnvConfig)


def test_the_default_and_monte_carlo_scenarios_are_the_files_the_studies_name():
    assert scenario_config("default") == EnvConfig() == load_config(ROOT / "configs" / "default.yaml")
    # The study gives the filter the sensor's own RD offset, whole periods (its file says why); nothing else differs.
    study = load_config(ROOT / "configs" / "initializer_study.yaml")
    assert study.filter.range_bias_psd == 0 and study.initializer.range_bias_sd < 0.002  # 0: see _sheet_of
    scenario = scenario_config("paper-monte-carlo")
    assert scenario == study.replace(
        filter={"range_bias_psd": scenario.filter.range_bias_psd},
        initializer={"range_bias_sd": scenario.initializer.range_bias_sd},
    )


def test_shallow_water_is_the_papers_multipath_world():
    config = gym.make("AASL-Helix-v0", scenario="shallow-water").unwrapped.config
    world = config.world
    assert (world.water_depth, world.surface_reflection, world.bed_reflection) == (20.0, -0.9, 0.3)
    assert world.reflections and world.reflection_model == "linear"
    assert config.measurement.mode == "geometric"
    assert config.filter_multipath == "linear"  # matched: the world's own model


def test_keywords_and_configs_override_a_scenarios_fields(tmp_path):
    env = gym.make("AASL-Helix-v0", scenario="shallow-water", reflections=False, source_motion="ctrv")
    config = env.unwrapped.config
    assert config.world.water_depth == 20.0 and not config.world.reflections
    assert config.filter_multipath == "none" and config.source.motion == "ctrv"
    exact = resolve_config({"world": {"reflection_model": "phasor"}}, "shallow-water")
    assert exact.world.reflection_model == "phasor" and exact.world.water_depth == 20.0
    changes = tmp_path / "changes.yaml"
    changes.write_text("world:\n  bed_reflection: 0.5\n")
    assert resolve_config(str(changes), "shallow-water").world.bed_reflection == 0.5
    assert resolve_config(str(changes), "shallow-water").world.water_depth == 20.0
    # a file valid only over the scenario (a linear world needs its geometric mode) is checked over it
    changes.write_text("world:\n  reflection_model: linear\n  bed_reflection: 0.5\n")
    assert resolve_config(str(changes), "shallow-water").world.bed_reflection == 0.5
    # the keyword wins over the file, which wins over the scenario, on the same field
    changes.write_text("world:\n  reflections: true\n")
    assert not resolve_config(str(changes), "shallow-water", reflections=False).world.reflections
    changes.write_text("world:\n  reflections: false\n")
    assert not resolve_config(str(changes), "shallow-water").world.reflections
    assert (
        resolve_config(str(changes), "shallow-water", measurement="geometric", multipath="phasor").filter_multipath
        == "phasor"
    )


def test_bad_scenarios_are_named():
    with pytest.raises(ConfigError, match="scenario: 'deep-space' is not one of"):
        gym.make("AASL-v0", scenario="deep-space")
    with pytest.raises(ConfigError, match="scenario='shallow-water' with config=EnvConfig"):
        resolve_config(EnvConfig(), "shallow-water")
    with pytest.raises(ConfigError, match=r"world\.reflection_model: 'linear' generates geometric measurements only"):
        gym.make("AASL-v0", scenario="shallow-water", measurement="signal")
    with pytest.raises(ConfigError, match=r"world\.reflection_model: 'first-order' is not one of"):
        from_dict({"world": {"reflection_model": "first-order"}})


def test_the_clis_take_a_scenario_and_a_config_over_it(tmp_path, capsys):
    changes = tmp_path / "changes.yaml"
    changes.write_text("world:\n  water_depth: 25.0\n")
    args = evaluate.parse_args(["--scenario", "shallow-water", "--config", str(changes), "--episodes", "1"])
    config, _ = evaluate.prepare(args)
    assert (config.world.water_depth, config.world.reflection_model) == (25.0, "linear")
    config, _ = evaluate.prepare(evaluate.parse_args(["--scenario", "submerged-pod", "--episodes", "1"]))
    assert config.world.fixed_position == (0.0, 0.0, -59.06)
    with pytest.raises(SystemExit):
        evaluate.parse_args(["--scenario", "deep-space"])
    assert "deep-space" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        train.parse_args(["--scenario", "deep-space"])
    assert "deep-space" in capsys.readouterr().err
    changes.write_text("world:\n  water_depth: 5.0\n")  # the shallow-water patrol no longer fits
    assert train.main(["--scenario", "shallow-water", "--config", str(changes), "--out", str(tmp_path)]) == 2
    assert "--config" in capsys.readouterr().err


def _first_order_rd(source, receiver, fixed, depth, surface, bed):
    """RD + a_surf delta_surf + a_bed delta_bed, from the image sources' distances (SPEC section 2)."""

    def rd(point):
        return np.linalg.norm(point - receiver) - np.linalg.norm(point - fixed)

    surface_image = source * [1, 1, -1]
    bed_image = source * [1, 1, -1] - [0, 0, 2 * depth]
    return rd(source) + surface * rd(surface_image) + bed * rd(bed_image)


def test_the_linear_world_measures_the_papers_first_order_rd_and_its_rate():
    config = scenario_config("shallow-water", {"measurement": {"range_difference_sd": 1e-9}})
    config = config.replace(measurement={"range_rate_difference_sd": 1e-9})
    world = config.world
    sensor = GeometricSensor(config, period=None)  # no whole-period ambiguity: compare RD itself
    rng = np.random.default_rng(0)
    source, velocity = np.array([6.0, -3.0, -14.0]), np.array([0.4, 0.2, -0.05])
    receiver, receiver_velocity = np.array([12.0, 4.0, -5.0]), np.array([-0.3, 0.9, 0.1])
    fixed = np.array(world.fixed_position)
    z = sensor.measure(rng, 0.0, source, velocity, receiver, receiver_velocity, fixed)
    args = (world.water_depth, world.surface_reflection, world.bed_reflection)
    expected = _first_order_rd(source, receiver, fixed, *args)
    assert z[0] == pytest.approx(expected, abs=1e-6)
    assert abs(expected - (np.linalg.norm(source - receiver) - np.linalg.norm(source - fixed))) > 0.05  # not direct
    step = 1e-4  # the rate: the RD's time derivative along both motions, by central differences
    ahead = _first_order_rd(source + step * velocity, receiver + step * receiver_velocity, fixed, *args)
    behind = _first_order_rd(source - step * velocity, receiver - step * receiver_velocity, fixed, *args)
    assert z[1] == pytest.approx((ahead - behind) / (2 * step), abs=1e-6)


def test_a_source_centred_on_the_submerged_pod_starts_near_it():
    config = scenario_config("submerged-pod")
    centre = np.array(config.source.initial_centre)
    depths = []
    for seed in range(200):
        state = sample_source(np.random.default_rng(seed), "static", config.source, config.world)
        assert np.linalg.norm(state.position - centre) <= config.source.initial_radius
        assert -config.world.water_depth + config.source.boundary_margin <= state.position[2] <= -2.0
        depths.append(state.position[2])
    # Uniform in the part of the ball above the bed's margin: a cap of height h = 20 - 1.06 m whose
    # centroid lies 3 (2r - h)^2 / (4 (3r - h)) above the ball's centre.
    height = 20.0 - (-58.0 - centre[2])
    centroid = centre[2] + 3 * (2 * 20.0 - height) ** 2 / (4 * (3 * 20.0 - height))
    assert np.mean(depths) == pytest.approx(centroid, abs=0.6)
    mean, _ = information_prior(config)
    assert np.linalg.norm(mean[0:3] - centre) <= config.source.initial_radius
    with pytest.raises(ConfigError, match=r"source\.initial_centre"):
        from_dict({"source": {"initial_centre": [0.0, 0.0, -80.0]}})
    with pytest.raises(ConfigError, match=r"source\.initial_centre: its ball"):
        from_dict({"source": {"initial_centre": [0.0, 0.0, -59.0], "initial_radius": 0.5}})
    with pytest.raises(ConfigError, match=r"source\.initial_centre: its ball"):  # beyond the region's edge
        from_dict({"source": {"initial_centre": [40.0, 0.0, -10.0], "initial_radius": 1.0}})


def test_tdoa_ls_starts_on_the_water_side_of_a_pod_on_the_bed():
    config = scenario_config("submerged-pod")
    region = source_region(config.world, config.source)
    fixed = np.array(config.world.fixed_position)
    mobile = np.array([[12.0, 3.0, -52.0]])
    source = np.array([5.0, -4.0, -50.0])
    rd = np.linalg.norm(source - mobile[0]) - np.linalg.norm(source - fixed)
    burst = Burst(
        np.zeros(1), np.array([[rd, 0.0]]), mobile, np.zeros((1, 3)), fixed, np.eye(2), None, direct_measurement
    )
    start = make_initializer("tdoa-ls", config.initializer, region)(burst, np.random.default_rng(0)).states[0]
    assert region.z_min <= start[2] <= region.z_max  # a start below the bed ends below it
    assert np.linalg.norm(start[0:3] - mobile[0]) - np.linalg.norm(start[0:3] - fixed) == pytest.approx(rd, abs=1e-6)


def test_the_lake_holds_its_source_at_depth_within_15_m_of_the_dock():
    env = gym.make("AASL-Square-v0", scenario="lake", source_motion="uturn").unwrapped
    config = env.config
    assert config.world.fixed_position == (0.0, 0.0, -0.91) and config.receiver.surface_depth == 1.19
    assert (config.world.surface_reflection, config.world.bed_reflection) == (-0.98, 0.2)
    for seed in range(3):
        env.reset(seed=seed)
        assert env.source.position[2] == -0.6 and env.receiver_position[2] == -1.19
        for _ in range(env.max_steps):
            env._move(np.zeros(3))  # the truth motions alone: no need to run the tracker here
            assert np.hypot(*env.source.position[:2]) <= 15.0 + 1e-3  # held to it at 0.5 s samples
            assert env.source.position[2] == -0.6
            assert env.receiver_position[2] == -1.19  # a surface vessel, kept out of the dock's 1 m sphere
            assert np.linalg.norm(env.receiver_position - env.fixed) >= 1.0 - 1e-9
            assert np.hypot(*env.receiver_position[:2]) <= 6.0 + 1e-9


def test_held_and_kept_sources_are_checked():
    with pytest.raises(ConfigError, match=r"source\.depth: 2\.9 m must lie source\.boundary_margin = 0\.3 m"):
        gym.make("AASL-v0", scenario="lake", config={"source": {"depth": 2.9}})
    with pytest.raises(ConfigError, match=r"source\.keep_within: must exceed source\.initial_radius = 12\.0 m"):
        gym.make("AASL-v0", scenario="lake", config={"source": {"keep_within": 10.0}})
    env = gym.make(
        "AASL-v0", scenario="lake", source_motion="cv", config={"source": {"speed_range": [5.0, 6.0], "max_speed": 6.0}}
    )
    with pytest.raises(ValueError, match=r"no cv path drawn in 1000 tries kept within source\.keep_within = 15\.0 m"):
        env.reset(seed=0)
