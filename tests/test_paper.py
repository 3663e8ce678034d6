"""The reference paper's studies (``paper.py``): their variants, the paper's divergence rule, the model
error against closed-form cases, and tiny grids whose tables have their columns and whose rows are the
same with one worker and with two."""

import json

import numpy as np
import pytest

import paper
from aasl_gym.scenarios import scenario_config
from aasl_gym.study.paper import (
    DIVERGENCE_RMSE,
    LAKE_MOTIONS,
    LAKE_PATROLS,
    coefficient_variants,
    lake_variants,
    make_study,
    model_error,
    multipath_variants,
    navigation_variants,
    summarize_variants,
    wrapped,
)

SHORT = "episode:\n  duration: 6.0\n"  # 30 steps: the filter starts after the 2 s burst


def test_the_variants_span_what_the_paper_varies():
    cells = {(v.labels["world"], v.labels["filter"]) for v in multipath_variants()}
    assert cells == {(w, f) for w in ("linear", "phasor") for f in ("none", "linear", "phasor")}
    grid = coefficient_variants(6)
    assert {v.labels["surface_reflection"] for v in grid} == {-1.0, -0.8, -0.6, -0.4, -0.2, 0.0}
    assert {v.labels["bed_reflection"] for v in grid} == {0.0, 0.2, 0.4, 0.6, 0.8, 1.0}
    assert len(grid) == 6 * 6 * 2 * 2  # x both filters x both worlds
    levels = navigation_variants(drift=0.02)
    config = make_study("navigation").config(levels[-1])
    assert config.receiver.nav_position_sd == 0.7 and config.receiver.velocity_sd == pytest.approx(0.28)
    assert config.receiver.nav_drift_sd == 0.02 and config.filter.compensate_navigation
    assert len({v.name for v in levels}) == len(levels) == 2 * 8 * 2


def test_a_trial_diverges_as_the_paper_says():
    study = make_study("multipath", trials=1)
    name = study.variants[0].name
    row = {"variant": name, "final_error": 1.0, "max_error": 40.0, "rmse_second_half": 2.0, "success": {"1.0": False}}
    rows = [row | {"rmse": DIVERGENCE_RMSE - 0.1}, row | {"rmse": DIVERGENCE_RMSE + 0.1}, row | {"rmse": None}]
    entry = summarize_variants(study, rows)[0]
    assert entry["n"] == 3 and entry["converged_rate"] == pytest.approx(1 / 3)
    assert entry["rmse_mean"] == pytest.approx(DIVERGENCE_RMSE - 0.1) and entry["rmse_sd"] == 0.0
    assert entry["rmse_all_mean"] == pytest.approx(DIVERGENCE_RMSE)  # the two with an estimate
    assert entry["rmse_median"] == pytest.approx(DIVERGENCE_RMSE + 0.1)  # None counts as infinite


def test_the_model_error_vanishes_without_reflections_and_is_folded_into_a_wavelength():
    rng = np.random.default_rng(3)
    states = [
        rng.uniform(-15, -2, (50, 3)),
        rng.normal(0, 1, (50, 3)),
        rng.uniform(-15, -2, (50, 3)),
        rng.normal(0, 1, (50, 3)),
    ]
    still = scenario_config("shallow-water", {"world": {"surface_reflection": 0.0, "bed_reflection": 0.0}})
    for model in ("linear", "none"):
        assert np.allclose(model_error(still, *states, model=model), 0.0, atol=1e-9)
    config = scenario_config("shallow-water")
    error = model_error(config, *states)
    assert np.std(error[:, 0]) > 0.1  # reflections of -0.9 / 0.3 do move it
    expected = _first_order_rd(config, states[0], states[2]) - _tone_rd(config, states[0], states[2])
    assert np.allclose(wrapped(error[:, 0] - expected, config.wavelength), 0.0, atol=1e-9)


