"""What a study writes: ``report.md`` (a few plain sentences, the summary table and the paired
comparisons), ``results.json`` (the stable interface other tools read) and the console's table."""

from __future__ import annotations

import math
import statistics
from pathlib import Path

from aasl_gym.config import EnvConfig, to_dict
from aasl_gym.io import atomic_write_text
from aasl_gym.study.jobs import MATCHED_FILTER
from aasl_gym.study.log import Row, write_results_json

SUMMARY_HEADER = [
    "| policy | initializer | motion | n | success 0.5 m | success 1 m [95 % CI] | success 3 m "
    "| mean conv. time (s) [95 % CI] | censored mean (s) | first estimate (s) | median RMSE (m) "
    "| median final error (m) | re-inits |",
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
]
DEFINITIONS = (
    "Convergence time: first time the error falls below 1 m and stays below to the end; its mean and 95 % CI are over "
    "the episodes that converged, the censored mean counts a non-converged episode as the full duration. "
    "Success at a threshold: the error converged below it within the episode (its 95 % CI: Wilson's; every "
    "threshold's is in results.json). First estimate: the mean time the tracker first gave an estimate."
)


def _fmt(value: float | None, digits: int = 1) -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}f}"


def plain_summary(summary: list[Row]) -> list[str]:
    """A few sentences on what the summary table says: per motion, which combination found the source
    (to within 1 m, and kept it) most often against the others; the re-initializations; how far a
    share at this many episodes can be trusted."""
    several_initializers = len({s["initializer"] for s in summary}) > 1
    label = (lambda s: f"{s['policy']} with {s['initializer']}") if several_initializers else (lambda s: s["policy"])
    sentences = []
    for motion in dict.fromkeys(s["motion"] for s in summary):
        rows = [s for s in summary if s["motion"] == motion]
        best = max(rows, key=lambda s: (s["success_rate"]["1.0"], -(s["mean_convergence_time_censored"] or math.inf)))
        others = ", ".join(f"{label(s)} {s['success_rate']['1.0']:.0%}" for s in rows if s is not best)
        sentences.append(
            f"{motion.upper() if motion != 'static' else 'Static'} sources: {label(best)} found and kept "
            f"the source to within 1 m in {best['success_rate']['1.0']:.0%} of {best['n']} "
            f"episode{'s' * (best['n'] != 1)}" + (f" ({others})." if others else ".")
        )
    busiest = max(summary, key=lambda s: s["mean_reinitializations"])
    sentences.append(
        f"The tracker re-initialized {min(s['mean_reinitializations'] for s in summary):.1f}-"
        f"{busiest['mean_reinitializations']:.1f} times per episode on average "
        f"(most: {label(busiest)}, {busiest['motion']})."
    )
    fewest = min(s["n"] for s in summary)
    sentences.append(
        f"With {fewest} episodes per combination a success share is known to about "
        f"+-{98 / math.sqrt(fewest):.0f} points (95 %); smaller differences may be chance."
    )
    return ["In short: " + " ".join(sentences), ""]


def _filter_models(models: dict[str, str]) -> str:
    """The filter's motion model for each source motion (``models``), in words; where one model serves every
    motion, the motions it does not match are named (their sources move otherwise than it predicts)."""
    used = set(models.values())
    if len(used) > 1:
        return "filter motion model per source motion: " + ", ".join(f"{m} `{f}`" for m, f in models.items())
    (model,) = used
    mismatched = [m for m in models if MATCHED_FILTER.get(m) != model]
    note = f" (not matched to the {', '.join(mismatched)} sources; `--filter-model matched` gives each motion its own)"
    return f"filter motion model `{model}` for every source motion" + (note if mismatched else "")


def _setup(config: EnvConfig, filter_models: dict[str, str]) -> str:
    """One paragraph on the measurements, navigation, reflections, filter and episode."""
    if config.measurement.mode == "geometric":
        measurements = (
            f"Measurement noise: sigma_R = {config.measurement.range_difference_sd} m, "
            f"sigma_V = {config.measurement.range_rate_difference_sd} m/s; "
        )
    else:
        measurements = (
            f"Measurements: the acoustic front end ({config.signal.path} path, "
            f"{config.signal.frame_duration} s frames, source level {config.source.source_level_db} dB, "
            f"noise level {config.world.noise_level_db} dB; R from each frame's SNR); "
        )
    return (
        measurements + f"navigation sigma_rov = {config.receiver.nav_position_sd} m; "
        f"reflections {'on' if config.world.reflections else 'off'}; filter multipath model "
        f"`{config.filter_multipath}`; {_filter_models(filter_models)}; episode {config.episode.duration:.0f} s at "
        f"{config.measurement.rate:.0f} Hz."
    )


def _summary_line(s: Row) -> str:
    ci = s["convergence_time_ci95"]
    rates = s["success_rate"]
    low, high = s["success_rate_ci95"]["1.0"]
    return (
        f"| {s['policy']} | {s['initializer']} | {s['motion']} | {s['n']} | "
        f"{rates['0.5']:.0%} | {rates['1.0']:.0%} [{low:.0%}, {high:.0%}] | {rates['3.0']:.0%} | "
        f"{_fmt(s['mean_convergence_time'])} [{_fmt(ci[0])}, {_fmt(ci[1])}] | "
        f"{_fmt(s['mean_convergence_time_censored'])} | {_fmt(s['mean_time_to_first_estimate'])} | "
        f"{_fmt(s['rmse_median'], 2)} | {_fmt(s['final_error_median'], 2)} | {s['mean_reinitializations']:.1f} |"
    )


