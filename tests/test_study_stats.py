"""aasl_gym.study.stats against independent truths: scipy's t interval and hand-computed answers on rows
built so that the answer is known."""

import math

import numpy as np
import pytest
from scipy import stats

from aasl_gym.study.stats import mean_ci95, paired_comparisons, share_ci95, study_comparisons, summarize

DURATION = 100.0


def row(
    policy="helix",
    seed=0,
    time=None,
    success=None,
    motion="static",
    initializer="lcmap",
    rmse=1.0,
    final_error=0.5,
    reinitializations=0,
    measurement="geometric",
    first=None,
):
    """An episode row; ``success`` defaults to converging within 1 m exactly when ``time`` is set."""
    converged = time is not None
    success = {"0.5": converged, "1.0": converged, "3.0": True} if success is None else success
    return {
        "policy": policy,
        "initializer": initializer,
        "motion": motion,
        "measurement": measurement,
        "seed": seed,
        "convergence_time": time,
        "success": success,
        "rmse": rmse,
        "final_error": final_error,
        "reinitializations": reinitializations,
        "time_to_first_estimate": first,
    }


def test_mean_ci95_is_the_student_t_interval():
    # By hand: mean 2, sd 1, t(0.975, 2 dof) = 4.303 (the tables' value), half width 4.303 / sqrt(3).
    mean, (low, high) = mean_ci95([1.0, 2.0, 3.0])
    assert mean == 2.0
    assert low == pytest.approx(2 - 4.303 / math.sqrt(3), abs=1e-3)
    assert high == pytest.approx(2 + 4.303 / math.sqrt(3), abs=1e-3)
    sample = np.random.default_rng(7).normal(30.0, 8.0, size=17)
    expected = stats.t.interval(0.95, df=16, loc=sample.mean(), scale=stats.sem(sample))
    mean, ci = mean_ci95(sample)
    assert mean == pytest.approx(np.mean(sample))
    assert ci == pytest.approx(list(expected), rel=1e-12)


def test_mean_ci95_without_enough_values():
    assert mean_ci95([]) == (None, [None, None])
    assert mean_ci95(np.array([])) == (None, [None, None])
    assert mean_ci95([4.5]) == (4.5, [None, None])  # a mean, but no spread to build an interval on
    mean, (low, high) = mean_ci95([2.0, 2.0])
    assert mean == low == high == 2.0  # no spread: the interval closes on the mean
    mean, ci = mean_ci95([1.0, float("nan"), 3.0])
    assert math.isnan(mean) and all(math.isnan(v) for v in ci)  # a NaN is not silently dropped


def test_a_shares_interval_is_wilsons():
    """Wilson's interval written out: (p + z^2/2n +- z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n), z = 1.96."""
    z = stats.norm.ppf(0.975)
    for successes, count in ((93, 100), (0, 10), (10, 10), (1, 3)):
        p = successes / count
        centre, half = p + z**2 / (2 * count), z * math.sqrt(p * (1 - p) / count + z**2 / (4 * count**2))
        expected = [(centre - half) / (1 + z**2 / count), (centre + half) / (1 + z**2 / count)]
        assert share_ci95(successes, count) == pytest.approx(expected, abs=1e-12)
    assert share_ci95(10, 10)[1] == pytest.approx(1.0) and share_ci95(10, 10)[0] < 0.75  # not a point at 100 %


def test_summary_of_hand_made_rows():
    rows = [
        row(seed=0, time=10.0, rmse=1.0, final_error=0.2, reinitializations=1, first=2.0),
        row(seed=1, time=None, rmse=None, final_error=4.0, reinitializations=0, first=3.0),
        row(seed=2, time=30.0, rmse=5.0, final_error=None, reinitializations=2, first=7.0),
        row(seed=3, time=None, rmse=2.0, final_error=0.6, reinitializations=1),
        row(policy="spiral", seed=0, time=None, rmse=None, final_error=None),
    ]
    helix, spiral = summarize(rows, DURATION)
    assert (helix["policy"], helix["n"], spiral["policy"], spiral["n"]) == ("helix", 4, "spiral", 1)
    assert helix["success_rate"] == {"0.5": 0.5, "1.0": 0.5, "3.0": 1.0}
    assert helix["success_rate_ci95"]["1.0"] == share_ci95(2, 4) and helix["success_rate_ci95"]["3.0"][1] == 1.0
    assert helix["mean_time_to_first_estimate"] == 4.0  # of 2, 3 and 7: the episode with none left out
    # Over the two episodes that converged: mean 20, sd sqrt(200), t(0.975, 1 dof) = 12.706.
    assert helix["mean_convergence_time"] == 20.0
    assert helix["convergence_time_ci95"] == pytest.approx([20 - 12.706 * 10, 20 + 12.706 * 10], abs=0.01)
    assert helix["mean_convergence_time_censored"] == (10 + DURATION + 30 + DURATION) / 4
    assert helix["rmse_median"] == 2.0  # of 1, 5, 2: the missing one left out
    assert helix["final_error_median"] == 0.6  # of 0.2, 4, 0.6
    assert helix["mean_reinitializations"] == 1.0
    # Nothing converged and nothing measured: no mean, no interval, the censored mean is the duration.
    assert spiral["mean_convergence_time"] is None and spiral["convergence_time_ci95"] == [None, None]
    assert spiral["mean_convergence_time_censored"] == DURATION
    assert spiral["rmse_median"] is None and spiral["final_error_median"] is None
    assert spiral["success_rate"]["1.0"] == 0.0 and spiral["mean_time_to_first_estimate"] is None


