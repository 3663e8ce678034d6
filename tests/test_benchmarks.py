"""The study scripts' own arithmetic (``benchmarks/``), against closed forms and a Monte Carlo."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from aasl_gym.config import load_config

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_instructions
from crb_bound import as_few_chance, bound_env, efficient_count_range, efficient_success, episode_covariance
from heldout_figure import bound_rows, tracker_success
from reproduce_rows import differences, paper_variants
from sweep_patrol import parse_grid

ROOT = Path(__file__).resolve().parents[1]


def test_an_efficient_estimators_count_range_is_the_coin_flips():
    """Two fair coins: 0, 1 or 2 heads with chances 1/4, 1/2, 1/4; sure episodes always count."""
    assert efficient_count_range([0.5, 0.5]) == (0, 2)
    assert efficient_count_range([1.0] * 5) == (5, 5)
    assert as_few_chance([0.5, 0.5], 0) == 0.25
    assert as_few_chance([0.5, 0.5], 1) == 0.75


def test_the_count_range_and_the_chance_of_as_few_match_a_monte_carlo():
    """A hundred episodes with unequal chances (as a study's are): the range holds about 90 % of simulated counts
    and the chance of as few is their share at or below the count."""
    rng = np.random.default_rng(5)
    chances = rng.uniform(0.8, 1.0, size=100)
    counts = np.sum(rng.random((40000, 100)) < chances, axis=1)
    low, high = efficient_count_range(list(chances))
    inside = np.mean((counts >= low) & (counts <= high))
    assert 0.9 <= inside < 0.97  # whole counts: the range holds at least 90 %
    assert np.mean(counts < low) <= 0.05 and np.mean(counts > high) <= 0.05
    for count in (low, int(np.median(counts)), high):
        assert abs(as_few_chance(list(chances), count) - np.mean(counts <= count)) < 0.01


def _direct_path_rows(source, velocity, mobile, mobile_velocity, fixed):
    """d[RD, RRD]/d[p_s, v_s] (K, 2, 6) of the direct path from its geometry (geometry.py's conventions, written out
    here by hand): RD = |p_s - p_m| - |p_s - p_f|, RRD = (v_s - v_m) . u_m - v_s . u_f for a fixed p_f."""
    rows = np.zeros((len(mobile), 2, 6))
    for k, (p_m, v_m) in enumerate(zip(mobile, mobile_velocity)):
        to_mobile, to_fixed = source[k] - p_m, source[k] - fixed
        r_m, r_f = np.linalg.norm(to_mobile), np.linalg.norm(to_fixed)
        u_m, u_f = to_mobile / r_m, to_fixed / r_f
        rows[k, 0, :3] = rows[k, 1, 3:] = u_m - u_f
        rows[k, 1, :3] = (np.eye(3) - np.outer(u_m, u_m)) @ (velocity[k] - v_m) / r_m
        rows[k, 1, :3] -= (np.eye(3) - np.outer(u_f, u_f)) @ velocity[k] / r_f
    return rows


def _cv_track(position, velocity, times, z_max):
    """A CV source's positions and velocities (K, 6) at ``times`` (K,; s), turned back specularly at ``z_max`` (m), and
    their derivatives (K, 6, 6) in its [p_0, v_0]: past the bounce z = 2 z_max - (z_0 + v_z t), v_z the opposite."""
    track = np.concatenate([position + times[:, None] * velocity, np.broadcast_to(velocity, (len(times), 3))], axis=1)
    derivative = np.zeros((len(times), 6, 6))
    derivative[:, :3, :3] = derivative[:, 3:, 3:] = np.eye(3)
    derivative[:, :3, 3:] = times[:, None, None] * np.eye(3)
    bounced = track[:, 2] > z_max
    track[bounced, 2] = 2 * z_max - track[bounced, 2]
    track[bounced, 5] *= -1
    derivative[bounced, 2] *= -1
    derivative[bounced, 5] *= -1
    return track, derivative


@pytest.mark.parametrize("seed", [4, 29])  # 29: a bounce off the surface margin at 12.95 s
def test_the_cramer_rao_bound_is_the_closed_form_fisher_information_of_a_cv_track(seed):
    """``crb_bound.episode_covariance`` (finite differences of simulated tracks, point 1's bound) against the Fisher
    information written out from the direct path's closed-form gradients for a CV source that keeps its line or
    bounces off the surface margin: the prior, the two biases, R_eff and the position's covariance at every step, on
    the initializer study's world."""
    config = load_config(ROOT / "configs/initializer_study.yaml").replace(episode={"duration": 30.0})
    env = bound_env(config, "cv", "helix")
    covariance = episode_covariance(env, seed=seed)
    env.reset(seed=seed)
    source, dt = env.source, env.dt
    receiver, truth = [], []
    for _ in range(env.max_steps):
        env.step(np.zeros(3))
        receiver.append(np.concatenate([env.receiver_position, env.receiver_velocity]))
        truth.append(np.concatenate([env.source.position, env.source.velocity]))
    times = dt * np.arange(1, env.max_steps + 1)
    track, derivative = _cv_track(source.position, source.velocity, times, env.motion_region.z_max)
    assert np.allclose(track, truth) and (np.any(track[:, 5] != source.velocity[2]) == (seed == 29))
    receiver = np.array(receiver)
    rows = _direct_path_rows(track[:, :3], track[:, 3:], receiver[:, :3], receiver[:, 3:], env.fixed)
    jacobian = np.zeros((len(times), 2, 8))  # d z_k / d [p_0, v_0, b_p, b_v]
    jacobian[:, :, :6] = rows @ derivative
    jacobian[:, 0, 6] = jacobian[:, 1, 7] = 1.0
    measurement, navigation, prior = config.measurement, config.receiver, config.initializer
    noise = np.diag([measurement.range_difference_sd**2 + navigation.nav_position_sd**2,
                     measurement.range_rate_difference_sd**2 + navigation.velocity_sd**2])  # fmt: skip
    prior_sd = [prior.position_sd] * 3 + [prior.velocity_prior_sd] * 3 + [prior.range_bias_sd, prior.rate_bias_sd]
    information = np.diag(np.array(prior_sd) ** -2.0) + np.cumsum(
        np.swapaxes(jacobian, 1, 2) @ np.linalg.inv(noise) @ jacobian, axis=0
    )
    position = np.zeros((len(times), 3, 8))  # d p(t_k) / d [p_0, v_0, b_p, b_v]
    position[:, :, :6] = derivative[:, :3]
    expected = position @ np.linalg.inv(information) @ np.swapaxes(position, 1, 2)
    assert np.allclose(covariance, expected, rtol=1e-5, atol=1e-12)
    assert np.sqrt(np.trace(covariance[-1])) < 0.5 * np.sqrt(np.trace(covariance[10]))  # the track tells


def test_an_efficient_estimators_chance_is_the_chi_distributions_for_a_round_error():
    """Point 1's efficient estimator: for an error N(0, s^2 I) the chance of |e| < t is the chi law's (3 dof) cdf at
    t / s; a flat error along one axis, the normal's two-sided chance."""
    rng = np.random.default_rng(11)
    for sd in (0.3, 0.6, 1.2):
        assert abs(efficient_success(sd**2 * np.eye(3), 1.0, rng) - stats.chi(3).cdf(1.0 / sd)) < 0.015
    flat = np.diag([0.8**2, 1e-12, 1e-12])
    assert abs(efficient_success(flat, 1.0, rng) - (2 * stats.norm.cdf(1.0 / 0.8) - 1)) < 0.015


def test_the_heldout_figure_reads_the_bound_tables_at_one_metre(tmp_path):
    """A crb_bound.md with a 1 m table without and one with the tracker and oracle columns, then a 0.5 m table: the
    figure takes the last 1 m table's row of a motion (the efficient estimator's share and range, and the tracker's and
    MAP's shares where it has them); the tracker's share comes from a results.json where the set has one."""
    header = "| motion | episodes | bound < {t} m to the end | first time | efficient | its count, 90 % range |"
    tables = [
        header.format(t="1.0"), "|---|---|---|---|---|---|", "| cv | 100 | 96% | 23.5 | 95% | 92-98 |",
        "| static | 100 | 100% | 20.3 | 100% | 100-100 |", "",
        header.format(t="1.0") + " tracker | chance | ratio | MAP |", "|---|---|---|---|---|---|---|---|---|---|",
        "| cv | 100 | 96% | 23.5 | 94% | 91-97 | 93% | 32% | 0.72 | 97% |", "",
        header.format(t="0.5"), "|---|---|---|---|---|---|", "| cv | 100 | 78% | 38.5 | 84% | 79-89 |",
    ]  # fmt: skip
    (tmp_path / "crb_bound.md").write_text("Some prose.\n\n" + "\n".join(tables) + "\n")
    rows = bound_rows(tmp_path)
    assert rows["cv"] == {"episodes": 100, "efficient": 94.0, "low": 91.0, "high": 97.0, "tracker": 93.0, "map": 97.0}
    assert rows["static"] == {"episodes": 100, "efficient": 100.0, "low": 100.0, "high": 100.0}
    assert tracker_success(tmp_path, rows) == {"cv": 93.0}
    summary = [{"motion": "cv", "success_rate": {"1.0": 0.95}}]  # evaluate.py's, where the set has one
    (tmp_path / "results.json").write_text(json.dumps({"summary": summary}))
    assert tracker_success(tmp_path, rows) == {"cv": 95.0}


def test_the_reproduction_check_maps_a_paper_logs_variants_and_skips_timings():
    """The coefficient study's log (a 6 x 6 grid, two worlds, two filters): its rows' variant names map to the changes
    its config line holds, in order; a row's wall-clock fields are not compared, its other fields are."""
    header = json.loads((ROOT / "reports/paper/coefficients/episodes.jsonl").read_text().splitlines()[0])["config"]
    variants = paper_variants(header)
    assert len(variants) == 144 and list(variants.values()) == header["variants"]
    assert variants["phasor world, matched filter, a_surf -1, a_bed 0.2"]["world"]["bed_reflection"] == 0.2
    logged, now = {"rmse": 1.0, "tracker": {"ms_mean": 0.3, "median_error": 2.0}}, {"rmse": 1.0}
    now["tracker"] = {"ms_mean": 0.5, "median_error": 2.5}
    assert differences(logged, now) == ["tracker.median_error: logged 2.0, now 2.5"]


def test_the_instruction_count_runs_and_counts_what_it_is_asked(monkeypatch, capsys):
    """The child run takes the frames (or steps) it reports, so the counts divide by what ran; counts that are not
    FEW < MORE are refused with the flag named, before Valgrind is looked for."""
    assert bench_instructions.run_frontend("free", 3) == 3
    assert bench_instructions.run_frontend("default", 2) == 2
    monkeypatch.setattr(sys, "argv", ["bench_instructions.py", "--counts", "5", "3"])
    with pytest.raises(SystemExit):
        bench_instructions.main()
    assert "--counts must be two numbers with 0 <= FEW < MORE, got 5 3" in capsys.readouterr().err


def test_the_consistency_report_counts_chi_square_draws_inside_their_intervals(tmp_path):
    """Statistics drawn from their own chi-square laws (a consistent filter's): about 95 % inside the two-sided 95 %
    intervals and means near the dof; an unconverged episode is counted, not pooled; the report and its figure are
    written."""
    import consistency

    rng = np.random.default_rng(7)
    rows = [
        ("free", "cv", 12.0, list(rng.chisquare(3, 4000)), list(rng.chisquare(2, 4000))),
        ("free", "cv", np.inf, [], []),
        ("free", "ca", 30.0, list(4 * rng.chisquare(3, 4000)), list(rng.chisquare(2, 4000))),  # overconfident
    ]
    summary = consistency.groups(rows)
    cv, ca = summary
    assert cv[:4] == ("free", "cv", 1, 2) and cv[4].size == 4000
    assert abs(consistency.share(cv[4], consistency.NEES_BOUNDS) - 0.95) < 0.015
    assert abs(consistency.share(cv[5], consistency.NIS_BOUNDS) - 0.95) < 0.015
    assert abs(cv[4].mean() - 3) < 0.15 and abs(cv[5].mean() - 2) < 0.1
    assert consistency.share(ca[4], consistency.NEES_BOUNDS) < 0.7
    assert "| free | cv | 1 / 2 | 4000 |" in "\n".join(consistency.table(summary))
    consistency.write_report(tmp_path, summary)
    assert (tmp_path / "consistency.md").read_text().count("| free |") == 2
    assert (tmp_path / "consistency.png").read_bytes()[:4] == b"\x89PNG"


def test_a_patrol_sweeps_grid_names_a_bad_field_or_value():
    grid = parse_grid(["spiral_period=60,120", "spiral_depth=3"])
    assert grid == {"spiral_period": [60.0, 120.0], "spiral_depth": [3.0]}
    bad = (("spiral_perod=60", "a patrol field"), ("radius=", "a patrol field"), ("radius=5,x", "numbers"))
    for pair, message in bad:
        with pytest.raises(SystemExit, match=message):
            parse_grid([pair])


def test_a_malformed_run_names_what_is_expected():
    from tracker_check import parse_runs

    assert parse_runs(["free:static,cv:10:2"]) == [("free", m, s) for m in ("static", "cv") for s in (10, 11)]
    for bad, message in (("free:cv:10", "WORLD:MOTIONS"), ("moon:cv:1:2", "unknown world"), ("free:cw:1:2", "cw")):
        with pytest.raises(SystemExit, match=message):
            parse_runs([bad])
