"""The phasor search against the simulated truth: from a lattice that misses the source by metres,
the short window's fine fit lands on it, the velocity solve finds a near-surface source's velocity
from rest, and the track search finds a near-surface source within the water column; the lattices and
the diversity cut by their definitions."""

import itertools

import numpy as np
import pytest

from aasl_gym.config import FilterConfig
from aasl_gym.filters import make_motion_model
from aasl_gym.initializers import Burst, select_samples
from aasl_gym.measurement_models import FrameAveragedPhasor, Propagation, frame_offsets
from aasl_gym.motion import Box
from aasl_gym.search import (
    DISTINCT,
    HELD_POSITION_SD,
    distinct_best,
    local_lattice,
    prior_lattice,
    search,
    search_track,
    solve_velocity,
)

FIXED = np.array([0.0, 0.0, -0.96])
WAVELENGTH = 1.5
FRAME = FrameAveragedPhasor(Propagation(60.0, -0.9, 0.3, 2 * np.pi / WAVELENGTH), frame_offsets(0.2, 3))
TIMES = np.arange(0.2, 5.01, 0.2)  # the first 5 s of an episode at 5 Hz
NOISE = np.diag([0.05**2, 0.02**2])
# The source at the window's first sample: 14 m down, moving at 0.6 m/s (the default world's kind).
START = np.array([6.0, -9.0, -14.0, 0.4, -0.3, 0.05, 0.0, 0.0])


def phasor_window(rng: np.random.Generator, start: np.ndarray = START) -> tuple[Burst, object]:
    """Five seconds of the frame model along a straight track from ``start``, with the default noise,
    the mobile hydrophone on a descending arc at 7-9 m; the burst as the tracker weighs it (robust,
    RD modulo the wavelength)."""
    model = make_motion_model(FilterConfig(motion_model="cv"))
    track = model.trajectory(start[None], TIMES - TIMES[0])[0]
    angle = TIMES / 15.0
    mobile = np.stack([15 * np.cos(angle), 15 * np.sin(angle), -7.0 - 0.4 * TIMES], -1)
    mobile_velocity = np.stack([-np.sin(angle), np.cos(angle), np.full_like(TIMES, -0.4)], -1)
    z = FRAME(track[:, 0:3], track[:, 3:6], mobile, mobile_velocity, FIXED)
    z = z + np.sqrt(np.diag(NOISE)) * rng.normal(size=z.shape)
    burst = Burst(TIMES, z, mobile, mobile_velocity, FIXED, NOISE, WAVELENGTH, FRAME, WAVELENGTH, (0.05, 0.02), True)
    return burst, model