def test_summary_groups_by_policy_initializer_motion_and_measurement():
    rows = [
        row(motion=m, initializer=i, measurement=k, seed=s, time=5.0)
        for m in ("static", "cv")
        for i in ("naive", "lcmap")
        for k in ("signal", "geometric")
        for s in (0, 1, 2)
    ]
    summary = summarize(rows, DURATION)
    keys = [(s["policy"], s["initializer"], s["motion"], s["measurement"]) for s in summary]
    assert keys == sorted(keys, key=str) and len(set(keys)) == 8
    assert all(s["n"] == 3 for s in summary)


def paired_rows():
    """spiral against helix on seeds 0-4 (static); spiral's extra rows have no partner: seed 5, another
    initializer, and a motion helix never ran."""
    helix = [row("helix", seed, time) for seed, time in enumerate((10.0, 20.0, 30.0, None, 40.0))]
    spiral = [row("spiral", seed, time) for seed, time in enumerate((15.0, 20.0, None, 50.0, None))]
    unpaired = [row("spiral", 5, 1.0), row("spiral", 0, 1.0, initializer="naive"), row("spiral", 0, 1.0, motion="cv")]
    return helix + spiral + unpaired


def test_paired_comparison_on_rows_with_a_known_answer():
    (comparison,) = paired_comparisons(paired_rows(), DURATION, "policy", "helix")
    assert (comparison["policy"], comparison["baseline"], comparison["motion"]) == ("spiral", "helix", "static")
    assert comparison["pairs"] == 5
    assert comparison["both_converged"] == 2  # seeds 0 and 1
    assert comparison["time_ratio_both"] == pytest.approx((15 + 20) / (10 + 20))
    # Censored: spiral 15, 20, 100, 50, 100 against helix 10, 20, 30, 100, 40.
    assert comparison["time_ratio_censored"] == pytest.approx(285 / 200)
    differences = np.array([5.0, 0.0, 70.0, -50.0, 60.0])
    assert comparison["time_difference_censored"] == pytest.approx(17.0)
    expected = stats.t.interval(0.95, df=4, loc=differences.mean(), scale=stats.sem(differences))
    assert comparison["time_difference_censored_ci95"] == pytest.approx(list(expected))
    assert comparison["success_difference_1m"] == pytest.approx(3 / 5 - 4 / 5)


def test_paired_comparison_by_initializer_and_without_shared_convergence():
    rows = [row(initializer="lcmap", seed=s, time=None) for s in range(3)]
    rows += [row(initializer="naive", seed=s, time=40.0) for s in range(3)]
    (comparison,) = paired_comparisons(rows, DURATION, "initializer", "naive")
    assert comparison["initializer"] == "lcmap" and comparison["pairs"] == 3
    assert comparison["both_converged"] == 0 and comparison["time_ratio_both"] is None
    assert comparison["time_ratio_censored"] == pytest.approx(DURATION / 40.0)
    assert comparison["time_difference_censored"] == pytest.approx(60.0)
    assert comparison["time_difference_censored_ci95"] == pytest.approx([60.0, 60.0])  # the same every seed
    assert comparison["success_difference_1m"] == pytest.approx(-1.0)


def test_a_study_compares_against_naive_and_helix_or_the_first():
    rows = paired_rows()
    assert set(study_comparisons(rows, DURATION, ["helix", "spiral"], ["lcmap"])) == {"policy"}
    assert study_comparisons(rows, DURATION, ["spiral", "helix"], ["lcmap"])["policy"][0]["baseline"] == "helix"
    assert study_comparisons(rows, DURATION, ["spiral"], ["lcmap", "naive"])["initializer"][0]["baseline"] == "naive"
    by_first = study_comparisons(rows, DURATION, ["spiral"], ["lcmap", "random"])["initializer"]
    assert by_first[0]["baseline"] == "lcmap"
    assert study_comparisons(rows, DURATION, ["spiral"], ["lcmap"]) == {}
