"""The phasor search: a start for the reflecting world from the prior alone, grown window by window.

Under reflections the tracker's filters and window fits carry the phasor model, whose apparent RD and
RRD ripple on the scale of a wavelength as the source moves. LC-MAP and the coarse window fits weigh
candidates with the direct path and the ripple as noise; that model's errors are broad (RD 0.16 /
0.36 / 0.52 m, RRD 0.12 / 0.35 / 1.96 m/s at 50 / 90 / 99 %, tuning seeds), and its candidates land
4-62 m from a moving source, far outside the basin of a fine (phasor) fit of a long window (about
1 m and 0.05 m/s on 30 s). A fine fit of a *short* window has a wider basin, and a fit that explains
it carried on to longer windows stays near the truth (``benchmarks/fine_search.py``).

So :func:`search` fits a short window with the phasor model from a lattice of starts: each start's
velocity is solved with its position held (:func:`solve_velocity`, on windows growing from 0.6 s to the
whole: on 5 s at once the ripple leaves a velocity basin of a few tenths of a m/s, and a start at rest
missed a near-surface source's velocity even at its true position), the best ``SEARCH_SCREEN`` of them
are fitted freely, and
the fits that explain the window (the fine gate) are returned, at most ``SEARCH_POOL``, none within
``DISTINCT`` of a better one. The tracker (:class:`aasl_gym.estimator.SourceTracker`) runs it once an
episode on the first ``SEARCH_WINDOW`` seconds from :func:`prior_lattice` - the ball of
``source.initial_radius`` grown by ``initializer.max_source_speed``, within the water column - and,
while its growing window is under ``LOCAL_UNTIL``, on the last seconds from :func:`local_lattice`
about its likeliest filter. It keeps the finds as a pool that each re-seed refits on its window: a
wrong dip that explained 5 s rarely explains 20. Where the growing window is longer than ``LEAD_IN``, the local
finds are first fitted on its last ``LEAD_IN`` seconds, which lead them into the long window's narrow basin. A
recovery (the likeliest filter turned inconsistent) searches the last seconds from :func:`prior_lattice` about that
filter, the ball of ``REGIONAL_RADIUS``: a filter that never found its source can sit tens of metres off it, beyond
the local cube's reach.

After the growing window, a filter can sit in a wrong dip of its whole track's phasor fit (a CV filter on a
parked source drifts into one), where the refit from its own state stays. :func:`search_track` looks about it
on windows that grow to the whole track; the tracker runs it where the track refit explains the track poorly
(``TRACK_SEARCH_GATE``).
"""

from __future__ import annotations

import numpy as np

from aasl_gym.filters import MotionModel
from aasl_gym.initializers import Burst, recent_samples
from aasl_gym.motion import Box
from aasl_gym.window import WindowFit, fit_window

