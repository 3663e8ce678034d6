"""Truth motion of the source, kinematics of the robot, and the robot's navigation error.

Source motions (SPEC section 5): static, constant velocity (CV), constant acceleration (CA, speed capped
at ``max_speed``) and constant turn rate and velocity (CTRV, a horizontal coordinated turn); and the lake
trial's U-turn (``uturn``: straight, then a horizontal half-turn at a constant rate, then straight back
along a parallel line ``2 |v_h| / |omega|`` to the side, v_h the horizontal velocity). A source with
``source.depth`` set is held at that depth (hung from a vessel): it starts where a free one would in plan
view (so not uniformly over the disc: the ball's projection is densest at its centre) and moves
horizontally. A path is held to ``source.keep_within`` at samples :data:`PATH_CHECK_STEP` apart. Each follows
its model exactly, except that surface and bed (less a margin) reflect it specularly. A fast source can
therefore leave the surveillance region within an episode (1.5 m/s for 120 s is 180 m); with
``source.confined`` it reflects at the region's edge too - a loitering attacker, but no longer the
named motion model whenever it bounces.
All positions in metres, velocities in m/s, accelerations in m/s^2, turn rates in rad/s.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from aasl_gym.config import ReceiverConfig, SourceConfig, WorldConfig
from aasl_gym.geometry import vector_norm

MOTION_KINDS = ("static", "cv", "ca", "ctrv")


@dataclass(frozen=True)
class SourceState:
    kind: str  # static, cv, ca, ctrv
    position: np.ndarray  # m
    velocity: np.ndarray  # m/s
    acceleration: np.ndarray  # m/s^2 (ca only; zero otherwise)
    turn_rate: float  # rad/s about z (ctrv, uturn)
    max_speed: float  # m/s
    turn_start: float = 0.0  # s until a uturn's half-turn begins (counts down)
    turn_left: float = 0.0  # s of a uturn's half-turn still to fly (pi / |turn_rate| before it begins)


@dataclass(frozen=True)
class Box:
    """The region a body must stay in: a vertical cylinder ``|p_xy| <= radius``, ``z_min <= z <= z_max``."""

    radius: float
    z_min: float
    z_max: float

    def towards_middle(self, z: float) -> float:
        """-1 (down) from a depth ``z`` (m) at or above the middle of the box's depths, +1 (up) from below it."""
        return -1.0 if z >= 0.5 * (self.z_min + self.z_max) else 1.0


def source_region(world: WorldConfig, source: SourceConfig) -> Box:
    """Where a source may start (and where plausible initial estimates lie)."""
    margin = source.boundary_margin
    return Box(world.region_radius - margin, -world.water_depth + margin, -margin)


def motion_region(world: WorldConfig, source: SourceConfig) -> Box:
    """The bounds a moving source reflects at: the water column, and the region's edge if confined."""
    region = source_region(world, source)
    return region if source.confined else replace(region, radius=np.inf)


def sample_initial_position(rng: np.random.Generator, radius: float, region: Box, centre: np.ndarray) -> np.ndarray:
    """Uniform in the ball of ``radius`` (m) about ``centre`` (m), restricted to ``region`` (rejection sampling)."""
    while True:
        offset = rng.uniform(-radius, radius, size=3)
        point = centre + offset
        if (
            offset @ offset <= radius**2
            and region.z_min <= point[2] <= region.z_max
            and np.hypot(point[0], point[1]) <= region.radius
        ):
            return point


def _direction_velocity(rng: np.random.Generator, speed: float, max_vertical_speed: float) -> np.ndarray:
    heading = rng.uniform(-np.pi, np.pi)
    vertical = rng.uniform(-1.0, 1.0) * min(max_vertical_speed, speed)
    horizontal = np.sqrt(speed**2 - vertical**2)
    return np.array([horizontal * np.cos(heading), horizontal * np.sin(heading), vertical])


PATH_CHECK_STEP = 0.5  # s between the points at which a drawn path is held to source.keep_within
PATH_DRAWS = 1000  # draws before a source.keep_within that no path meets is reported


def sample_source(
    rng: np.random.Generator, kind: str, source: SourceConfig, world: WorldConfig, duration: float = 0.0
) -> SourceState:
    """Draw a source motion of ``kind`` (``mixed`` draws one of the four of :data:`MOTION_KINDS`) with seeded
    random parameters; with ``source.keep_within`` set, a moving source is redrawn until its path over the
    ``duration`` (s) of the episode keeps that close to ``source.initial_centre`` horizontally."""
    if kind == "mixed":
        kind = MOTION_KINDS[int(rng.integers(len(MOTION_KINDS)))]
    for _ in range(PATH_DRAWS):
        state = _draw_source(rng, kind, source, world)
        if source.keep_within is None or _keeps_within(state, source, world, duration):
            return state
    raise ValueError(
        f"no {kind} path drawn in {PATH_DRAWS} tries kept within source.keep_within = {source.keep_within} m for "
        f"{duration} s: lower source.speed_range or raise keep_within"
    )


