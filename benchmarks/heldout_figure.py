"""Issue 12's point 1 at a glance: on each held-out free-field set, the tracker's success at 1 m beside the exact MAP's
share and an efficient estimator's, per motion, with the issue's bar.

    python benchmarks/heldout_figure.py [--out reports/tracker/point1_heldout.png]

Reads what the committed runs wrote: each set's ``crb_bound.md`` (``crb_bound.py --target 1.0``: the efficient
estimator's mean share and its count's 90 % range, and with ``--tracker --oracle`` the tracker's success and the whole
track's MAP fit from the truth) and, where there is one, its ``results.json`` (the tracker, ``evaluate.py``; it takes
precedence over the table's tracker column). A motion whose table has no oracle column shows no MAP bar; a panel
shows the sets that ran its motion (the CV-only sets add to the CV panel).
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from aasl_gym.io import atomic_write

SETS = {  # folder under reports/tracker -> its seeds
    "heldout_free": "700000-700099",
    "heldout_free_740000": "740000-740099",
    "heldout_free_760000": "760000-760099",
    "heldout_free_cv_730000": "730000-730099",  # CV only, crb_bound.py --tracker --oracle (session 49)
    "heldout_free_cv_750000": "750000-750099",
    "heldout_free_cv_770000": "770000-770099",
    "heldout_free_cv_780000": "780000-780099",
}
MOTIONS = ("static", "cv", "ca", "ctrv")
BARS = {"static": 98, "cv": 95, "ca": 50, "ctrv": 95}  # % at 1 m, issue 12 point 1
TARGET = 1.0  # m


def tracker_success(folder: Path, bounds: dict[str, dict[str, float]]) -> dict[str, float]:
    """The tracker's success at ``TARGET`` (%) per motion, from the run's ``results.json`` where it has one, else from
    the tracker column of its bound table, ``bounds`` (:func:`bound_rows`, read once by the caller)."""
    if not (folder / "results.json").is_file():
        return {motion: row["tracker"] for motion, row in bounds.items() if "tracker" in row}
    summary = json.loads((folder / "results.json").read_text())["summary"]
    return {row["motion"]: 100 * row["success_rate"][str(TARGET)] for row in summary}


def bound_rows(folder: Path) -> dict[str, dict[str, float]]:
    """Per motion, from the last table of ``crb_bound.md`` at ``TARGET`` with a row for it: the episodes, the efficient
    estimator's share and its count's 90 % range (%), and the tracker's and the exact MAP's shares (%) where the table
    has their columns."""
    rows: dict[str, dict[str, float]] = {}
    target = None
    for line in (folder / "crb_bound.md").read_text().splitlines():
        if line.startswith("| motion"):
            found = re.search(r"bound < ([0-9.]+) m", line)
            target = float(found.group(1)) if found else None
            continue
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if target != TARGET or not cells or cells[0] not in MOTIONS:
            continue
        low, high = (float(x) for x in cells[5].split("-"))
        row = rows[cells[0]] = {"episodes": float(cells[1])}
        row.update(efficient=float(cells[4].rstrip("%")), low=low, high=high)
        if len(cells) >= 7:
            row["tracker"] = float(cells[6].rstrip("%"))
        if len(cells) >= 10:
            row["map"] = float(cells[9].rstrip("%"))
    return rows


def missing_sets(root: Path) -> list[str]:
    """The held-out sets (:data:`SETS`) with no ``crb_bound.md`` under ``root``."""
    return [name for name in SETS if not (root / name / "crb_bound.md").is_file()]


def figure(root: Path) -> Figure:
    """One panel per motion: per held-out set under ``root`` that ran it, the tracker's, the exact MAP's and an
    efficient estimator's success at ``TARGET``, and the issue's bar."""
    bounds = {name: bound_rows(root / name) for name in SETS}
    sets = {name: (tracker_success(root / name, bounds[name]), bounds[name]) for name in SETS}
    shown = {motion: [name for name, (_, bounds) in sets.items() if motion in bounds] for motion in MOTIONS}
    fig = Figure(figsize=(14, 3.4))
    axes = fig.subplots(1, len(MOTIONS), sharey=False, width_ratios=[max(len(shown[m]), 3) for m in MOTIONS])
    width = 0.26
    for ax, motion in zip(axes, MOTIONS):
        for i, name in enumerate(shown[motion]):
            tracker, bounds = sets[name]
            bound = bounds[motion]
            first = i == 0  # one legend entry per kind of bar
            ax.bar(i - width, tracker.get(motion, np.nan), width, color="tab:blue", label="tracker" if first else None)
            exact = bound.get("map", np.nan)
            ax.bar(i, exact, width, color="tab:orange", label="exact MAP (from the truth)" if first else None)
            error = [[bound["efficient"] - bound["low"]], [bound["high"] - bound["efficient"]]]
            ax.bar(i + width, bound["efficient"], width, yerr=error, color="tab:gray", capsize=3,
                   label="efficient estimator (90 % range)" if first else None)  # fmt: skip
        ax.axhline(BARS[motion], color="k", linestyle="--", linewidth=1, label="issue's bar")
        ax.set_xticks(range(len(shown[motion])), [SETS[name].split("-")[0] for name in shown[motion]])
        ax.set_title(motion.upper() if motion != "static" else "static")
        ax.set_ylim(85 if BARS[motion] >= 90 else 40, 101)  # a few points decide the high bars
        ax.set_xlabel("held-out seeds from")
        ax.tick_params(axis="x", labelsize=8)
    axes[0].set_ylabel(f"success at {TARGET:g} m (%)")
    fig.suptitle("Issue 12, point 1: free field, helix, LC-MAP, matched filter - 100 episodes per set and motion")
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.legend(*axes[1].get_legend_handles_labels(), loc="lower center", ncol=4, fontsize=8)
    return fig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--root", type=Path, default=Path("reports/tracker"), help="folder holding the held-out sets")
    parser.add_argument("--out", type=Path, default=Path("reports/tracker/point1_heldout.png"))
    args = parser.parse_args()
    if missing := missing_sets(args.root):
        raise SystemExit(f"--root {args.root}: no crb_bound.md in {missing}; run the held-out sets first (README)")
    fig = figure(args.root)
    atomic_write(args.out, lambda tmp: fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png"))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
