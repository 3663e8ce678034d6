"""What ``paper.py`` writes for a study: ``results.json``, ``report.md`` (our numbers beside the reference
paper's) and its figures - the coefficient heat maps, the navigation sweep and the model-error map."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from aasl_gym.config import EnvConfig, to_dict
from aasl_gym.io import atomic_write_text
from aasl_gym.scenarios import scenario_config, scenario_description
from aasl_gym.study.log import Row, write_results_json
from aasl_gym.study.paper import (
    DIVERGENCE_RMSE,
    LAKE_MOTIONS,
    LAKE_PATROLS,
    WORLD_MODELS,
    Study,
    model_error_map,
    model_error_samples,
)
from aasl_gym.study.plots import pop_trajectories, save_png, write_trajectory_plots
from aasl_gym.study.report import handover

DPI = 110
QUANTILES = (50, 90, 99)  # %, of the models' absolute errors
# The reference paper's multipath table (100 trials; metrics over its converged trials): what ours stands beside.
PAPER_MULTIPATH = (
    ("paper's world", "direct path only", "9 %", "25.71 ± 2.44", "10.10 ± 3.57", "106.16 ± 15.83"),
    ("paper's world", "multipath-aware", "100 %", "0.98 ± 2.15", "0.15 ± 0.97", "9.27 ± 22.40"),
)
DEFINITIONS = (
    f"A trial diverged when its RMSE (over the steps with an estimate) exceeds {DIVERGENCE_RMSE:.0f} m or it never "
    "had an estimate (the paper's definition); converged: the share that did not. RMSE, final and maximum error are "
    "the mean ± sample sd over the converged trials, as the paper gives them; RMSE, 2nd half (ours): over the "
    "episode's second half, the tracking once the start is long past; success at 1 m (ours): the error fell "
    "below 1 m and stayed there to the end."
)


def _fmt(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _median_cell(values: Sequence[float | None], digits: int = 2) -> str:
    """The median of the known ``values``, or "-"."""
    known = [value for value in values if value is not None]
    return _fmt(float(np.median(known)), digits) if known else "-"


def _rmse_cells(rmse: list[float]) -> tuple[str, str]:
    """The table's "mean ± sd" (with two trials or more) and median of trials' RMSEs (m)."""
    spread = f"{np.mean(rmse):.2f} ± {np.std(rmse, ddof=1):.2f}" if len(rmse) > 1 else "-"
    return spread, _median_cell(rmse)


def _pm(entry: Row, metric: str) -> str:
    return f"{_fmt(entry[metric + '_mean'])} ± {_fmt(entry[metric + '_sd'])}"


def _setup(study: Study, motion: str, config: EnvConfig, seeds: list[int]) -> list[str]:
    sources = f"{', '.join(study.motions)} sources" if study.motions else f"a {motion} source"
    patrols = list(dict.fromkeys(variant.policy for variant in study.variants))
    patrol = f"{patrols[0]} patrol" if len(patrols) == 1 else "patrol it names (" + ", ".join(patrols) + ")"
    return [
        f"Scenario `{study.scenario}`: {scenario_description(study.scenario)}",
        "",
        f"Each variant runs the {config.episode.duration:.0f} s {patrol} with the LC-MAP tracker on the same "
        f"{len(seeds)} seeds ({seeds[0]}-{seeds[-1]}), {sources}, the filter's motion model matched to "
        + ("each." if study.motions else "it."),
        "",
        DEFINITIONS,
    ]


def _variant_table(summary: list[Row], columns: list[str]) -> list[str]:
    metrics = "n | converged | RMSE (m) | final error (m) | maximum error (m) | RMSE, 2nd half (m) | success 1 m"
    lines = ["| " + " | ".join([*columns, metrics]) + " |", "|" + "---|" * (len(columns) + 7)]
    for entry in summary:
        cells = [str(entry[column]) for column in columns]
        lines.append(
            "| " + " | ".join(cells) + f" | {entry['n']} | {entry['converged_rate']:.0%} | {_pm(entry, 'rmse')} | "
            f"{_pm(entry, 'final_error')} | {_pm(entry, 'max_error')} | {_pm(entry, 'rmse_second_half')} | "
            f"{entry['success_rate_1m']:.0%} |"
        )
    return lines


def _multipath_section(summary: list[Row]) -> list[str]:
    lines = ["## The multipath table", "", *_variant_table(summary, ["world", "filter"]), ""]
    lines += ["The paper's table (its world, 100 trials):", ""]
    lines += [
        "| world | filter | converged | RMSE (m) | final error (m) | maximum error (m) |",
        "|---|---|---|---|---|---|",
    ]
    lines += ["| " + " | ".join(row) + " |" for row in PAPER_MULTIPATH]
    return lines


def _coefficient_grid(summary: list[Row], world: str) -> tuple[list[float], list[float], dict[str, np.ndarray]]:
    """Per filter, the mean RMSE (m, diverged trials included) on the (a_surf, a_bed) grid of ``world``."""
    cells = [entry for entry in summary if entry["world"] == world]
    surface = sorted({entry["surface_reflection"] for entry in cells})
    bed = sorted({entry["bed_reflection"] for entry in cells})
    maps = {}
    for model in ("none", "matched"):
        grid = np.full((len(surface), len(bed)), np.nan)
        for entry in cells:
            if entry["filter"] == model and entry["rmse_all_mean"] is not None:
                grid[surface.index(entry["surface_reflection"]), bed.index(entry["bed_reflection"])] = entry[
                    "rmse_all_mean"
                ]
        maps[model] = grid
    return surface, bed, maps


def _coefficient_section(summary: list[Row]) -> list[str]:
    lines = ["## Mean RMSE (m) by reflection coefficients: direct-path filter / the world's own", ""]
    for world in WORLD_MODELS:
        surface, bed, maps = _coefficient_grid(summary, world)
        lines += [f"{world} world (rows a_surf, columns a_bed):", ""]
        lines += ["| a_surf \\ a_bed | " + " | ".join(f"{b:.2f}" for b in bed) + " |", "|---|" + "---|" * len(bed)]
        for i, a_surf in enumerate(surface):
            cells = [f"{maps['none'][i, j]:.1f} / {maps['matched'][i, j]:.1f}" for j in range(len(bed))]
            lines.append(f"| {a_surf:+.2f} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def _coefficient_figure(summary: list[Row]) -> Figure:
    figure = Figure(figsize=(12, 7.5))
    axes = figure.subplots(len(WORLD_MODELS), 3)
    for row, world in enumerate(WORLD_MODELS):
        surface, bed, maps = _coefficient_grid(summary, world)
        difference = maps["none"] - maps["matched"]
        largest = float(np.nanmax(np.abs(difference))) if np.any(np.isfinite(difference)) else 1.0
        panels: tuple[tuple[np.ndarray, str, str, dict[str, float]], ...] = (
            (maps["none"], "direct-path filter", "viridis", {}),
            (maps["matched"], "multipath-aware filter (the world's model)", "viridis", {}),
            (difference, "difference (direct - aware)", "RdBu_r", {"vmin": -largest, "vmax": largest}),  # 0: white
        )
        for ax, (grid, title, colours, limits) in zip(axes[row], panels):
            extent = _extent(bed, surface)
            image = ax.imshow(grid, origin="lower", aspect="auto", cmap=colours, extent=extent, **limits)
            figure.colorbar(image, ax=ax, label="mean RMSE (m)")
            ax.set_xticks(bed)  # a tick at each cell's centre
            ax.set_yticks(surface)
            ax.set_title(f"{world} world: {title}", fontsize=9)
            ax.set_xlabel("a_bed")
            ax.set_ylabel("a_surf")
    figure.tight_layout()
    return figure


def _extent(x: list[float], y: list[float]) -> tuple[float, float, float, float]:
    dx = (x[-1] - x[0]) / max(1, len(x) - 1) / 2
    dy = (y[-1] - y[0]) / max(1, len(y) - 1) / 2
    return (x[0] - dx, x[-1] + dx, y[0] - dy, y[-1] + dy)


def _navigation_section(summary: list[Row]) -> list[str]:
    lines = ["## RMSE by navigation error", ""]
    return lines + _variant_table(summary, ["sigma_rov", "compensation", "drift"])


def _navigation_figure(summary: list[Row], rows: list[Row]) -> Figure:
    figure = Figure(figsize=(7, 4.2))
    ax = figure.subplots()
    for index, (compensation, drift) in enumerate(dict.fromkeys((e["compensation"], e["drift"]) for e in summary)):
        cells = [e for e in summary if (e["compensation"], e["drift"]) == (compensation, drift)]
        levels = np.array([e["sigma_rov"] for e in cells])
        rmse = [[r["rmse"] for r in rows if r["variant"] == e["variant"] and r["rmse"] is not None] for e in cells]
        means = np.array([np.mean(v) if v else np.nan for v in rmse])
        spread = np.array([np.std(v, ddof=1) if len(v) > 1 else 0.0 for v in rmse])
        label = compensation + (f", drift {drift:g} m/sqrt(s)" if drift else "")
        style = "--" if drift else "-"
        ax.plot(levels, means, style, marker="o", color=f"C{index}", label=label)
        low = np.maximum(means - spread, 0.1 * means)  # the log axis has no room for a band below zero
        ax.fill_between(levels, low, means + spread, color=f"C{index}", alpha=0.15)
    ax.set_xlabel("sigma_rov (m); velocity sd 0.4 sigma_rov")
    ax.set_ylabel("RMSE (m): mean ± sd of the trials with an estimate")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    return figure


PAPER_LAKE = {"nominal": 1.89, "compensated": 1.37}  # m, the paper's lake RMSE of each filter


def _lake_section(summary: list[Row], rows: list[Row]) -> list[str]:
    ordered = sorted(summary, key=lambda e: (LAKE_PATROLS.index(e["patrol"]), LAKE_MOTIONS.index(e["motion"])))
    lines = ["## RMSE by patrol and source path", "", *_variant_table(ordered, ["patrol", "motion", "filter"]), ""]
    lines += [
        "## All trials: nominal against compensated",
        "",
        "| filter | trials | with an estimate | RMSE (m): mean ± sd | median RMSE (m) | success 1 m "
        "| paper's RMSE (m) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, paper_rmse in PAPER_LAKE.items():
        trials = [row for row in rows if row["variant"].startswith(f"{name} filter")]
        rmse = [row["rmse"] for row in trials if row["rmse"] is not None]
        spread, median = _rmse_cells(rmse)
        success = np.mean([row["success"]["1.0"] for row in trials]) if trials else float("nan")
        lines.append(
            f"| {name} | {len(trials)} | {len(rmse)} | {spread} | {median} | {success:.0%} | {paper_rmse:.2f} |"
        )
    return lines


def _lake_figure(summary: list[Row]) -> Figure:
    figure = Figure(figsize=(11, 4.2))
    ax = figure.subplots()
    cells = list(dict.fromkeys((entry["patrol"], entry["motion"]) for entry in summary))
    for index, name in enumerate(PAPER_LAKE):
        medians = [
            next(e["rmse_median"] for e in summary if (e["patrol"], e["motion"], e["filter"]) == (*cell, name))
            for cell in cells
        ]
        heights = [np.nan if value is None else value for value in medians]
        ax.bar(
            np.arange(len(cells)) + 0.4 * index - 0.2,
            heights,
            width=0.4,
            color=f"C{index}",
            label=f"{name}: median RMSE",
        )
        ax.axhline(PAPER_LAKE[name], color=f"C{index}", linestyle=":", label=f"paper, {name}")
    ax.set_xticks(np.arange(len(cells)), [f"{patrol}\n{motion}" for patrol, motion in cells], fontsize=8)
    ax.set_ylabel("RMSE (m)")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, axis="y", which="both")
    ax.legend(fontsize=8)
    return figure


PAPER_FACILITY_RMSE = 1.65  # m, the paper's 8-pod run


def _facility_section(rows: list[Row]) -> list[str]:
    lines = [
        "## The facility: detection, hand-over and tracking",
        "",
        "| source | pairs | trials | heard | paired with the attacked pod | detection (s): median "
        "| RMSE (m): mean ± sd | median RMSE (m) | success 1 m | time to 1 m after detection (s): median "
        "| final error (m): median | RMSE, 2nd half (m): median | paper's RMSE (m) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    cells = dict.fromkeys((row["motion"], row["variant"]) for row in rows)
    for motion, variant in cells:
        trials = [row for row in rows if row["motion"] == motion and row["variant"] == variant]
        heard, same_pod, delays = handover(trials)
        detection = _median_cell([row["detection_time"] for row in heard], 1)
        spread, median = _rmse_cells([row["rmse"] for row in trials if row["rmse"] is not None])
        success = np.mean([row["success"]["1.0"] for row in trials])
        lines.append(
            f"| {motion} | {variant} | {len(trials)} | {len(heard) / len(trials):.0%} | {same_pod:.0%} | {detection} "
            f"| {spread} | {median} | {success:.0%} | {_median_cell(delays, 1)} "
            f"| {_median_cell([row['final_error'] for row in trials])} "
            f"| {_median_cell([row['rmse_second_half'] for row in trials])} | {PAPER_FACILITY_RMSE:.2f} |"
        )
    return lines + ["", *_paired_lines(rows, "loudest pod", "rmse")]


def _paired_lines(rows: list[Row], baseline: str, metric: str) -> list[str]:
    """Per motion and variant other than ``baseline``, on the seeds both ran: the share of trials whose
    ``metric`` is below the baseline's and the median of their ratio."""
    known = {(row["motion"], row["variant"], row["seed"]): row[metric] for row in rows if row[metric] is not None}
    lines = []
    for motion, variant in dict.fromkeys((m, v) for m, v, _ in known if v != baseline):
        pairs = [
            (value, known[(motion, baseline, seed)])
            for (m, v, seed), value in known.items()
            if (m, v) == (motion, variant) and (motion, baseline, seed) in known
        ]
        if pairs:
            ratio = float(np.median([value / base for value, base in pairs]))
            lower = np.mean([value < base for value, base in pairs])
            lines.append(
                f"- {motion}, {variant} against {baseline}, {len(pairs)} paired seeds: {metric} lower in "
                f"{lower:.0%}, median ratio {ratio:.2f}."
            )
    return lines