def _keeps_within(state: SourceState, source: SourceConfig, world: WorldConfig, duration: float) -> bool:
    centre, region = np.asarray(source.initial_centre[:2]), motion_region(world, source)
    for _ in range(int(np.ceil(duration / PATH_CHECK_STEP)) + 1):
        if np.hypot(*(state.position[:2] - centre)) > source.keep_within:
            return False
        state = advance_source(state, PATH_CHECK_STEP, region)
    return True


def _draw_source(rng: np.random.Generator, kind: str, source: SourceConfig, world: WorldConfig) -> SourceState:
    region = source_region(world, source)
    position = sample_initial_position(rng, source.initial_radius, region, np.asarray(source.initial_centre))
    depth = source.depth
    if depth is not None:  # held there: it moves horizontally
        position[2] = -depth
    zero = np.zeros(3)
    if kind == "static":
        return SourceState(kind, position, zero, zero, 0.0, source.max_speed)
    speed = rng.uniform(*source.speed_range)
    velocity = _direction_velocity(rng, speed, source.max_vertical_speed if depth is None else 0.0)
    acceleration = zero
    turn_rate = 0.0
    if kind == "ca":
        acceleration = _direction_velocity(rng, rng.uniform(*source.acceleration_range), 0.0)
    elif kind in ("ctrv", "uturn"):
        turn_rate = rng.choice([-1.0, 1.0]) * rng.uniform(*source.turn_rate_range)
    elif kind != "cv":
        raise ValueError(f"unknown source motion {kind!r}; allowed: {list(MOTION_KINDS) + ['uturn', 'mixed']}")
    if kind == "uturn":
        start, half_turn = rng.uniform(*source.uturn_start_range), np.pi / abs(turn_rate)
        return SourceState(kind, position, velocity, acceleration, turn_rate, source.max_speed, start, half_turn)
    return SourceState(kind, position, velocity, acceleration, turn_rate, source.max_speed)


def small_angle_series(small: np.ndarray, closed, series, *arguments) -> np.ndarray:
    """``closed`` (the closed form: floats of ``small``'s shape) with ``series(*arguments)`` where ``small``, as a
    fresh float64 array: the arguments, broadcast to that shape, taken at the small angles alone. ``np.where``
    would evaluate the series - its powers are the slowest of NumPy's calls here - at every angle and throw most of
    it away. One angle (0-d) takes ``np.where`` as before: NumPy's scalar power is another routine than its array
    power."""
    if small.ndim == 0:
        return np.where(small, series(*arguments), closed)
    closed = np.array(closed, dtype=float)
    if small.any():
        closed[small] = series(*(np.broadcast_to(argument, small.shape)[small] for argument in arguments))
    return closed


