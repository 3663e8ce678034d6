"""Top and depth views of an episode with matplotlib.

``rgb_array`` draws on an Agg canvas through the object-oriented API (no pyplot, no GUI backend), so it
works headless; ``human`` opens a pyplot window with whatever backend the user has configured.
"""

from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse

from aasl_gym.config import EnvConfig

COLOURS = {"receiver": "tab:blue", "source": "tab:red", "estimate": "tab:green", "fixed": "black"}


def covariance_ellipse(
    covariance: np.ndarray, axes: tuple[int, int], centre: np.ndarray, sigmas: float = 2.0, **style
) -> Ellipse:
    """The ``sigmas``-sigma ellipse of the 2-D marginal of a 3x3 position covariance."""
    block = covariance[np.ix_(axes, axes)]
    values, vectors = np.linalg.eigh(block)
    values = np.maximum(values, 0.0)
    angle = np.degrees(np.arctan2(vectors[1, 1], vectors[0, 1]))
    width, height = 2 * sigmas * np.sqrt(values[1]), 2 * sigmas * np.sqrt(values[0])
    return Ellipse((centre[axes[0]], centre[axes[1]]), width, height, angle=angle, **style)


def draw_episode(
    figure: Figure,
    trajectory: dict[str, list[np.ndarray]],
    fixed: np.ndarray,
    covariance: np.ndarray | None,
    time: float,
    config: EnvConfig,
    title: str | None = None,
) -> None:
    """Top view (x-y) and depth view (x-z) of the robot, source and estimate paths; ``fixed`` is the pod's
    hydrophone (3,) or a facility's (N, 3)."""
    figure.clear()
    top, side = figure.subplots(1, 2)
    limit = max(
        config.world.region_radius, config.receiver.region_radius
    )  # the robot may roam beyond the source's region
    for ax, (i, j), labels in ((top, (0, 1), ("x (m)", "y (m)")), (side, (0, 2), ("x (m)", "z (m)"))):
        for name in ("receiver", "source", "estimate"):
            points = np.asarray(trajectory.get(name, []))
            if len(points):
                ax.plot(points[:, i], points[:, j], color=COLOURS[name], lw=1, label=name)
                ax.plot(points[-1, i], points[-1, j], "o", color=COLOURS[name], ms=4)
        pods = np.atleast_2d(fixed)
        ax.plot(pods[:, i], pods[:, j], "s", color=COLOURS["fixed"], ms=6, label="pod" if len(pods) == 1 else "pods")
        estimate = trajectory.get("estimate") or []
        if covariance is not None and len(estimate) and np.all(np.isfinite(covariance)):
            ax.add_patch(
                covariance_ellipse(covariance, (i, j), estimate[-1], fill=False, color=COLOURS["estimate"], ls="--")
            )
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
        ax.set_xlim(-limit, limit)
        ax.grid(alpha=0.3)
    top.set_ylim(-limit, limit)
    top.set_aspect("equal")
    side.set_ylim(-config.world.water_depth, 0)
    side.axhline(0, color="steelblue", lw=0.8)
    top.set_title("top view")
    side.set_title("depth view")
    top.legend(loc="upper right", fontsize=7)
    figure.suptitle(title or f"t = {time:.1f} s")


class Renderer:
    def __init__(self, config: EnvConfig, human: bool = False):
        self.config = config
        self.human = human
        if human:
            import matplotlib.pyplot as plt

            self._plt = plt
            plt.ion()
            self.figure = plt.figure(figsize=(10, 4.5))
        else:
            self.figure = Figure(figsize=(10, 4.5), dpi=80)
            self.canvas = FigureCanvasAgg(self.figure)

    def draw(self, trajectory, fixed, covariance, time):
        draw_episode(self.figure, trajectory, fixed, covariance, time, self.config)
        if self.human:
            self.figure.canvas.draw_idle()
            self._plt.pause(0.001)
            return None
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()

    def close(self):
        if self.human:
            self._plt.close(self.figure)
