"""Scripted patrol references against closed-form geometry: each path's velocity is its time derivative,
the helix and spiral keep their radii, depths and speed, the lawnmower stays on its square, the square
runs its perimeter."""

import numpy as np
import pytest

from aasl_gym.config import PatrolConfig
from aasl_gym.patrols import REFERENCES, PatrolGeometry, lawnmower_waypoints, patrol_command

CONFIG = PatrolConfig()
GEOMETRY = PatrolGeometry(np.array([0.0, 0.0, -0.96]), np.array([15.0, 0.0, -7.0]))
TIMES = np.linspace(0.3, 239.7, 400)


@pytest.mark.parametrize("pattern", sorted(REFERENCES))
def test_the_reference_velocity_is_the_derivative_of_the_path(pattern):
    """Central differences of p_ref(t) give v_ref(t) (away from the lawnmower's corners)."""
    step = 1e-5
    for t in TIMES:
        ahead, behind = (
            REFERENCES[pattern](t + step, CONFIG, GEOMETRY)[0],
            REFERENCES[pattern](t - step, CONFIG, GEOMETRY)[0],
        )
        numeric = (ahead - behind) / (2 * step)
        if pattern in ("lawnmower", "square") and abs(np.linalg.norm(numeric) - CONFIG.speed) > 0.01 * CONFIG.speed:
            continue  # a corner or a turn back between the two points
        np.testing.assert_allclose(REFERENCES[pattern](t, CONFIG, GEOMETRY)[1], numeric, atol=1e-4)


def test_the_helix_keeps_its_radius_depth_band_and_speed():
    positions, velocities = map(np.array, zip(*(REFERENCES["helix"](t, CONFIG, GEOMETRY) for t in TIMES)))
    np.testing.assert_allclose(np.hypot(positions[:, 0], positions[:, 1]), CONFIG.radius)
    assert np.all((-positions[:, 2] >= CONFIG.depth_min - 1e-9) & (-positions[:, 2] <= CONFIG.depth_max + 1e-9))
    np.testing.assert_allclose(np.hypot(velocities[:, 0], velocities[:, 1]), CONFIG.speed)
    depth_at_quarter_period = -REFERENCES["helix"](CONFIG.depth_period / 4, CONFIG, GEOMETRY)[0][2]
    assert depth_at_quarter_period == pytest.approx(CONFIG.depth_max)


def test_the_spiral_sweeps_its_radii_at_its_depth_and_tangential_speed():
    positions, velocities = map(np.array, zip(*(REFERENCES["spiral"](t, CONFIG, GEOMETRY) for t in TIMES)))
    radii = np.hypot(positions[:, 0], positions[:, 1])
    assert radii.min() == pytest.approx(CONFIG.spiral_radius_min, abs=0.5)
    assert radii.max() == pytest.approx(CONFIG.spiral_radius_max, abs=0.5)
    np.testing.assert_allclose(positions[:, 2], -CONFIG.spiral_depth)
    tangential = np.abs(positions[:, 0] * velocities[:, 1] - positions[:, 1] * velocities[:, 0]) / radii
    np.testing.assert_allclose(tangential, CONFIG.speed, rtol=1e-9)


def test_the_lawnmower_stays_on_its_square_and_the_command_pulls_onto_the_path():
    half = 0.5 * CONFIG.lawnmower_width
    waypoints = lawnmower_waypoints(CONFIG, GEOMETRY)
    assert np.all(np.abs(waypoints[:, :2]) <= half + 1e-9)
    for t in TIMES:
        position, velocity = REFERENCES["lawnmower"](t, CONFIG, GEOMETRY)
        assert np.all(np.abs(position[:2]) <= half + 1e-9)
        assert np.linalg.norm(velocity) == pytest.approx(CONFIG.speed)
    target, feedforward = REFERENCES["helix"](10.0, CONFIG, GEOMETRY)
    off = target + np.array([1.0, -2.0, 0.5])
    np.testing.assert_allclose(
        patrol_command("helix", 10.0, off, CONFIG, GEOMETRY), feedforward - CONFIG.position_gain * (off - target)
    )
    with pytest.raises(ValueError, match="unknown patrol pattern 'zigzag'"):
        patrol_command("zigzag", 0.0, off, CONFIG, GEOMETRY)


def test_the_square_runs_its_perimeter_from_the_point_nearest_the_start():
    """On the square of half-side ``radius`` at the mid depth, at ``speed``, once round in 8 r / speed,
    from the start's nearest point: the start (15, 0) is the middle of the +x side, so a quarter of a side
    later the robot is at (r, r / 2) heading +y, and at the corner (r, r) half a side after the start."""
    half, depth = CONFIG.radius, -0.5 * (CONFIG.depth_min + CONFIG.depth_max)
    for t in TIMES:
        position, velocity = REFERENCES["square"](t, CONFIG, GEOMETRY)
        assert np.max(np.abs(position[:2])) == pytest.approx(half)
        assert position[2] == depth and np.linalg.norm(velocity) == pytest.approx(CONFIG.speed)
    quarter_side = 0.5 * half / CONFIG.speed
    position, velocity = REFERENCES["square"](quarter_side, CONFIG, GEOMETRY)
    np.testing.assert_allclose(position, [half, 0.5 * half, depth], atol=1e-12)
    np.testing.assert_allclose(velocity, [0.0, CONFIG.speed, 0.0], atol=1e-12)
    corner = REFERENCES["square"](2 * quarter_side, CONFIG, GEOMETRY)[0]
    np.testing.assert_allclose(corner, [half, half, depth], atol=1e-9)
    lap = 8 * half / CONFIG.speed
    np.testing.assert_allclose(
        REFERENCES["square"](lap + 1.0, CONFIG, GEOMETRY)[0], REFERENCES["square"](1.0, CONFIG, GEOMETRY)[0], atol=1e-9
    )