def coordinated_turn_displacement(
    velocity: np.ndarray, turn_rate: np.ndarray | float, dt: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """Exact displacement (m) and final velocity (m/s) over ``dt`` of a horizontal turn at ``turn_rate``.

    Broadcasts over leading dimensions of ``velocity`` (``(..., 3)``) and ``turn_rate`` (``(...)``).
    Uses the series of sin(w dt)/w and (1 - cos(w dt))/w near w = 0, where the closed form loses digits.
    """
    angle = np.asarray(turn_rate) * dt
    small = np.abs(angle) < 1e-4
    safe = np.where(small, 1.0, angle)
    cos_a, sin_a = np.cos(angle), np.sin(angle)  # where the closed form is taken, the angle is ``safe``'s
    sin_term = small_angle_series(small, sin_a / safe * dt, lambda a, t: t * (1 - a**2 / 6), angle, dt)
    cos_term = small_angle_series(small, (1 - cos_a) / safe * dt, lambda a, t: t * (a / 2 - a**3 / 24), angle, dt)
    vx, vy, vz = velocity[..., 0], velocity[..., 1], velocity[..., 2]
    displacement = np.stack([sin_term * vx - cos_term * vy, cos_term * vx + sin_term * vy, vz * dt], axis=-1)
    new_velocity = np.stack([cos_a * vx - sin_a * vy, sin_a * vx + cos_a * vy, vz], axis=-1)
    return displacement, new_velocity


def _reflect(position: np.ndarray, velocity: np.ndarray, acceleration: np.ndarray, region: Box):
    position, velocity, acceleration = position.copy(), velocity.copy(), acceleration.copy()
    for bound, side in ((region.z_max, 1.0), (region.z_min, -1.0)):
        if side * (position[2] - bound) > 0:
            position[2] = 2 * bound - position[2]
            velocity[2] = -velocity[2]
            acceleration[2] = -acceleration[2]
    horizontal = np.hypot(position[0], position[1])
    if np.isfinite(region.radius) and horizontal > region.radius:
        normal = np.array([position[0], position[1], 0.0]) / horizontal
        position[:2] *= (2 * region.radius - horizontal) / horizontal
        velocity -= 2 * (velocity @ normal) * normal
        acceleration -= 2 * (acceleration @ normal) * normal
    return position, velocity, acceleration


def advance_source(state: SourceState, dt: float, region: Box) -> SourceState:
    """The source ``dt`` seconds later (exact within the model, specular reflection at ``region``'s bounds)."""
    if state.kind == "static":
        return state
    if state.kind == "uturn":
        return _advance_uturn(state, dt, region)
    position, velocity, acceleration = state.position, state.velocity, state.acceleration
    if state.kind == "ctrv":
        displacement, velocity = coordinated_turn_displacement(velocity, state.turn_rate, dt)
        position = position + displacement
    else:
        position = position + velocity * dt + 0.5 * acceleration * dt**2
        velocity = velocity + acceleration * dt
        if state.kind == "ca" and (speed := vector_norm(velocity)) > state.max_speed:
            velocity = velocity * (state.max_speed / speed)
            acceleration = np.zeros(3)
    position, velocity, acceleration = _reflect(position, velocity, acceleration, region)
    return replace(state, position=position, velocity=velocity, acceleration=acceleration)


def _advance_uturn(state: SourceState, dt: float, region: Box) -> SourceState:
    """A U-turn ``dt`` s on: straight until its half-turn begins, the turn, straight again (a step may hold all)."""
    position, velocity = state.position, state.velocity
    straight = min(dt, state.turn_start)
    position = position + velocity * straight
    turning = min(dt - straight, state.turn_left)
    if turning > 0:
        displacement, velocity = coordinated_turn_displacement(velocity, state.turn_rate, turning)
        position = position + displacement
    position = position + velocity * (dt - straight - turning)
    position, velocity, _ = _reflect(position, velocity, np.zeros(3), region)
    return replace(
        state,
        position=position,
        velocity=velocity,
        turn_start=state.turn_start - straight,
        turn_left=state.turn_left - turning,
    )


def receiver_region(world: WorldConfig, receiver: ReceiverConfig) -> Box:
    return Box(receiver.region_radius, -world.water_depth + receiver.bed_clearance, -receiver.min_depth)


def move_receiver(
    position: np.ndarray,
    command: np.ndarray,
    dt: float,
    max_speed: float,
    region: Box,
    keep_out_centre: np.ndarray,
    keep_out_radius: float,
    surface_depth: float | None = None,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Apply a velocity command (m/s) for ``dt`` seconds.

    The command's norm is clipped to ``max_speed``; a surface vessel (``surface_depth`` given) ignores z
    and holds its hydrophone at that depth. The new position is projected back into ``region`` and out
    of the keep-out sphere (a surface vessel horizontally, at its depth). Returns the new position, the
    velocity actually achieved and whether a limit was hit.
    """
    command = np.asarray(command, dtype=float)
    if surface_depth is not None:
        command = np.array([command[0], command[1], 0.0])
    speed = vector_norm(command)
    if speed > max_speed:
        command = command * (max_speed / speed)
    target = position + command * dt
    hit = False
    if surface_depth is not None:
        target[2] = -surface_depth
    elif not region.z_min <= target[2] <= region.z_max:
        target[2] = np.clip(target[2], region.z_min, region.z_max)
        hit = True
    horizontal = np.hypot(target[0], target[1])
    if horizontal > region.radius:
        target[:2] *= region.radius / horizontal
        hit = True
    offset = target - keep_out_centre
    distance = vector_norm(offset)
    if distance < keep_out_radius:
        if surface_depth is not None:  # out to the sphere's circle at the vessel's depth
            across = np.hypot(offset[0], offset[1])
            heading = offset[:2] / across if across > 1e-9 else np.array([1.0, 0.0])
            target[:2] = keep_out_centre[:2] + heading * np.sqrt(keep_out_radius**2 - offset[2] ** 2)
        else:
            direction = offset / distance if distance > 1e-9 else np.array([1.0, 0.0, 0.0])
            target = keep_out_centre + direction * keep_out_radius
        hit = True
    return target, (target - position) / dt, hit


@dataclass
class NavigationError:
    """What the robot's navigation reports: truth plus white noise, plus an optional random-walk drift."""

    position_sd: float  # m, sigma_rov
    velocity_sd: float  # m/s
    drift_sd: float = 0.0  # m/sqrt(s)
    drift: np.ndarray | None = None

    def reset(self) -> None:
        self.drift = np.zeros(3)

    def report(
        self, rng: np.random.Generator, position: np.ndarray, velocity: np.ndarray, dt: float
    ) -> tuple[np.ndarray, np.ndarray]:
        if self.drift is None:
            self.reset()
        assert self.drift is not None  # reset() set it
        if self.drift_sd > 0:
            self.drift = self.drift + rng.normal(0.0, self.drift_sd * np.sqrt(dt), 3)
        noise = rng.normal(0.0, 1.0, 6)
        return position + self.drift + self.position_sd * noise[:3], velocity + self.velocity_sd * noise[3:]
