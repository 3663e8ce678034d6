"""evaluate.py end to end on a tiny job: files, results.json schema, and clear errors for bad input."""

import json
import sys

import numpy as np
import pytest

import evaluate
from agents import study


def test_tiny_evaluation_writes_report_results_and_plots(tmp_path):
    out = tmp_path / "eval"
    code = evaluate.main(
        [
            "--policies",
            "helix",
            "circle",
            "--initializers",
            "lcmap",
            "naive",
            "--motions",
            "static",
            "--episodes",
            "1",
            "--reflections",
            "off",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    for name in (
        "report.md",
        "results.json",
        "convergence_time.png",
        "success_vs_threshold.png",
        "trajectories_static.png",
    ):
        assert (out / name).stat().st_size > 0
    opening = (out / "report.md").read_text().splitlines()[2]
    assert opening.startswith("In short: Static sources:") and "of 1 episode " in opening and "+-98 points" in opening
    assert "filter motion model `cv` for every source motion;" in (out / "report.md").read_text()  # static's own
    assert "## The facility" not in (out / "report.md").read_text()  # one pod: no detection or hand-over
    results = json.loads((out / "results.json").read_text())
    assert set(results) >= {"command", "config", "episodes", "summary"}
    # Where it ran: a seed's episode is the same to the last bit only on one machine and build.
    assert results["platform"]["numpy"] == np.__version__ and results["platform"]["processor"]
    assert isinstance(results["platform"]["blas"], str)  # the BLAS kernels (threadpoolctl; empty if none is found)
    assert len(results["episodes"]) == 4
    assert "trajectory" not in results["episodes"][0]  # the paths go into the plots, not the results
    row = results["episodes"][0]
    assert {
        "policy",
        "initializer",
        "motion",
        "measurement",
        "seed",
        "convergence_time",
        "success",
        "rmse",
        "final_error",
    } <= set(row)
    assert set(row["success"]) == {"0.1", "0.2", "0.5", "1.0", "2.0", "3.0"}
    summary = results["summary"][0]
    assert {
        "policy",
        "initializer",
        "motion",
        "measurement",
        "n",
        "success_rate",
        "mean_convergence_time",
        "convergence_time_ci95",
        "rmse_median",
    } <= set(summary)
    # paired on seeds: every policy x initializer saw the same seed
    assert {r["seed"] for r in results["episodes"]} == {1000}
    assert results["config"]["world"]["reflections"] is False


def test_the_report_says_which_sources_the_filter_does_not_match():
    """A CV filter on CA and CTRV sources fails where the matched one finds them: the report must say which it ran."""
    from aasl_gym.study.report import _filter_models

    one = _filter_models({"static": "cv", "cv": "cv", "ca": "cv", "ctrv": "cv"})
    assert one.startswith("filter motion model `cv` for every source motion") and "the ca, ctrv sources" in one
    assert "not matched" not in _filter_models({"static": "cv", "cv": "cv"})
    matched = _filter_models({"static": "cv", "ctrv": "ctrv"})
    assert matched == "filter motion model per source motion: static `cv`, ctrv `ctrv`"


def test_rows_are_the_same_with_one_worker_and_with_two(tmp_path):
    """Every episode runs from its own seed, so the process pool changes no row."""
    flags = [
        "--policies",
        "helix",
        "--motions",
        "static",
        "cv",
        "--episodes",
        "1",
        "--no-plots",
        "--measurement",
        "geometric",
        "--reflections",
        "off",
        "--config",
        str(tmp_path / "short.yaml"),
    ]
    (tmp_path / "short.yaml").write_text("episode:\n  duration: 20.0\n")
    for workers in ("1", "2"):
        assert evaluate.main(flags + ["--workers", workers, "--out", str(tmp_path / workers)]) == 0
    one, two = (json.loads((tmp_path / w / "results.json").read_text())["episodes"] for w in ("1", "2"))
    assert one == two


def test_ray_writes_the_rows_of_the_process_pool_and_resumes_its_log(tmp_path):
    """``--backend ray`` on a local 2-CPU Ray: the same rows as the process pool, and a run cut after
    two episodes resumes from its log on Ray to the same results."""
    pytest.importorskip("ray")
    (tmp_path / "short.yaml").write_text("episode:\n  duration: 20.0\n")
    flags = [
        "--policies",
        "helix",
        "--motions",
        "static",
        "cv",
        "--episodes",
        "2",
        "--no-plots",
        "--measurement",
        "geometric",
        "--reflections",
        "off",
        "--config",
        str(tmp_path / "short.yaml"),
        "--workers",
        "2",
    ]
    assert evaluate.main(flags + ["--out", str(tmp_path / "pool")]) == 0
    lines = (tmp_path / "pool" / "episodes.jsonl").read_text().splitlines()
    (tmp_path / "ray").mkdir()
    (tmp_path / "ray" / "episodes.jsonl").write_text("\n".join(lines[:3]) + "\n")
    assert evaluate.main(flags + ["--backend", "ray", "--resume", "--out", str(tmp_path / "ray")]) == 0
    pool, ray = (json.loads((tmp_path / name / "results.json").read_text())["episodes"] for name in ("pool", "ray"))
    assert pool == ray
    assert evaluate.main(flags + ["--backend", "ray", "--out", str(tmp_path / "ray-whole")]) == 0
    assert json.loads((tmp_path / "ray-whole" / "results.json").read_text())["episodes"] == pool


def test_bad_flags_are_named(capsys, tmp_path):
    with pytest.raises(SystemExit):
        evaluate.main(["--policies", "zigzag"])
    assert "zigzag" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        evaluate.main(["--episodes", "0"])
    assert "--episodes" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        evaluate.main(["--seed", "-5"])
    assert "--seed must be >= 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        evaluate.main(["--ray-address", "auto"])
    assert "--ray-address needs --backend ray" in capsys.readouterr().err
    assert evaluate.main(["--config", str(tmp_path / "missing.yaml"), "--out", str(tmp_path)]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert evaluate.main(["--policies", "ppo:" + str(tmp_path / "none.zip"), "--out", str(tmp_path)]) == 2
    assert "no file" in capsys.readouterr().err
    corrupt = tmp_path / "bad.zip"
    corrupt.write_text("not a model")
    assert evaluate.main(["--policies", f"ppo:{corrupt}", "--out", str(tmp_path)]) == 2
    assert "not a Stable-Baselines3 model" in capsys.readouterr().err


def test_a_missing_ray_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    (tmp_path / "short.yaml").write_text("episode:\n  duration: 10.0\n")
    flags = [
        "--policies",
        "helix",
        "--motions",
        "static",
        "--episodes",
        "1",
        "--no-plots",
        "--measurement",
        "geometric",
        "--config",
        str(tmp_path / "short.yaml"),
        "--backend",
        "ray",
        "--out",
        str(tmp_path / "out"),
    ]
    assert evaluate.main(flags) == 2
    assert "--backend ray needs Ray" in capsys.readouterr().err


def test_an_interrupted_evaluation_resumes_where_it_stopped(tmp_path, monkeypatch, capsys):
    """Kill a run after its first episode (leaving a torn line): --resume runs only the rest and writes
    the same results as the uninterrupted run; another config is refused by name."""
    short, other = tmp_path / "short.yaml", tmp_path / "other.yaml"
    short.write_text("episode:\n  duration: 10.0\n")
    other.write_text("episode:\n  duration: 12.0\n")
    flags = [
        "--policies",
        "helix",
        "random",
        "--motions",
        "static",
        "--episodes",
        "2",
        "--no-plots",
        "--workers",
        "1",
        "--reflections",
        "off",
        "--config",
        str(short),
    ]
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert evaluate.main(flags + ["--out", str(whole)]) == 0
    lines = (whole / "episodes.jsonl").read_text().splitlines()
    assert len(lines) == 1 + 4  # the config, then one line an episode
    cut.mkdir()
    (cut / "episodes.jsonl").write_text("\n".join(lines[:2]) + "\n" + lines[2][: len(lines[2]) // 2])

    ran = []
    run_episode = study.run_episode
    monkeypatch.setattr(evaluate, "run_episode", lambda job: ran.append((job.policy, job.seed)) or run_episode(job))
    assert evaluate.main(flags + ["--out", str(cut), "--resume"]) == 0
    assert len(ran) == 3  # the torn episode ran again, the complete one did not
    episodes = [json.loads((out / "results.json").read_text())["episodes"] for out in (whole, cut)]
    assert episodes[0] == episodes[1]

    capsys.readouterr()
    assert evaluate.main(flags[:-1] + [str(other), "--out", str(cut), "--resume"]) == 2
    assert "--resume" in capsys.readouterr().err