def _paths(config, source):
    """The direct path and the surface and bed images of ``source`` (N, 3), with their gains (SPEC section 2)."""
    depth, world = config.world.water_depth, config.world
    mirror = source * [1, 1, -1]
    return [(source, 1.0), (mirror, world.surface_reflection), (mirror - [0, 0, 2 * depth], world.bed_reflection)]


def _first_order_rd(config, source, mobile):
    fixed = np.array(config.world.fixed_position)

    def rd(point):
        return np.linalg.norm(point - mobile, axis=-1) - np.linalg.norm(point - fixed, axis=-1)

    return sum(gain * rd(point) for point, gain in _paths(config, source))


def _tone_rd(config, source, mobile):
    """The phase difference of the two receivers' phasor sums a_k / r_k exp(-j k r_k), in metres (modulo a
    wavelength): RD is the extra path to the mobile hydrophone, so its phase lags by k RD."""
    wavenumber = 2 * np.pi / config.wavelength
    fixed = np.array(config.world.fixed_position)

    def phase(receiver):
        total = 0
        for point, gain in _paths(config, source):
            distance = np.linalg.norm(point - receiver, axis=-1)
            total = total + gain / distance * np.exp(-1j * wavenumber * distance)
        return np.angle(total)

    return (phase(fixed) - phase(mobile)) / wavenumber
    assert wrapped(np.array([0.76, -0.76, 2.0]), 1.5) == pytest.approx([-0.74, 0.74, 0.5])


@pytest.mark.slow
def test_a_tiny_multipath_study_has_its_table_and_the_same_rows_on_two_workers(tmp_path, capsys):
    short = tmp_path / "short.yaml"
    short.write_text(SHORT)
    common = ["multipath", "--trials", "2", "--config", str(short), "--no-plots"]
    assert paper.main([*common, "--workers", "1", "--out", str(tmp_path / "one")]) == 0
    assert paper.main([*common, "--workers", "2", "--out", str(tmp_path / "two")]) == 0
    one, two = (json.loads((tmp_path / d / "results.json").read_text()) for d in ("one", "two"))
    assert one["trials"] == two["trials"] and len(one["trials"]) == 12
    assert {"rmse", "final_error", "max_error", "rmse_second_half", "variant", "seed"} <= set(one["trials"][0])
    columns = {"variant", "world", "filter", "n", "converged_rate", "rmse_mean", "rmse_sd", "final_error_mean"}
    assert columns | {"max_error_mean", "rmse_second_half_mean", "success_rate_1m"} <= set(one["summary"][0])
    report = (tmp_path / "one" / "report.md").read_text()
    header = "| world | filter | n | converged | RMSE (m) | final error (m) | maximum error (m) | RMSE, 2nd half (m) |"
    assert header in report
    assert "| paper's world | multipath-aware | 100 % | 0.98 ± 2.15 | 0.15 ± 0.97 | 9.27 ± 22.40 |" in report
    capsys.readouterr()
    three = [*common[:2], "3", *common[3:], "--workers", "1"]
    assert paper.main([*three, "--out", str(tmp_path / "one"), "--resume"]) == 0
    assert "18 trials (12 from" in capsys.readouterr().out
    assert paper.main([*three, "--out", str(tmp_path / "fresh")]) == 0
    resumed, fresh = (json.loads((tmp_path / d / "results.json").read_text()) for d in ("one", "fresh"))
    assert resumed["trials"] == fresh["trials"] and resumed["summary"] == fresh["summary"]


