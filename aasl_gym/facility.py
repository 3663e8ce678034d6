"""The multi-pod facility's layout (issue 15): where its pods' hydrophones stand and the loop the robot
patrols before an attack is heard. The env that runs it is :mod:`aasl_gym.facility_env`.

The pods stand on a grid of ``rows`` rows and ceil(pods / rows) columns, ``spacing`` metres apart (the
last row holds what is left, centred), the grid centred on ``world.fixed_position``, every hydrophone at
its depth. The loop is a circle about the same centre, ``loop_margin`` outside the outermost hydrophone.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from aasl_gym.config import FacilityConfig


def pod_hydrophones(facility: FacilityConfig, centre: tuple[float, float, float] | np.ndarray) -> np.ndarray:
    """The pods' hydrophones (pods, 3; m), row by row, the grid centred on ``centre`` (m)."""
    columns = math.ceil(facility.pods / facility.rows)
    rows = []
    for row in range(facility.rows):
        count = min(columns, facility.pods - row * columns)
        if count <= 0:
            break
        xs = (np.arange(count) - 0.5 * (count - 1)) * facility.spacing
        y = (row - 0.5 * (facility.rows - 1)) * facility.spacing
        rows += [[x, y, 0.0] for x in xs]
    return np.asarray(centre, dtype=float) + np.array(rows)


def loop_radius(facility: FacilityConfig, hydrophones: np.ndarray) -> float:
    """Radius (m) of the patrol loop about the hydrophones' centre: ``loop_margin`` beyond the farthest."""
    offsets = hydrophones[:, :2] - hydrophones[:, :2].mean(axis=0)
    return float(np.max(np.hypot(offsets[:, 0], offsets[:, 1]))) + facility.loop_margin