def write_study(
    out: Path, command: str, study: Study, motion: str, rows: list[Row], summary: list[Row], plots: bool = True
) -> list[Path]:
    """``results.json``, ``report.md`` and the study's figure (unless ``plots`` is off), atomically."""
    config = study.config()
    seeds = sorted({row["seed"] for row in rows})
    sections = {
        "multipath": lambda: _multipath_section(summary),
        "coefficients": lambda: _coefficient_section(summary),
        "navigation": lambda: _navigation_section(summary),
        "lake": lambda: _lake_section(summary, rows),
        "facility": lambda: _facility_section(rows),
    }
    figures = {
        "coefficients": lambda: _coefficient_figure(summary),
        "navigation": lambda: _navigation_figure(summary, rows),
        "lake": lambda: _lake_figure(summary),
    }
    trajectories = pop_trajectories(rows)
    names = [save_png(figures[study.name](), out, f"{study.name}.png", DPI)] if plots and study.name in figures else []
    if plots and trajectories:
        names += write_trajectory_plots(out, trajectories, config)
    variants = [{"name": v.name, "labels": v.labels, "changes": v.changes} for v in study.variants]
    results: dict[str, Any] = {"command": command, "study": study.name, "scenario": study.scenario, "motion": motion}
    results |= {"config": to_dict(config), "variants": variants, "trials": rows, "summary": summary}
    write_results_json(out / "results.json", results)
    lines = [f"# Reference paper ablation: {study.name}", "", f"Command: `{command}`", ""]
    lines += _setup(study, motion, config, seeds) + ["", *sections[study.name]()]
    lines += [line for name in names for line in ("", f"![{name}]({name})")]
    atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
    return [out / "report.md", out / "results.json"] + [out / name for name in names]


