"""Truth motions against analytic motion; robot kinematics against its limits."""

import dataclasses

import numpy as np
import pytest

from aasl_gym.config import SourceConfig, WorldConfig
from aasl_gym.motion import (
    Box,
    NavigationError,
    SourceState,
    advance_source,
    motion_region,
    move_receiver,
    sample_source,
    small_angle_series,
)

WORLD, SOURCE = WorldConfig(), SourceConfig()
BIG = Box(1e6, -1e6, 1e6)  # no boundary: pure model motion


def test_cv_moves_on_a_straight_line():
    state = SourceState("cv", np.array([1.0, 2, -10]), np.array([0.5, -0.3, 0.05]), np.zeros(3), 0.0, 1.5)
    for _ in range(50):
        state = advance_source(state, 0.2, BIG)
    np.testing.assert_allclose(state.position, [1 + 5, 2 - 3, -10 + 0.5], atol=1e-12)


def test_ca_matches_closed_form_until_speed_cap():
    a = np.array([0.01, 0, 0])
    state = SourceState("ca", np.zeros(3), np.array([0.2, 0, 0]), a, 0.0, 1.5)
    for _ in range(100):
        state = advance_source(state, 0.2, BIG)
    t = 20.0
    np.testing.assert_allclose(state.position, [0.2 * t + 0.5 * 0.01 * t**2, 0, 0], atol=1e-10)
    for _ in range(2000):
        state = advance_source(state, 0.2, BIG)
    assert np.linalg.norm(state.velocity) == pytest.approx(1.5)


def test_ctrv_follows_a_circle():
    omega, speed = 0.1, 1.0
    state = SourceState("ctrv", np.zeros(3), np.array([speed, 0, 0]), np.zeros(3), omega, 1.5)
    radius = speed / omega
    for step in range(1, 200):
        state = advance_source(state, 0.2, BIG)
        angle = omega * 0.2 * step
        np.testing.assert_allclose(
            state.position[:2], [radius * np.sin(angle), radius * (1 - np.cos(angle))], atol=1e-9
        )
        assert np.linalg.norm(state.velocity) == pytest.approx(speed)


@pytest.mark.parametrize("kind", ["static", "cv", "ca", "ctrv", "mixed"])
@pytest.mark.parametrize("confined", [False, True])
def test_sources_start_near_the_pod_and_stay_in_their_bounds(kind, confined):
    source = dataclasses.replace(SOURCE, confined=confined)
    region = motion_region(WORLD, source)
    for seed in range(20):
        rng = np.random.default_rng(seed)
        state = sample_source(rng, kind, source, WORLD)
        assert np.linalg.norm(state.position) <= SOURCE.initial_radius
        assert -WORLD.water_depth < state.position[2] < 0
        if state.kind != "static":
            assert SOURCE.speed_range[0] - 1e-12 <= np.linalg.norm(state.velocity) <= SOURCE.max_speed + 1e-12
        for _ in range(600):
            state = advance_source(state, 0.2, region)
            assert np.hypot(*state.position[:2]) <= (WORLD.region_radius if confined else np.inf)
            assert region.z_min - 1e-9 <= state.position[2] <= region.z_max + 1e-9


def test_an_unconfined_source_keeps_its_model_beyond_the_region():
    """By default only surface and bed bound the source: a fast CV source leaves the region on a line."""
    region = motion_region(WORLD, SOURCE)
    state = SourceState("cv", np.array([30.0, 0, -10]), np.array([1.5, 0.5, 0]), np.zeros(3), 0.0, 1.5)
    start = state.position
    for _ in range(600):
        state = advance_source(state, 0.2, region)
    np.testing.assert_allclose(state.position, start + 120.0 * np.array([1.5, 0.5, 0]), atol=1e-9)


def test_same_seed_same_source():
    a = sample_source(np.random.default_rng(3), "mixed", SOURCE, WORLD)
    b = sample_source(np.random.default_rng(3), "mixed", SOURCE, WORLD)
    assert a.kind == b.kind and np.array_equal(a.position, b.position) and np.array_equal(a.velocity, b.velocity)


def test_receiver_speed_limit_and_keep_out():
    region = Box(60.0, -58.0, -1.0)
    centre = np.array([0.0, 0, -0.96])
    position, velocity, hit = move_receiver(
        np.array([10.0, 0, -5]), np.array([10.0, 0, 0]), 0.2, 1.5, region, centre, 3.0
    )
    assert np.linalg.norm(velocity) == pytest.approx(1.5) and not hit
    position, hits = np.array([4.0, 0, -3]), []
    for _ in range(20):
        position, _, hit = move_receiver(position, np.array([-1.5, 0, 0]), 0.2, 1.5, region, centre, 3.0)
        hits.append(hit)
        assert np.linalg.norm(position - centre) >= 3.0 - 1e-9
    assert any(hits)
    position, _, hit = move_receiver(np.array([10.0, 0, -1.1]), np.array([0, 0, 1.5]), 0.2, 1.5, region, centre, 3.0)
    assert position[2] == pytest.approx(-1.0) and hit


def test_surface_vessel_ignores_z():
    region = Box(60.0, -58.0, -0.5)
    position, velocity, _ = move_receiver(
        np.array([10.0, 0, -1]), np.array([0.0, 1, -1]), 0.2, 1.5, region, np.zeros(3), 3.0, surface_depth=1.0
    )
    assert position[2] == -1.0 and velocity[2] == 0.0


