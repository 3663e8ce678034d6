"""evaluate.py end to end on a tiny job: files, results.json schema, and clear errors for bad input."""

import json

import pytest

import evaluate


def test_tiny_evaluation_writes_report_results_and_plots(tmp_path):
    out = tmp_path / "eval"
    code = evaluate.main(["--policies", "helix", "circle", "--initializers", "lcmap", "naive", "--motions", "static",
                          "--episodes", "1", "--reflections", "off", "--multipath", "none", "--out", str(out)])
    assert code == 0
    for name in ("report.md", "results.json", "convergence_time.png", "success_vs_threshold.png", "trajectories_static.png"):
        assert (out / name).stat().st_size > 0
    results = json.loads((out / "results.json").read_text())
    assert set(results) >= {"command", "config", "episodes", "summary"}
    assert len(results["episodes"]) == 4
    assert "trajectory" not in results["episodes"][0]  # the paths go into the plots, not the results
    row = results["episodes"][0]
    assert {"policy", "initializer", "motion", "measurement", "seed", "convergence_time", "success", "rmse", "final_error"} <= set(row)
    assert set(row["success"]) == {"0.1", "0.2", "0.5", "1.0", "2.0", "3.0"}
    summary = results["summary"][0]
    assert {"policy", "initializer", "motion", "measurement", "n", "success_rate", "mean_convergence_time",
            "convergence_time_ci95", "rmse_median"} <= set(summary)
    # paired on seeds: every policy x initializer saw the same seed
    assert {r["seed"] for r in results["episodes"]} == {1000}
    assert results["config"]["world"]["reflections"] is False


def test_bad_flags_are_named(capsys, tmp_path):
    with pytest.raises(SystemExit):
        evaluate.main(["--policies", "zigzag"])
    assert "zigzag" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        evaluate.main(["--episodes", "0"])
    assert "--episodes" in capsys.readouterr().err
    assert evaluate.main(["--config", str(tmp_path / "missing.yaml"), "--out", str(tmp_path)]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert evaluate.main(["--policies", "ppo:" + str(tmp_path / "none.zip"), "--out", str(tmp_path)]) == 2
    assert "no file" in capsys.readouterr().err
    corrupt = tmp_path / "bad.zip"
    corrupt.write_text("not a model")
    assert evaluate.main(["--policies", f"ppo:{corrupt}", "--out", str(tmp_path)]) == 2
    assert "not a Stable-Baselines3 model" in capsys.readouterr().err