def _model_error_figure(config: EnvConfig, samples: dict[str, np.ndarray]) -> Figure:
    xs, zs, error = model_error_map(config)
    figure = Figure(figsize=(12, 3.8))
    map_axes, rd_axes, rrd_axes = figure.subplots(1, 3, gridspec_kw={"width_ratios": [1.6, 1, 1]})
    half, cell = 0.5 * config.wavelength, 0.5 * (xs[1] - xs[0])
    extent = (xs[0] - cell, xs[-1] + cell, zs[-1] - cell, zs[0] + cell)  # zs runs down from the top row
    image = map_axes.imshow(error, origin="upper", aspect="auto", cmap="RdBu_r", vmin=-half, vmax=half, extent=extent)
    figure.colorbar(image, ax=map_axes, label="RD error, folded into one wavelength (m)")
    map_axes.set_title("linear - phasor RD, still sources in the plane y = 0", fontsize=9)
    map_axes.set_xlabel("source x (m)")
    map_axes.set_ylabel("source z (m)")
    for index, (model, label) in enumerate((("linear", "first-order (linear)"), ("none", "direct path"))):
        rd_axes.hist(samples[model][:, 0], bins=60, histtype="step", color=f"C{index}", label=label)
        rrd_axes.hist(np.clip(samples[model][:, 1], -3, 3), bins=60, histtype="step", color=f"C{index}", label=label)
    rd_axes.set_xlabel("RD error against the exact tone (m), folded")
    rd_axes.set_title("where a helix study meets it", fontsize=9)
    rd_axes.legend(fontsize=7)
    rrd_axes.set_xlabel("RRD error against the exact tone (m/s), clipped to ±3")
    figure.tight_layout()
    return figure