SEARCH_WINDOW = 5.0  # s: the first window searched (on 3 s more dips pass, on 10 s the basins narrow)
SEARCH_SCREEN = 0.1  # share of the lattice kept after the velocity solve (the truth's cell ranked in the top 3 %)
LOCAL_HALF_WIDTH = 3.0  # m: the local search's cube about the likeliest filter
LOCAL_SPACING = 1.5  # m: its lattice
LOCAL_UNTIL = 60.0  # s of growing window after which no local search runs (30 s: CV 37 of 60 tuning seeds, 60 s: 45)
LOCAL_POOL = 16  # of a local or a regional search's finds, at most this many join the pool (at most SEARCH_POOL)
# s: where the growing window is longer, the local search's finds are fitted on its last LEAD_IN seconds before they
# join the pool: a 5 s fit's basin is wide, a long window's narrow (see search_track). The track search's first
# window, and the one value tried.
LEAD_IN = 15.0
# m: the radius of a recovery's search ball about the likeliest filter, and s between two such searches. Spiral CTRV
# tuning seeds 20000-20095 and 20100-20195: 152 -> 161 of 192 found, lost tracks 19 -> 8, the same time per episode;
# spiral static / CV 47 / 40 -> 48 / 39 of 48; the helix 96 of 96 either way.
REGIONAL_RADIUS = 12.0
REGIONAL_COOLDOWN = 20.0
SEARCH_POOL = 64  # candidates the pool keeps between re-seeds (each re-seed refits it and keeps it best first)
HELD_POSITION_SD = 0.5  # m: the position prior of the velocity solve, about the lattice point
SOLVE_ITERATIONS = 4  # Levenberg-Marquardt iterations of that solve, on each of its windows
SOLVE_WINDOWS = (0.6, 1.2, 2.0, 3.0)  # s: the velocity solve's shorter windows before the whole one, in turn
DISTINCT = 0.3  # m: fits closer than this are one candidate
# The track search. Robust cost per residual of a whole-track refit above which it runs (its find is adopted where
# it beats the refit): converged filters' refits cost 0.51-0.69 (16 spiral-static tuning seeds), failing ones 0.64-3.1.
TRACK_SEARCH_GATE = 0.75
TRACK_HALF_WIDTH = 3.0  # m: its cube about the filter
TRACK_SPACING = 1.5  # m: its lattice (125 points, each at the filter's motion and at rest)
TRACK_WINDOWS = (15.0, 40.0)  # s: the windows its starts are fitted on in turn before the whole track
TRACK_KEEP = (32, 8)  # distinct fits of each of those windows that go on to the next


def prior_lattice(region: Box, spacing: float, centre: np.ndarray) -> np.ndarray:
    """Points (N, 3) of a cubic lattice of ``spacing`` (m) inside the ball of radius ``region.radius``
    about ``centre`` (m), between ``region``'s depth bounds; the top layer at ``z_max``."""
    axis = np.arange(-region.radius, region.radius + 1e-9, spacing)
    depths = np.arange(region.z_max, region.z_min - 1e-9, -spacing)
    points = np.stack(np.meshgrid(centre[0] + axis, centre[1] + axis, depths, indexing="ij"), -1).reshape(-1, 3)
    return points[np.linalg.norm(points - centre, axis=1) <= region.radius]


def local_lattice(centre: np.ndarray, half_width: float, spacing: float) -> np.ndarray:
    """Points (N, 3) of a cubic lattice of ``spacing`` (m) filling the cube of ``half_width`` about ``centre``."""
    axis = np.arange(-half_width, half_width + 1e-9, spacing)
    return centre + np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)


def distinct_best(states: np.ndarray, costs: np.ndarray, limit: int) -> np.ndarray:
    """Indices of at most ``limit`` of ``states`` (C, n), best cost first, none within ``DISTINCT`` of a better one."""
    kept: list[int] = []
    for i in np.argsort(costs, kind="stable"):
        if _apart(states[i, 0:3], states[kept, 0:3]):
            kept.append(int(i))
            if len(kept) == limit:
                break
    return np.array(kept, dtype=int)


def _apart(point: np.ndarray, others: np.ndarray) -> bool:
    """Whether ``point`` (3,) lies further than ``DISTINCT`` from each of ``others`` (K, 3; m): every distance at
    once (a norm per pair took 0.7 ms to keep 32 of 250 fits, this 0.2 ms)."""
    return bool((np.linalg.norm(others - point, axis=1) > DISTINCT).all())