@pytest.mark.slow
def test_the_sweeps_write_their_grids_and_plots(tmp_path):
    short = tmp_path / "short.yaml"
    short.write_text(SHORT)
    out = tmp_path / "coefficients"
    assert (
        paper.main(
            [
                "coefficients",
                "--grid",
                "2",
                "--trials",
                "1",
                "--config",
                str(short),
                "--workers",
                "1",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    report = (out / "report.md").read_text()
    assert "| a_surf \\ a_bed | 0.00 | 1.00 |" in report and "| -1.00 | " in report and "| +0.00 | " in report
    assert (out / "coefficients.png").stat().st_size > 10_000
    out = tmp_path / "navigation"
    assert paper.main(["navigation", "--trials", "1", "--config", str(short), "--workers", "1", "--out", str(out)]) == 0
    summary = json.loads((out / "results.json").read_text())["summary"]
    assert [(s["sigma_rov"], s["compensation"]) for s in summary][:3] == [
        (0.0, "R_ac only"),
        (0.0, "R_eff"),
        (0.1, "R_ac only"),
    ]
    assert (out / "navigation.png").stat().st_size > 10_000


def test_model_error_writes_its_map_and_quantiles(tmp_path):
    assert paper.main(["model-error", "--samples", "200", "--out", str(tmp_path)]) == 0
    stats = json.loads((tmp_path / "results.json").read_text())["statistics"]
    assert set(stats) == {"linear", "none"}
    assert 0 <= stats["linear"]["abs_rd_error_p50"] <= stats["linear"]["abs_rd_error_p99"] <= 0.75
    assert (tmp_path / "model_error.png").stat().st_size > 10_000


def test_bad_flags_are_named(tmp_path, capsys):
    with pytest.raises(SystemExit):
        paper.main(["coefficients", "--grid", "1"])
    assert "--grid must be >= 2" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        paper.main(["multipath", "--seed", "-1"])
    assert "--seed must be >= 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        paper.main(["ablation"])
    assert "ablation" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("world:\n  depth: 20\n")
    assert paper.main(["multipath", "--config", str(bad), "--out", str(tmp_path)]) == 2
    assert "world.depth: unknown key" in capsys.readouterr().err


def test_a_tiny_lake_study_runs_every_patrol_and_path_with_both_filters(tmp_path):
    short = tmp_path / "short.yaml"
    short.write_text(SHORT)
    assert paper.main(["lake", "--trials", "1", "--config", str(short), "--out", str(tmp_path)]) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    cells = {(e["patrol"], e["motion"], e["filter"]) for e in results["summary"]}
    assert cells == {(p, m, f) for p in LAKE_PATROLS for m in LAKE_MOTIONS for f in ("nominal", "compensated")}
    assert {row["policy"] for row in results["trials"]} == set(LAKE_PATROLS)
    assert not any("trajectory" in row for row in results["trials"])  # they went into the plots
    assert {f"trajectories_{motion}.png" for motion in LAKE_MOTIONS} <= {p.name for p in tmp_path.iterdir()}
    report = (tmp_path / "report.md").read_text()
    assert "| filter | trials | with an estimate | RMSE (m): mean ± sd | median RMSE (m) | success 1 m " in report
    assert "| nominal | 12 | " in report and report.count("| 1.37 |") == 1
    config = make_study("lake").config(lake_variants()[0])
    assert config.filter.multipath == "none" and not config.filter.compensate_navigation


def test_a_tiny_facility_study_pairs_each_trial_with_a_pod(tmp_path):
    short = tmp_path / "short.yaml"
    short.write_text("episode:\n  duration: 8.0\nfacility:\n  onset_range: [1.0, 3.0]\n")
    assert paper.main(["facility", "--trials", "1", "--config", str(short), "--no-plots", "--out", str(tmp_path)]) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    cells = [(row["motion"], row["variant"]) for row in results["trials"]]
    assert cells == [(m, v) for m in ("static", "cv", "ctrv") for v in ("loudest pod", "every pod that hears")]
    for row in results["trials"]:
        assert 1.0 <= row["detection_time"] <= 3.2 and 0 <= row["pod"] < 8 and 0 <= row["source_pod"] < 8
    for loudest, every in zip(results["trials"][::2], results["trials"][1::2]):  # one source, one detection
        assert (loudest["detection_time"], loudest["pod"]) == (every["detection_time"], every["pod"])
    report = (tmp_path / "report.md").read_text()
    assert "| source | pairs | trials | heard | paired with the attacked pod | detection (s): median |" in report