def window_prior(states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tracker's window prior for a cv model: velocity sd 1 m/s, b_p within a wavelength, b_v 2 cm/s."""
    sd = np.full(states.shape[1], np.inf)
    sd[3:6], sd[-2:] = 1.0, (WAVELENGTH, 0.02)
    mean = np.zeros_like(states)
    mean[:, -2] = states[:, -2]
    return mean, sd


def test_a_search_without_starts_finds_nothing():
    """A lattice coarser than its ball has no points: the search returns no candidates, shaped as states."""
    burst, model = phasor_window(np.random.default_rng(0))
    found = search(burst, model, np.zeros((0, START.size)), window_prior, 3.0 * burst.measurements.size)
    assert found.shape == (0, START.size)
    assert len(prior_lattice(Box(12.0, -60.0, -2.0), 30.0, np.zeros(3))) == 0  # such a lattice


@pytest.mark.parametrize("latest_first", [False, True], ids=["states-at-end", "states-at-start"])
def test_a_start_in_the_truths_basin_is_kept(latest_first):
    """The local search's form: a lattice of 1.5 m about the source, every start carrying a velocity
    5 cm/s off along each axis. One candidate kept is the truth - within what 5 s of noise allow (0.3 m) - at the sample
    the burst ends on (the first one when its samples run latest first, as the search of an episode's
    start has them). Five seconds do not yet single it out: dips a metre off explain them as well, which
    is why the tracker carries the candidates on to longer windows."""
    burst, model = phasor_window(np.random.default_rng(0))
    truth = START.copy()
    if latest_first:
        burst = select_samples(burst, slice(None, None, -1))
    else:
        truth[0:3] += (TIMES[-1] - TIMES[0]) * START[3:6]
    lattice = local_lattice(truth[0:3], 3.0, 1.5)
    starts = np.repeat(truth[None], len(lattice), axis=0)
    starts[:, 0:3], starts[:, 3:6] = lattice, truth[3:6] + 0.05
    gate = 3.0 * burst.measurements.size
    found = search(burst, model, starts, window_prior, gate)
    errors = np.linalg.norm(found[:, 0:3] - truth[0:3], axis=1)
    nearest = np.argmin(errors)
    assert errors[nearest] < 0.4
    assert np.linalg.norm(found[nearest, 3:6] - truth[3:6]) < 0.1
    assert np.all(
        np.linalg.norm(found[:, None, 0:3] - found[None, :, 0:3], axis=-1)[np.triu_indices(len(found), 1)] > DISTINCT
    )


def test_the_velocity_solve_finds_a_near_surface_sources_velocity_from_rest():
    """Held at the true position, a start at rest must reach the source's velocity (1.2 m/s, 3 and 5.5 m
    below the surface, where the surface image's phase turns fastest). Four iterations on the whole
    5 s reach none of these six draws (0.5 - 0.9 m/s off: the ripple leaves a velocity basin of a few
    tenths of a m/s); the solve on growing windows must reach at least four (it reaches five)."""
    reached = 0
    for depth, seed in itertools.product([3.0, 5.5], range(3)):
        start = START.copy()
        start[2], start[3:6] = -depth, (1.1, -0.45, -0.08)
        burst, model = phasor_window(np.random.default_rng(seed), start)
        burst = select_samples(burst, slice(None, None, -1))  # the state at the first sample
        rest = start.copy()
        rest[3:6] = 0.0
        prior_mean, prior_sd = window_prior(rest[None])
        prior_mean[:, 0:3], prior_sd[0:3] = rest[0:3], HELD_POSITION_SD
        solved = solve_velocity(burst, model, rest[None], prior_mean, prior_sd)
        reached += np.linalg.norm(solved.states[0, 3:6] - start[3:6]) < 0.1
    assert reached >= 4


@pytest.mark.parametrize("centre", [(0.0, 0.0, 0.0), (3.0, -2.0, -59.06)])  # the surface; a pod on the bed
def test_the_prior_lattice_fills_the_ball_within_the_water_column(centre):
    region = Box(20.0, -58.0, -2.0)
    centre = np.array(centre)
    points = prior_lattice(region, 2.0, centre)
    assert np.all(np.linalg.norm(points - centre, axis=1) <= 20.0 + 1e-9)
    assert np.all((points[:, 2] <= -2.0 + 1e-9) & (points[:, 2] >= -58.0 - 1e-9))
    # One point per 8 m^3 of the ball's part inside the water column (a spherical cap of height h,
    # pi h^2 (3r - h) / 3), and the layer on the cap's flat face (radius sqrt(r^2 - (r - h)^2)), half a layer more.
    height = 20.0 - min(abs(centre[2] - (-2.0)), abs(centre[2] - (-58.0)))
    volume = np.pi * height**2 * (3 * 20.0 - height) / 3
    face = np.pi * (20.0**2 - (20.0 - height) ** 2)
    expected = (volume + 0.5 * 2.0 * face) / 2.0**3
    assert abs(len(points) - expected) < 0.02 * expected


def test_the_local_lattice_is_a_cube_about_its_centre():
    centre = np.array([1.0, -2.0, -10.0])
    points = local_lattice(centre, 3.0, 1.5)
    assert len(points) == 5**3
    np.testing.assert_allclose(points.mean(axis=0), centre)
    assert np.abs(points - centre).max() == pytest.approx(3.0)


def test_distinct_best_keeps_the_better_of_close_states_best_first():
    states = np.zeros((4, 8))
    states[:, 0] = [0.0, 0.5 * DISTINCT, 5.0, 10.0]
    costs = np.array([2.0, 1.0, 3.0, 0.5])
    kept = distinct_best(states, costs, limit=3)
    assert kept.tolist() == [3, 1, 2]
    assert distinct_best(states, costs, limit=1).tolist() == [3]


def test_distinct_best_decides_at_the_threshold_as_the_norm_does():
    """States within rounding of ``DISTINCT`` from a better one, on both sides of it, and a NaN: all distances at
    once keep and drop exactly the states that a norm per pair (the root of its sum of squares) does. Not
    ``np.linalg.norm`` of one vector: that takes BLAS's dot, whose AVX-512 kernels round otherwise."""
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(600, 3))
    factors = 1 + np.array([-2e-16, -1e-16, 0.0, 1e-16, 2e-16, 1e-12])[np.arange(600) % 6]
    states = np.zeros((601, 8))
    states[1:, 0:3] = directions / np.linalg.norm(directions, axis=1)[:, None] * DISTINCT * factors[:, None]
    states[7, 1] = np.nan
    costs = np.arange(601.0)
    apart = [i for i in range(1, 601) if np.sqrt(np.sum((states[i, 0:3] - states[0, 0:3]) ** 2)) > DISTINCT]
    assert 0 < len(apart) < 599  # both sides of the threshold are there
    for i in range(1, 601):
        pair = distinct_best(states[[0, i]], costs[[0, i]], limit=2).tolist()
        assert pair == ([0, 1] if i in apart else [0]), i