def _comparison_section(field: str, rows: list[Row]) -> list[str]:
    plural = {"policy": "policies", "initializer": "initializers"}[field]
    lines = [
        "",
        f"## Paired comparison of {plural} against `{rows[0]['baseline']}` (same seeds)",
        "",
        f"| {field} | motion | pairs | both converged | time ratio (both converged) | time ratio (censored) "
        "| time difference (censored) [95 % CI] (s) | success 1 m difference |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in rows:
        ci = c["time_difference_censored_ci95"]
        lines.append(
            f"| {c[field]} | {c['motion']} | {c['pairs']} | {c['both_converged']} | "
            f"{_fmt(c['time_ratio_both'], 2)} | {_fmt(c['time_ratio_censored'], 2)} | "
            f"{_fmt(c['time_difference_censored'])} [{_fmt(ci[0])}, {_fmt(ci[1])}] | "
            f"{c['success_difference_1m']:+.0%} |"
        )
    return lines


def facility_section(rows: list[Row]) -> list[str]:
    """A facility's detection and hand-over per policy and motion, from the rows that carry them (``detection_time``,
    ``pod``, ``source_pod``: AASL-Facility-v0's episodes); nothing for a single pod. The robot cannot track before a
    pod hears the attack, so the time to 1 m is given after detection too."""
    rows = [row for row in rows if "detection_time" in row]
    if not rows:
        return []
    lines = [
        "",
        "## The facility: detection and hand-over",
        "",
        "| policy | motion | n | heard | paired with the attacked pod | detection (s): median "
        "| time to 1 m after detection (s): median |",
        "|---|---|---|---|---|---|---|",
    ]
    for policy, motion in dict.fromkeys((row["policy"], row["motion"]) for row in rows):
        cell = [row for row in rows if (row["policy"], row["motion"]) == (policy, motion)]
        heard, paired, delays = handover(cell)
        detection = _fmt(_median([row["detection_time"] for row in heard]))
        lines.append(
            f"| {policy} | {motion} | {len(cell)} | {len(heard) / len(cell):.0%} "
            f"| {'-' if math.isnan(paired) else f'{paired:.0%}'} | {detection} | {_fmt(_median(delays))} |"
        )
    return lines


def handover(rows: list[Row]) -> tuple[list[Row], float, list[float]]:
    """Of a facility's episodes (rows with ``detection_time``, ``pod``, ``source_pod``): those a pod heard, the share
    of them the tracker paired with the attacked pod (NaN if none was heard) and, for those that converged, the time
    (s) from detection to 1 m."""
    heard = [row for row in rows if row["detection_time"] is not None]
    paired = sum(row["pod"] == row["source_pod"] for row in heard) / len(heard) if heard else math.nan
    converged = [row for row in heard if row["convergence_time"] is not None]
    return heard, paired, [row["convergence_time"] - row["detection_time"] for row in converged]


def _median(values: list[float]) -> float | None:
    return statistics.median(values) if values else None


def write_report(
    path: Path,
    command: str,
    config: EnvConfig,
    filter_models: dict[str, str],
    summary: list[Row],
    comparisons: dict[str, list[Row]],
    plots: list[str],
    rows: list[Row] | None = None,
) -> None:
    """``report.md``, atomically: ``config`` is the one the episodes ran with, ``filter_models`` the filter's
    motion model for each source motion, ``plots`` the figures' file names beside it; the episodes' ``rows`` add
    a facility's detection and hand-over (:func:`facility_section`)."""
    lines = [
        "# AASL-Gym evaluation",
        "",
        *plain_summary(summary),
        f"Command: `{command}`",
        "",
        _setup(config, filter_models),
        "",
        DEFINITIONS,
        "",
        "## Summary",
        "",
        *SUMMARY_HEADER,
        *(_summary_line(s) for s in summary),
    ]
    for field, compared in comparisons.items():
        if compared:
            lines += _comparison_section(field, compared)
    lines += facility_section(rows or [])
    if plots:
        lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    atomic_write_text(path, "\n".join(lines) + "\n")


def write_results(
    path: Path, command: str, config: EnvConfig, rows: list[Row], summary: list[Row], comparisons: dict[str, list[Row]]
) -> None:
    """``results.json``, atomically: ``{"command", "config", "episodes", "summary", "comparisons", "platform"}``
    (the schema of the project's spec; rows without their recorded paths; ``platform``: where it was written)."""
    write_results_json(
        path,
        {
            "command": command,
            "config": to_dict(config),
            "episodes": rows,
            "summary": summary,
            "comparisons": comparisons,
        },
    )


def console_table(summary: list[Row]) -> list[str]:
    """The summary's main columns as fixed-width text lines."""
    width = max(len("policy"), *(len(s["policy"]) for s in summary))  # a model's name carries its path
    lines = [
        f"{'policy':<{width}} {'initializer':<11} {'motion':<7} {'n':>4} {'succ@1m':>8} {'conv (s)':>9} {'RMSE med':>9}"
    ]
    for s in summary:
        lines.append(
            f"{s['policy']:<{width}} {s['initializer']:<11} {s['motion']:<7} {s['n']:>4} "
            f"{s['success_rate']['1.0']:>8.0%} {_fmt(s['mean_convergence_time']):>9} "
            f"{_fmt(s['rmse_median'], 2):>9}"
        )
    return lines
