"""What ``paper.py arrays`` writes: ``results.json``, ``report.md`` (the paper's comparison table beside ours,
the arrays' noise sweep) and ``arrays.png`` (each method's RMSE against the arrays' RD noise)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from aasl_gym.config import to_dict
from aasl_gym.io import atomic_write_text
from aasl_gym.scenarios import scenario_description
from aasl_gym.study.array_comparison import APERTURE_WAVELENGTHS, SWEEP_STRIDE, summarize, summarize_sweep
from aasl_gym.study.log import Row, write_results_json
from aasl_gym.study.paper import Study
from aasl_gym.study.plots import save_png

DPI = 110
PODS = 8  # the facility the totals are counted for (the paper's)
# The reference paper's table: RMSE (m) and update time (ms) per method.
PAPER = {"osls": (1.41, 0.30), "sdp": (0.94, 8.03), "ours": (0.69, 0.49)}
ESTIMATES = {
    "osls": "position, per snapshot",
    "sdp": "position, per snapshot",
    "ours": "position, velocity and the RD / RRD offsets, over the track",
}
LABELS = {"osls": "OSLS, 6 receivers", "sdp": "SDP, 8 receivers", "ours": "ours, 2 receivers (the tracker)"}


def _fmt(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _comparison_table(summary: list[Row]) -> list[str]:
    lines = [
        f"| method | receivers per pod | for {PODS} pods | estimates | RMSE (m): mean ± sd of trials | median RMSE (m) "
        "| median error (m) | bound on the RMSE (m) | update (ms): mean / median | paper: RMSE (m), update (ms) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for entry in summary:
        name = entry["method"]
        paper_rmse, paper_ms = PAPER[name]
        lines.append(
            f"| {LABELS[name]} | {entry['receivers_per_pod']} | {entry['receivers_total']} | {ESTIMATES[name]} "
            f"| {_fmt(entry['rmse_mean'])} ± {_fmt(entry['rmse_sd'])} | {_fmt(entry['rmse_median'])} "
            f"| {_fmt(entry['median_error'])} | {_fmt(entry['bound_rmse'])} "
            f"| {_fmt(entry['ms_mean'], 3)} / {_fmt(entry['ms_median'], 3)} "
            f"| {paper_rmse:.2f}, {paper_ms:.2f} |"
        )
    return lines


def _sweep_table(sweep: list[Row]) -> list[str]:
    lines = [
        "| arrays' RD noise sd (m) | OSLS RMSE (m): mean (median) | its bound (m) | SDP RMSE (m): mean (median) "
        "| its bound (m) |",
        "|---|---|---|---|---|",
    ]
    for entry in sweep:
        cells = [
            f"{_fmt(entry[n]['rmse_mean'])} ({_fmt(entry[n]['rmse_median'])}) | {_fmt(entry[n]['bound_rmse'])}"
            for n in ("osls", "sdp")
        ]
        lines.append(f"| {entry['sd']:g} | {cells[0]} | {cells[1]} |")
    return lines


def _sweep_figure(summary: list[Row], sweep: list[Row], sd: float) -> Figure:
    figure = Figure(figsize=(7, 4.2))
    ax = figure.subplots()
    levels = np.array([entry["sd"] for entry in sweep])
    for index, name in enumerate(("osls", "sdp")):
        medians = np.array([np.nan if e[name]["rmse_median"] is None else e[name]["rmse_median"] for e in sweep])
        ax.plot(levels, medians, marker="o", color=f"C{index}", label=f"{LABELS[name]}: median RMSE")
        bounds = np.array([np.nan if e[name]["bound_rmse"] is None else e[name]["bound_rmse"] for e in sweep])
        ax.plot(levels, bounds, "--", color=f"C{index}", alpha=0.6, label=f"{name.upper()}: Cramer-Rao bound")
        ax.axhline(PAPER[name][0], color=f"C{index}", linestyle=":", label=f"paper, {name.upper()}")
    ours = next(entry for entry in summary if entry["method"] == "ours")
    if ours["rmse_median"] is not None:
        ax.plot(
            [sd], [ours["rmse_median"]], marker="*", markersize=14, color="C2", linestyle="none", label=LABELS["ours"]
        )
    ax.axhline(PAPER["ours"][0], color="C2", linestyle=":", label="paper, ours")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("RD noise sd (m); the tracker's is the star's")
    ax.set_ylabel("RMSE (m)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    return figure


def write_array_comparison(
    out: Path, command: str, study: Study, motion: str, rows: list[Row], plots: bool = True
) -> list[Path]:
    """``results.json``, ``report.md`` and ``arrays.png`` (unless ``plots`` is off), atomically."""
    config = study.config()
    sd = config.measurement.range_difference_sd
    summary, sweep = summarize(rows, PODS), summarize_sweep(rows, sd)
    seeds = sorted({row["seed"] for row in rows})
    names = [save_png(_sweep_figure(summary, sweep, sd), out, "arrays.png", DPI)] if plots else []
    results: dict[str, Any] = {"command": command, "study": study.name, "scenario": study.scenario, "motion": motion}
    results |= {"config": to_dict(config), "trials": rows, "summary": summary, "sweep": sweep}
    write_results_json(out / "results.json", results)
    aperture = APERTURE_WAVELENGTHS * config.wavelength
    lines = [
        "# The reference paper's comparison with fixed arrays",
        "",
        f"Command: `{command}`",
        "",
        f"Scenario `{study.scenario}`: {scenario_description(study.scenario)}",
        "",
        f"{len(seeds)} trials (seeds {seeds[0]}-{seeds[-1]}), a {motion} source. Ours: the "
        f"{config.episode.duration:.0f} s helix patrol with the LC-MAP tracker. The arrays: centred on the pod's "
        f"hydrophone, every receiver within {APERTURE_WAVELENGTHS:g} wavelength ({aperture:.2f} m) "
        f"of every other (an octahedron for OSLS, a cube for SDP), one snapshot of range differences per step of "
        f"the same source track, each RD with the tracker's noise sd ({sd:g} m). RMSE over the steps from the "
        "tracker's first estimate on; update: one snapshot's solve, one `tracker.step` (starts and re-seeds "
        "included). Bound on the RMSE: the Cramer-Rao bound of the array for one snapshot (the root of its mean "
        "trace over the snapshots; median over the trials).",
        "",
        *_comparison_table(summary),
        "",
        f"## The arrays' RD noise (every {SWEEP_STRIDE}th snapshot)",
        "",
        *_sweep_table(sweep),
    ]
    lines += [line for name in names for line in ("", f"![{name}]({name})")]
    atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
    return [out / "report.md", out / "results.json"] + [out / name for name in names]
