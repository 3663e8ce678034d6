"""A study's figures, each written atomically as PNG: convergence times and success shares per
combination and motion, and the recorded episodes' paths in top and depth views."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from aasl_gym.config import EnvConfig
from aasl_gym.facility import pod_hydrophones
from aasl_gym.io import atomic_write
from aasl_gym.metrics import SUCCESS_THRESHOLDS
from aasl_gym.render import draw_episode
from aasl_gym.study.jobs import MOTIONS
from aasl_gym.study.log import Row

Trajectory = tuple[str, str, int, dict]  # policy, motion, seed, the episode's paths by name


def _motion_order(motion: str) -> int:
    return MOTIONS.index(motion) if motion in MOTIONS else 99


def save_png(figure: Figure, out: Path, name: str, dpi: int) -> str:
    """Write ``figure`` to ``out/name`` atomically; returns ``name``."""
    atomic_write(out / name, lambda tmp: figure.savefig(tmp, dpi=dpi, bbox_inches="tight", format="png"))
    return name


def pop_trajectories(rows: list[Row]) -> list[Trajectory]:
    """Take the recorded paths out of the rows (they go into the plots, not the results)."""
    return [(row["policy"], row["motion"], row["seed"], row.pop("trajectory")) for row in rows if "trajectory" in row]


def write_plots(out: Path, rows: list[Row], summary: list[Row]) -> list[str]:
    """The convergence-time boxes and the success-against-threshold curves; returns their file names."""
    groups = sorted({(s["policy"], s["initializer"]) for s in summary}, key=str)
    motions = sorted({s["motion"] for s in summary}, key=_motion_order)
    return [
        save_png(_convergence_boxes(rows, groups, motions), out, "convergence_time.png", 110),
        save_png(_success_curves(summary, groups, motions), out, "success_vs_threshold.png", 110),
    ]


def _convergence_boxes(rows: list[Row], groups: list[tuple[str, str]], motions: list[str]) -> Figure:
    figure = Figure(figsize=(max(6, 2.2 * len(motions)), 4))
    ax = figure.subplots()
    width = 0.8 / max(1, len(groups))
    for g, (policy, initializer) in enumerate(groups):
        data = [
            [
                r["convergence_time"]
                for r in rows
                if (r["policy"], r["initializer"], r["motion"]) == (policy, initializer, m)
                and r["convergence_time"] is not None
            ]
            for m in motions
        ]
        positions = np.arange(len(motions)) + (g - (len(groups) - 1) / 2) * width
        filled = [d if d else [np.nan] for d in data]
        parts = ax.boxplot(filled, positions=positions, widths=width * 0.9, patch_artist=True, manage_ticks=False)
        colour = f"C{g}"
        for box in parts["boxes"]:
            box.set_facecolor(colour)
            box.set_alpha(0.6)
        ax.plot([], [], color=colour, lw=6, alpha=0.6, label=f"{policy} / {initializer}")
    ax.set_xticks(np.arange(len(motions)), motions)
    ax.set_ylabel("convergence time to 1 m (s), converged episodes")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # outside: boxes fill the axes
    ax.grid(alpha=0.3)
    return figure


def _success_curves(summary: list[Row], groups: list[tuple[str, str]], motions: list[str]) -> Figure:
    figure = Figure(figsize=(max(6, 3 * len(motions)), 3.5))
    axes = np.atleast_1d(figure.subplots(1, len(motions), sharey=True))
    thresholds = [str(float(t)) for t in SUCCESS_THRESHOLDS]
    for ax, motion in zip(axes, motions):
        for g, (policy, initializer) in enumerate(groups):
            match = [
                s for s in summary if (s["policy"], s["initializer"], s["motion"]) == (policy, initializer, motion)
            ]
            if match:
                ax.plot(
                    SUCCESS_THRESHOLDS,
                    [match[0]["success_rate"][t] for t in thresholds],
                    "o-",
                    color=f"C{g}",
                    label=f"{policy} / {initializer}",
                )
        ax.set_xscale("log")
        ax.set_xticks(SUCCESS_THRESHOLDS, [f"{t:g}" for t in SUCCESS_THRESHOLDS])
        ax.set_title(motion)
        ax.set_xlabel("threshold (m)")
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("success rate within the episode")
    axes[-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    return figure


def write_trajectory_plots(out: Path, trajectories: list[Trajectory], config: EnvConfig) -> list[str]:
    """One figure per motion: for each recorded episode (policy, seed) the top and depth views of the
    robot's path, the source's and the estimate's (:func:`aasl_gym.render.draw_episode`)."""
    names = []
    fixed = pod_hydrophones(config.facility, config.world.fixed_position)  # one row but in a facility
    for motion in sorted({t[1] for t in trajectories}, key=_motion_order):
        episodes = sorted((t for t in trajectories if t[1] == motion), key=lambda t: (t[0], t[2]))
        figure = Figure(figsize=(10, 4.2 * len(episodes)))
        # subfigures() returns a lone SubFigure for one episode; its stubs do not let atleast_1d take it.
        panels = np.atleast_1d(figure.subfigures(len(episodes), 1))  # type: ignore[arg-type]
        for panel, (policy, _, seed, paths) in zip(panels, episodes):
            draw_episode(
                panel,
                paths,
                fixed,
                None,
                config.episode.duration,
                config,
                title=f"{policy}, {motion} source, seed {seed}",
            )
        names.append(save_png(figure, out, f"trajectories_{motion}.png", 80))
    return names