def search(burst: Burst, model: MotionModel, starts: np.ndarray, window_prior, gate: float) -> np.ndarray:
    """Fine candidates (C, n) at the burst's last sample that explain it (robust cost at most
    ``gate``), best first, at most ``SEARCH_POOL``, from ``starts`` (S, n) there; ``burst`` carries the
    filter's own (phasor) model and ``window_prior(states)`` gives the window fits' prior (mean (C, n),
    sd (n,)). Each start's velocity is solved first with its position held (``HELD_POSITION_SD``,
    :func:`solve_velocity`); the best ``SEARCH_SCREEN`` of those are then fitted freely. No starts (a lattice
    coarser than its ball), no candidates."""
    if not len(starts):
        return starts.copy()
    prior_mean, prior_sd = window_prior(starts)
    prior_mean[:, 0:3], held_sd = starts[:, 0:3], prior_sd.copy()
    held_sd[0:3] = HELD_POSITION_SD
    solved = solve_velocity(burst, model, starts, prior_mean, held_sd)
    screened = np.argsort(solved.costs, kind="stable")[: max(1, int(round(SEARCH_SCREEN * len(starts))))]
    states = solved.states[screened]
    free_mean, free_sd = window_prior(states)
    fit = fit_window(burst, model, states, free_mean, free_sd, robust=True)
    passed = np.flatnonzero(fit.costs <= gate)
    return fit.states[passed[distinct_best(fit.states[passed], fit.costs[passed], SEARCH_POOL)]]


def solve_velocity(
    burst: Burst, model: MotionModel, starts: np.ndarray, prior_mean: np.ndarray, held_sd: np.ndarray
) -> WindowFit:
    """The window fit (:func:`~aasl_gym.window.fit_window`, robust) of ``starts`` (S, n) on the burst's
    samples within each of ``SOLVE_WINDOWS`` (s) of its last one and then on all of it, each fit starting
    the next; ``held_sd`` (n,) holds the positions. A velocity error of 0.5 m/s moves the source 0.3 m in
    0.6 s, well inside the ripple's scale, but 2.5 m in 5 s; so the short windows' fits lead a start at
    rest into the whole window's narrow velocity basin (at the true positions of five default-world
    episodes: five of five, against none from rest on 5 s at once)."""
    states = starts
    for seconds in (*SOLVE_WINDOWS, np.inf):
        window = recent_samples(burst, seconds)
        solved = fit_window(window, model, states, prior_mean, held_sd, robust=True, iterations=SOLVE_ITERATIONS)
        states = solved.states
    return solved


def search_track(burst: Burst, model: MotionModel, state: np.ndarray, window_prior) -> WindowFit:
    """Fits (at most ``TRACK_KEEP[-1]``) of the whole ``burst`` - a track, with the filter's own model - from a
    lattice about ``state`` (n,), the filter's, at its motion and at rest: each start is fitted on the last
    ``TRACK_WINDOWS`` seconds in turn, the best ``TRACK_KEEP`` distinct fits of each going on to the next,
    and at last to the whole burst. A long phasor window's basin is a few mm/s in velocity and a few
    decimetres in position: a filter a metre off the source in a wrong dip stays there, while on 15 s the
    basins are wide enough for the lattice's cells to reach the truth's. The fits are folded into the
    ``model``'s depth bounds (:meth:`~aasl_gym.filters.MotionModel.fold_states`) after every window: near the
    surface the lattice reaches beyond them, where a fit lands on a mirror twin of one within."""
    lattice = local_lattice(state[0:3], TRACK_HALF_WIDTH, TRACK_SPACING)
    starts = np.repeat(state[None], 2 * len(lattice), axis=0)
    starts[:, 0:3] = np.concatenate([lattice, lattice])
    starts[len(lattice) :, 3:-2] = 0.0  # at rest: no velocity, acceleration or turn
    prior_mean, prior_sd = window_prior(starts)
    for seconds, keep in zip(TRACK_WINDOWS, TRACK_KEEP):
        fit = fit_window(recent_samples(burst, seconds), model, starts, prior_mean, prior_sd, robust=True)
        folded = model.fold_states(fit.states, fit.information)[0]
        kept = distinct_best(folded, fit.costs, keep)
        starts, prior_mean = folded[kept], prior_mean[kept]
    fit = fit_window(burst, model, starts, prior_mean, prior_sd, robust=True)
    states, information = model.fold_states(fit.states, fit.information)
    return WindowFit(states, fit.costs, information)
