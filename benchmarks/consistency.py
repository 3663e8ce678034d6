"""Filter consistency on converged episodes: the shares of steps whose position NEES (3 dof) and NIS
(2 dof) lie within their two-sided 95 % chi-square intervals, and their means (3 and 2 expected).

    python benchmarks/consistency.py default:static:10000:10 free:static,cv:1000:10 [--out DIR]

Each WORLD:MOTIONS:FIRST_SEED:COUNT runs the helix (the filter's motion model matched to the source's;
WORLD as ``tracker_check.WORLDS``: ``signal`` is the default world as shipped) and keeps the steps after the
episode's convergence time, i.e. while the error stays below 1 m; episodes that never converge are counted and
left out. A consistent filter has about 95 % of its steps inside each interval. ``--out`` also writes the table
(``consistency.md``, with the command) and the statistics' distributions against their chi-square laws
(``consistency.png``) to DIR.
"""

from __future__ import annotations

import argparse
import json
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from scipy.stats import chi2
from tqdm import tqdm

from tracker_check import MATCHED, WORLDS, parse_runs

NEES_DOF, NIS_DOF = 3, 2
NEES_BOUNDS = chi2.ppf([0.025, 0.975], NEES_DOF)
NIS_BOUNDS = chi2.ppf([0.025, 0.975], NIS_DOF)


def episode(job: tuple) -> tuple[str, str, float, list[float], list[float]]:
    import gymnasium as gym

    import aasl_gym  # noqa: F401

    world, motion, seed = job
    env = gym.make("AASL-Helix-v0", config=WORLDS[world], source_motion=motion, filter_model=MATCHED[motion]).unwrapped
    env.reset(seed=seed)
    steps, done = [], False
    while not done:
        _, _, terminated, truncated, info = env.step(np.zeros(3))
        done = terminated or truncated
        if info["initialized"] and not info["reinitialized"]:
            error = info["estimate_position"] - info["source_position"]
            nees = float(error @ np.linalg.solve(info["position_covariance"], error))
            steps.append((info["time"], nees, env.tracker.ukf.nis))
    converged = float(info["convergence_time"])
    kept = [(nees, nis) for time, nees, nis in steps if np.isfinite(converged) and time >= converged]
    return world, motion, converged, [k[0] for k in kept], [k[1] for k in kept]


def share(values: list[float], bounds: np.ndarray) -> float:
    values = np.asarray(values)
    return float(np.mean((values >= bounds[0]) & (values <= bounds[1]))) if values.size else float("nan")


def groups(rows: list[tuple]) -> list[tuple[str, str, int, int, np.ndarray, np.ndarray]]:
    """(world, motion, converged, episodes, NEES, NIS) of each world and motion that ran, the steps pooled."""
    out = []
    for world in WORLDS:
        for motion in MATCHED:
            group = [row for row in rows if row[0] == world and row[1] == motion]
            if group:
                nees = np.array([value for row in group for value in row[3]])
                nis = np.array([value for row in group for value in row[4]])
                converged = sum(bool(np.isfinite(row[2])) for row in group)
                out.append((world, motion, converged, len(group), nees, nis))
    return out


def table(summary: list[tuple]) -> list[str]:
    """The markdown table of :func:`groups`' rows."""
    lines = [
        "| world | motion | converged | steps | NEES in 95 % interval | NEES mean (3) | NIS in 95 % interval"
        " | NIS mean (2) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for world, motion, converged, count, nees, nis in summary:
        nees_mean = f"{nees.mean():.1f}" if nees.size else "-"
        nis_mean = f"{nis.mean():.1f}" if nis.size else "-"
        lines.append(
            f"| {world} | {motion} | {converged} / {count} | {nees.size} | {share(nees, NEES_BOUNDS):.0%} | {nees_mean}"
            f" | {share(nis, NIS_BOUNDS):.0%} | {nis_mean} |"
        )
    return lines


def figure(summary: list[tuple]) -> Figure:
    """Per world, the empirical CDFs of the NEES and the NIS of each motion over their chi-square CDFs."""
    worlds = list(dict.fromkeys(row[0] for row in summary))
    fig = Figure(figsize=(9, 3.2 * len(worlds)), layout="constrained")
    axes = fig.subplots(len(worlds), 2, squeeze=False)
    for ax_row, world in zip(axes, worlds):
        for ax, column, dof, name in ((ax_row[0], 4, NEES_DOF, "position NEES"), (ax_row[1], 5, NIS_DOF, "NIS")):
            grid = np.linspace(0, chi2.ppf(0.995, dof), 200)
            ax.plot(grid, chi2.cdf(grid, dof), "k--", lw=1.5, label=f"chi-square, {dof} dof")
            for row in (r for r in summary if r[0] == world and r[column].size):
                values = np.sort(row[column])
                ax.step(values, np.arange(1, values.size + 1) / values.size, where="post", label=row[1])
            ax.axvspan(*chi2.ppf([0.025, 0.975], dof), color="0.9", zorder=0)
            ax.set(xlim=(0, grid[-1]), ylim=(0, 1), xlabel=name, ylabel="share of steps", title=f"{world}: {name}")
            ax.legend(fontsize=8, loc="lower right")
    return fig


def write_report(out: Path, summary: list[tuple]) -> None:
    from aasl_gym.io import atomic_write, atomic_write_text

    command = "python benchmarks/consistency.py " + " ".join(sys.argv[1:])
    worlds = [f"`{world}`: `{json.dumps(WORLDS[world])}`" for world in dict.fromkeys(row[0] for row in summary)]
    text = "\n".join(
        [
            f"Steps after convergence (`{command}`): the helix, the filter's motion model matched to the source's; each"
            " world the default config with these changes: " + ", ".join(worlds) + ".",
            "",
            *table(summary),
            "",
            "![Each statistic's distribution against its chi-square law, the 95 % interval shaded](consistency.png)",
        ]
    )
    atomic_write_text(out / "consistency.md", text + "\n")
    fig = figure(summary)
    atomic_write(out / "consistency.png", lambda tmp: fig.savefig(tmp, dpi=110, format="png"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="WORLD:MOTIONS:FIRST_SEED:COUNT, WORLD in " + ", ".join(WORLDS))
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--out", type=Path, help="folder for consistency.md and consistency.png")
    args = parser.parse_args()
    if args.workers < 1:
        parser.error(f"--workers {args.workers}: at least 1")
    jobs = parse_runs(args.runs)
    with Pool(args.workers) as pool:
        rows = list(tqdm(pool.imap(episode, jobs, chunksize=1), total=len(jobs), unit="ep", leave=False))
    summary = groups(rows)
    print("\n".join(table(summary)))
    if args.out is not None:
        write_report(args.out, summary)
        print(f"wrote {args.out / 'consistency.md'} and {args.out / 'consistency.png'}")


if __name__ == "__main__":
    main()
