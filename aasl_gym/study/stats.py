"""A study's statistics: per combination, success shares with 95 % Wilson intervals, convergence times with 95 %
Student-t intervals, the time to the first estimate and error medians (:func:`summarize`); per motion, each policy
or initializer against a baseline on the seeds they share (:func:`paired_comparisons`).

A row's missing values are ``None`` (an episode that never converged has no convergence time); the
censored statistics count such an episode as the full episode ``duration``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import stats

from aasl_gym.study.log import Row


def mean_sd(values: Sequence[float]) -> tuple[float | None, float | None]:
    """Mean and sample sd (None for no values; sd 0 for one)."""
    if not values:
        return None, None
    sd = float(np.std(values, ddof=1)) if len(values) > 1 else 0.0
    return float(np.mean(values)), sd


def mean_ci95(values: Sequence[float] | np.ndarray) -> tuple[float | None, list[float | None]]:
    """Mean and a 95 % Student-t confidence interval (None where it cannot be computed: no values for
    the mean, fewer than two for the interval). NaN is not dropped: callers remove missing values."""
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return None, [None, None]
    mean = float(values.mean())
    if values.size < 2:
        return mean, [None, None]
    half = float(stats.t.ppf(0.975, values.size - 1) * values.std(ddof=1) / np.sqrt(values.size))
    return mean, [mean - half, mean + half]


def share_ci95(successes: int, count: int) -> list[float]:
    """A 95 % Wilson interval of a share of ``successes`` in ``count`` episodes: unlike the normal approximation's, it
    stays within [0, 1] and does not shrink to a point at 0 % or 100 %."""
    interval = stats.binomtest(successes, count).proportion_ci(confidence_level=0.95, method="wilson")
    return [float(interval.low), float(interval.high)]


def _combination(row: Row) -> tuple[str, str, str, str]:
    return row["policy"], row["initializer"], row["motion"], row["measurement"]


def summarize(rows: list[Row], duration: float) -> list[Row]:
    """One summary row per policy x initializer x motion x measurement, sorted by them."""
    summary = []
    for key in sorted({_combination(r) for r in rows}, key=str):
        group = [r for r in rows if _combination(r) == key]
        summary.append(_summary_row(key, group, duration))
    return summary


def _summary_row(key: tuple[str, str, str, str], group: list[Row], duration: float) -> Row:
    policy, initializer, motion, measurement = key
    times = np.array([r["convergence_time"] for r in group if r["convergence_time"] is not None])
    censored = np.array([duration if r["convergence_time"] is None else r["convergence_time"] for r in group])
    mean, ci = mean_ci95(times)
    rmses = [r["rmse"] for r in group if r["rmse"] is not None]
    first = [r["time_to_first_estimate"] for r in group if r.get("time_to_first_estimate") is not None]
    successes = {k: sum(bool(r["success"][k]) for r in group) for k in group[0]["success"]}
    finals = [r["final_error"] for r in group if r["final_error"] is not None]
    return {
        "policy": policy,
        "initializer": initializer,
        "motion": motion,
        "measurement": measurement,
        "n": len(group),
        "success_rate": {k: count / len(group) for k, count in successes.items()},
        "success_rate_ci95": {k: share_ci95(count, len(group)) for k, count in successes.items()},
        "mean_convergence_time": mean,
        "convergence_time_ci95": ci,
        "mean_convergence_time_censored": float(censored.mean()),
        "mean_time_to_first_estimate": float(np.mean(first)) if first else None,
        "rmse_median": float(np.median(rmses)) if rmses else None,
        "final_error_median": float(np.median(finals)) if finals else None,
        "mean_reinitializations": float(np.mean([r["reinitializations"] for r in group])),
    }


def paired_comparisons(rows: list[Row], duration: float, field: str, baseline: str) -> list[Row]:
    """Per motion, each ``field`` value (policy or initializer) against ``baseline`` on shared seeds
    (and the same value of the other field).

    Convergence times are compared two ways: on the seeds where both converged (ratio of means), and
    with a non-converged episode counted as the full duration (censored).
    """
    out = []
    other_field = "policy" if field == "initializer" else "initializer"
    index = {(r[field], r["motion"], r["seed"], r[other_field]): r for r in rows}
    others = sorted({r[field] for r in rows} - {baseline})
    for motion in sorted({r["motion"] for r in rows}):
        for other in others:
            pairs = [
                (index[(other, m, s, k)], index[(baseline, m, s, k)])
                for (f, m, s, k) in index
                if f == other and m == motion and (baseline, m, s, k) in index
            ]
            if pairs:
                out.append({field: other, "baseline": baseline, "motion": motion, **_compare_pairs(pairs, duration)})
    return out


def _compare_pairs(pairs: list[tuple[Row, Row]], duration: float) -> Row:
    """The comparison of each pair's first row against its second (the baseline's)."""
    both = np.array(
        [
            (a["convergence_time"], b["convergence_time"])
            for a, b in pairs
            if a["convergence_time"] is not None and b["convergence_time"] is not None
        ]
    ).reshape(-1, 2)
    censored = np.array(
        [
            [
                duration if a["convergence_time"] is None else a["convergence_time"],
                duration if b["convergence_time"] is None else b["convergence_time"],
            ]
            for a, b in pairs
        ]
    )
    diff_mean, diff_ci = mean_ci95(censored[:, 0] - censored[:, 1])
    ratio_both = float(both[:, 0].mean() / both[:, 1].mean()) if len(both) and both[:, 1].mean() > 0 else None
    success = np.mean([a["success"]["1.0"] for a, _ in pairs]) - np.mean([b["success"]["1.0"] for _, b in pairs])
    return {
        "pairs": len(pairs),
        "both_converged": len(both),
        "time_ratio_both": ratio_both,
        "time_ratio_censored": float(censored[:, 0].mean() / censored[:, 1].mean()),
        "time_difference_censored": diff_mean,
        "time_difference_censored_ci95": diff_ci,
        "success_difference_1m": float(success),
    }


def study_comparisons(
    rows: list[Row], duration: float, policies: Sequence[str], initializers: Sequence[str]
) -> dict[str, list[Row]]:
    """The paired comparisons a study reports: initializers against ``naive`` (or the first), when it
    has several; policies against ``helix`` (or the first), when it has several."""
    comparisons = {}
    if len(initializers) > 1:
        baseline = "naive" if "naive" in initializers else initializers[0]
        comparisons["initializer"] = paired_comparisons(rows, duration, "initializer", baseline)
    if len(policies) > 1:
        baseline = "helix" if "helix" in policies else policies[0]
        comparisons["policy"] = paired_comparisons(rows, duration, "policy", baseline)
    return comparisons
