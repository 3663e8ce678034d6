"""Scripted patrol patterns centred on the fixed hydrophone.

Each pattern is a reference path ``p_ref(t)`` with its velocity ``v_ref(t)``; the robot follows it with
``command = v_ref + gain * (p_ref - p)`` (m/s), so it is pulled onto the pattern from wherever it starts.
Depths in :class:`~aasl_gym.config.PatrolConfig` are positive numbers of metres below the surface.

* ``helix``: circle of ``radius`` in plan view at ``speed`` (horizontal), depth oscillating
  sinusoidally between ``depth_min`` and ``depth_max`` with period ``depth_period``.
* ``circle``: the same circle at the mid depth.
* ``spiral``: radius going linearly out from ``spiral_radius_min`` to ``spiral_radius_max`` and back
  (period ``spiral_period``) at constant tangential ``speed`` and ``spiral_depth``.
* ``square``: the square of half-side ``radius`` about the centre (the circle's circumscribed square), at
  the mid depth, counter-clockwise at ``speed`` from the point of it nearest the robot's start.
* ``lawnmower``: back-and-forth legs ``lawnmower_spacing`` apart across a square of side
  ``lawnmower_width``, at the mid depth, travelled forth and back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aasl_gym.config import EnvConfig, PatrolConfig


@dataclass(frozen=True)
class PatrolGeometry:
    """Where a pattern is anchored: its centre (the fixed hydrophone) and the robot's start."""

    centre: np.ndarray  # (3,) m
    start: np.ndarray  # (3,) m

    @classmethod
    def from_config(cls, config: EnvConfig) -> PatrolGeometry:
        """Centred on the fixed hydrophone, from where the robot starts."""
        return cls(
            np.asarray(config.world.fixed_position, dtype=float),
            np.asarray(config.receiver.start_position, dtype=float),
        )

    @property
    def start_angle(self) -> float:
        return math.atan2(self.start[1] - self.centre[1], self.start[0] - self.centre[0])

    @property
    def start_radius(self) -> float:
        return math.hypot(self.start[0] - self.centre[0], self.start[1] - self.centre[1])


def _on_circle(geometry: PatrolGeometry, radius: float, angle: float, angular_rate: float, z: float, vz: float):
    c, s = math.cos(angle), math.sin(angle)
    position = np.array([geometry.centre[0] + radius * c, geometry.centre[1] + radius * s, z])
    velocity = np.array([-radius * angular_rate * s, radius * angular_rate * c, vz])
    return position, velocity


def helix_reference(t: float, config: PatrolConfig, geometry: PatrolGeometry, oscillate: bool = True):
    mid = 0.5 * (config.depth_min + config.depth_max)
    amplitude = 0.5 * (config.depth_max - config.depth_min) if oscillate else 0.0
    omega_z = 2 * math.pi / config.depth_period
    z = -(mid + amplitude * math.sin(omega_z * t))
    vz = -amplitude * omega_z * math.cos(omega_z * t)
    angular_rate = config.speed / config.radius
    return _on_circle(geometry, config.radius, geometry.start_angle + angular_rate * t, angular_rate, z, vz)


def circle_reference(t: float, config: PatrolConfig, geometry: PatrolGeometry):
    return helix_reference(t, config, geometry, oscillate=False)


def spiral_reference(t: float, config: PatrolConfig, geometry: PatrolGeometry):
    r_min, r_max = config.spiral_radius_min, config.spiral_radius_max
    half = 0.5 * config.spiral_period
    slope = (r_max - r_min) / half  # m/s, radial speed
    sweep = config.speed / slope * math.log(r_max / r_min)  # rad turned on one leg
    r_start = min(max(geometry.start_radius, r_min), r_max)

    def radius_and_angle(u: float) -> tuple[float, float, float]:
        leg, within = divmod(u, half)
        rising = int(leg) % 2 == 0
        r = r_min + slope * within if rising else r_max - slope * within
        partial = math.log(r / r_min) if rising else math.log(r_max / r)
        return r, leg * sweep + config.speed / slope * partial, (slope if rising else -slope)

    offset = (r_start - r_min) / slope
    _, angle0, _ = radius_and_angle(offset)
    r, angle, radial_rate = radius_and_angle(t + offset)
    angle = geometry.start_angle + angle - angle0
    position, velocity = _on_circle(geometry, r, angle, config.speed / r, -config.spiral_depth, 0.0)
    velocity[:2] += radial_rate * (position[:2] - geometry.centre[:2]) / r
    return position, velocity