def test_navigation_error_statistics():
    nav = NavigationError(position_sd=0.1, velocity_sd=0.04)
    rng = np.random.default_rng(0)
    errors = np.array([np.concatenate(nav.report(rng, np.zeros(3), np.zeros(3), 0.2)) for _ in range(20000)])
    np.testing.assert_allclose(errors[:, :3].std(axis=0), 0.1, rtol=0.05)
    np.testing.assert_allclose(errors[:, 3:].std(axis=0), 0.04, rtol=0.05)


@pytest.mark.parametrize("turn_rate", [0.1, -0.07])
def test_a_uturn_comes_back_on_a_parallel_line_two_turn_radii_aside(turn_rate):
    """Straight for t1, a half-turn at omega (pi / |omega| s), straight for s: closed form
    p0 + v t1 + (2 / omega) R90(v) - v s, velocity -v; steps that straddle the turn's ends included."""
    v, p0, t1 = np.array([0.3, 0.1, 0.0]), np.array([1.0, -2.0, -0.6]), 7.1
    half_turn = np.pi / abs(turn_rate)
    state = SourceState("uturn", p0, v, np.zeros(3), turn_rate, 1.5, t1, half_turn)
    steps = 400
    for _ in range(steps):
        state = advance_source(state, 0.2, BIG)
    after = steps * 0.2 - t1 - half_turn
    assert after > 0
    left = np.array([-v[1], v[0], 0.0])
    np.testing.assert_allclose(state.position, p0 + v * t1 + 2.0 / turn_rate * left - v * after, atol=1e-9)
    np.testing.assert_allclose(state.velocity, -v, atol=1e-12)
    mid = SourceState("uturn", p0, v, np.zeros(3), turn_rate, 1.5, t1, half_turn)
    for _ in range(1000):  # steps of an uneven length that land on the turn's middle
        mid = advance_source(mid, (t1 + 0.5 * half_turn) / 1000, BIG)
    radius = np.linalg.norm(v) / abs(turn_rate)  # half-way round: a quarter turn, velocity at 90 degrees
    np.testing.assert_allclose(mid.velocity, np.sign(turn_rate) * left, atol=1e-9)
    np.testing.assert_allclose(
        mid.position, p0 + v * t1 + radius * (v / np.linalg.norm(v)) + (1 / turn_rate) * left, atol=1e-9
    )


def test_a_source_held_at_a_depth_starts_there_and_moves_horizontally():
    source = dataclasses.replace(SOURCE, depth=0.6, initial_centre=(0.0, 0.0, -0.6), boundary_margin=0.3)
    world = dataclasses.replace(WORLD, water_depth=3.0)
    rng = np.random.default_rng(4)
    for kind in ("static", "cv", "ctrv", "uturn"):
        state = sample_source(rng, kind, source, world)
        assert state.position[2] == -0.6 and state.velocity[2] == 0.0
        assert state.kind == kind
    uturn = sample_source(rng, "uturn", source, world)
    assert SOURCE.uturn_start_range[0] <= uturn.turn_start <= SOURCE.uturn_start_range[1]
    assert uturn.turn_left == pytest.approx(np.pi / abs(uturn.turn_rate))


def test_a_surface_vessel_is_kept_out_of_the_sphere_at_its_own_depth():
    centre, radius, depth = np.array([0.0, 0.0, -0.91]), 1.0, 1.19
    region = Box(6.0, -2.5, -0.5)
    position, _, hit = move_receiver(
        np.array([1.2, 0.0, -depth]), np.array([-1.0, 0.0, 0.3]), 0.5, 1.0, region, centre, radius, depth
    )
    assert hit and position[2] == -depth and position[1] == 0.0
    assert position[0] == pytest.approx(np.sqrt(radius**2 - (depth - 0.91) ** 2))  # on the sphere, at its depth


def test_the_small_angle_series_takes_the_values_np_where_takes(rng):
    """Evaluated where it is taken, the series gives what ``np.where`` over every angle gives, to the last bit (a
    power of NumPy's included): for grids of turns and lags whose angles are some small, all small or none small,
    and for one angle."""
    turn = np.concatenate([[0.0, 1e-7, 2e-6], rng.uniform(0.01, 0.1, 5) * rng.choice([-1, 1], 5)])[:, None]
    lags = np.linspace(-60.0, 0.0, 41)[None, :]

    def series(w, t):
        return t**2 / 2 - w**2 * t**4 / 8 + w * t**3 / 3

    grids = {
        "some": (slice(None), slice(None)),
        "all": (slice(0, 1), slice(None)),
        "none": (slice(3, None), slice(0, 40)),
    }
    for case, (rows, columns) in grids.items():
        w, t = turn[rows], lags[:, columns]
        angle = w * t
        small = np.abs(angle) < 1e-4
        closed = (1 - np.cos(angle)) / np.where(small, 1.0, w) - t
        assert {"some": small.any() and not small.all(), "all": small.all(), "none": not small.any()}[case]
        expected = np.where(small, series(w, t), closed)
        np.testing.assert_array_equal(small_angle_series(small, closed, series, w, t), expected, err_msg=case)
    one = np.float64(1e-3) * -0.05
    for closed_one in (2.0, np.float64(3.0)):
        expected = np.where(np.abs(one) < 1e-4, series(one, -0.05), closed_one)
        assert small_angle_series(np.abs(one) < 1e-4, closed_one, series, one, -0.05) == expected