def _error_statistics(samples: dict[str, np.ndarray], beyond: float) -> dict[str, dict[str, float]]:
    """Per model: quantiles of the absolute RD and RRD errors, and the share of RD errors above ``beyond`` (m)."""
    stats = {}
    for model, errors in samples.items():
        entry = {f"abs_rd_error_p{q}": float(np.percentile(np.abs(errors[:, 0]), q)) for q in QUANTILES}
        entry |= {f"abs_rrd_error_p{q}": float(np.percentile(np.abs(errors[:, 1]), q)) for q in QUANTILES}
        entry["share_rd_error_beyond"] = float(np.mean(np.abs(errors[:, 0]) > beyond))
        stats[model] = entry
    return stats


def write_model_error(
    out: Path, command: str, count: int, changes: dict[str, Any] | None = None, plots: bool = True
) -> list[Path]:
    """The first-order and direct-path models' errors against the exact tone's over the shallow-water
    scenario (with ``changes`` to its fields): a map, histograms of ``count`` pairs (seed 0) and their
    quantiles, in ``report.md`` and ``results.json``."""
    config = scenario_config("shallow-water", changes)
    samples = model_error_samples(config, count, np.random.default_rng(0))
    beyond = 3 * config.measurement.range_difference_sd
    stats = _error_statistics(samples, beyond)
    out.mkdir(parents=True, exist_ok=True)
    names = [save_png(_model_error_figure(config, samples), out, "model_error.png", DPI)] if plots else []
    results = {"command": command, "samples": count, "rd_threshold": beyond, "statistics": stats}
    write_results_json(out / "results.json", results)
    lines = [
        "# Where the first-order model breaks",
        "",
        f"Command: `{command}`",
        "",
        f"Scenario `shallow-water` ({config.world.water_depth:.0f} m, a_surf {config.world.surface_reflection}, "
        f"a_bed {config.world.bed_reflection}); {count} pairs of a CV source drawn as the env draws them and the "
        "helix's hydrophone at a random time. Each model's [RD, RRD] minus the exact tone's (the phasor sums a "
        "front end measures); the RD error folded into one wavelength (a tone's RD is known modulo it).",
        "",
        "| model | RD error 50 / 90 / 99 % (m) | RRD error 50 / 90 / 99 % (m/s) | RD error above 3 sigma_R |",
        "|---|---|---|---|",
    ]
    for model, entry in stats.items():
        rd = " / ".join(f"{entry[f'abs_rd_error_p{q}']:.3f}" for q in QUANTILES)
        rrd = " / ".join(f"{entry[f'abs_rrd_error_p{q}']:.3f}" for q in QUANTILES)
        lines.append(f"| {model} | {rd} | {rrd} | {entry['share_rd_error_beyond']:.0%} |")
    lines += [
        "",
        f"3 sigma_R = {beyond:.2f} m; a folded error is at most half a wavelength, {0.5 * config.wavelength} m.",
    ]
    lines += [line for name in names for line in ("", f"![{name}]({name})")]
    atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
    return [out / "report.md", out / "results.json"] + [out / name for name in names]