def lawnmower_waypoints(config: PatrolConfig, geometry: PatrolGeometry) -> np.ndarray:
    half = 0.5 * config.lawnmower_width
    legs = max(2, int(config.lawnmower_width // config.lawnmower_spacing) + 1)
    ys = np.linspace(-half, half, legs)
    depth = -0.5 * (config.depth_min + config.depth_max)
    points = []
    for i, y in enumerate(ys):
        xs = (-half, half) if i % 2 == 0 else (half, -half)
        points += [(xs[0], y), (xs[1], y)]
    return np.array([[geometry.centre[0] + x, geometry.centre[1] + y, depth] for x, y in points])


def _along_polyline(waypoints: np.ndarray, distance: float) -> tuple[np.ndarray, np.ndarray]:
    """The point (m) ``distance`` m along the polyline through ``waypoints`` (N, 3) and its unit tangent."""
    segments = np.diff(waypoints, axis=0)
    lengths = np.linalg.norm(segments, axis=1)
    index = min(int(np.searchsorted(np.cumsum(lengths), distance, side="right")), len(lengths) - 1)
    along = distance - (np.cumsum(lengths)[index] - lengths[index])
    tangent = segments[index] / lengths[index]
    return waypoints[index] + along * tangent, tangent


def _distance_along_nearest(waypoints: np.ndarray, point: np.ndarray) -> float:
    """How far (m) along the polyline through ``waypoints`` (N, 3) its point nearest ``point`` lies, in plan view."""
    best, best_distance, travelled = math.inf, 0.0, 0.0
    for start, end in zip(waypoints[:-1, :2], waypoints[1:, :2]):
        segment = end - start
        length = float(np.linalg.norm(segment))
        along = float(np.clip((point[:2] - start) @ segment / length**2, 0.0, 1.0)) * length
        gap = float(np.linalg.norm(start + along * segment / length - point[:2]))
        if gap < best:
            best, best_distance = gap, travelled + along
        travelled += length
    return best_distance


def lawnmower_reference(t: float, config: PatrolConfig, geometry: PatrolGeometry):
    waypoints = lawnmower_waypoints(config, geometry)
    total = np.linalg.norm(np.diff(waypoints, axis=0), axis=1).sum()
    travelled = (config.speed * t) % (2 * total)
    direction = 1.0
    if travelled > total:  # on the way back
        travelled, direction = 2 * total - travelled, -1.0
    point, tangent = _along_polyline(waypoints, travelled)
    return point, direction * config.speed * tangent


def square_waypoints(config: PatrolConfig, geometry: PatrolGeometry) -> np.ndarray:
    """The square's corners counter-clockwise from (+r, -r), closed (5, 3; m), ``r`` = ``config.radius``."""
    half, depth = config.radius, -0.5 * (config.depth_min + config.depth_max)
    corners = [(half, -half), (half, half), (-half, half), (-half, -half), (half, -half)]
    return np.array([[geometry.centre[0] + x, geometry.centre[1] + y, depth] for x, y in corners])


def square_reference(t: float, config: PatrolConfig, geometry: PatrolGeometry):
    waypoints = square_waypoints(config, geometry)
    perimeter = 8.0 * config.radius
    start = _distance_along_nearest(waypoints, geometry.start)
    point, tangent = _along_polyline(waypoints, (start + config.speed * t) % perimeter)
    return point, config.speed * tangent


REFERENCES = {
    "helix": helix_reference,
    "circle": circle_reference,
    "spiral": spiral_reference,
    "lawnmower": lawnmower_reference,
    "square": square_reference,
}


def patrol_command(
    pattern: str, t: float, position: np.ndarray, config: PatrolConfig, geometry: PatrolGeometry
) -> np.ndarray:
    """Velocity command (m/s) that follows ``pattern`` from the robot's (reported) ``position`` at time ``t``."""
    try:
        reference = REFERENCES[pattern]
    except KeyError:
        raise ValueError(f"unknown patrol pattern {pattern!r}; allowed: {sorted(REFERENCES)}") from None
    target, feedforward = reference(t, config, geometry)
    return feedforward + config.position_gain * (target - position)