def test_the_track_search_stays_in_the_water_column_near_the_surface():
    """A CV source 3 m below the surface (the slab's top at 2 m), 40 s of the frame model heard from a helix
    at 7-11 m, and a filter 1 m above and 0.8 m beside it: the track search's lattice reaches above the slab,
    where each fit of the folded trajectories has a mirror twin within that explains the window alike. Every
    fit returned lies within the slab, and the best is the source (within 0.1 m)."""
    times = np.arange(0.2, 40.01, 0.2)
    truth = np.array([6.0, -9.0, -3.0, 0.4, -0.3, 0.0, 0.0, 0.0])
    straight = make_motion_model(FilterConfig(motion_model="cv"))
    track = straight.trajectory(truth[None], times - times[-1])[0]  # the state given at the window's end
    angle, phase = times / 15.0, 0.2 * times
    mobile = np.stack([15 * np.cos(angle), 15 * np.sin(angle), -9.0 - 2.0 * np.cos(phase)], -1)
    mobile_velocity = np.stack([-np.sin(angle), np.cos(angle), 0.4 * np.sin(phase)], -1)
    z = FRAME(track[:, 0:3], track[:, 3:6], mobile, mobile_velocity, FIXED)
    z = z + np.sqrt(np.diag(NOISE)) * np.random.default_rng(0).normal(size=z.shape)
    burst = Burst(times, z, mobile, mobile_velocity, FIXED, NOISE, WAVELENGTH, FRAME, WAVELENGTH, (0.05, 0.02), True)
    folding = make_motion_model(FilterConfig(motion_model="cv"), (-58.0, -2.0), fold_trajectories=True)
    filter_state = truth + np.array([0.8, 0.0, 1.0, 0, 0, 0, 0, 0])
    found = search_track(burst, folding, filter_state, window_prior)
    assert np.all(found.states[:, 2] <= -2.0 + 1e-9)
    best = int(np.argmin(found.costs))
    assert np.linalg.norm(found.states[best, 0:3] - truth[0:3]) < 0.1
