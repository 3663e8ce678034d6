"""The source tracker: burst collection, initialization, a bank of UKFs, re-seeding and recovery.

One call of :meth:`SourceTracker.step` per measurement. Until the initialization burst is complete the
tracker only collects (the estimate is the prior's); then the chosen initializer starts the filter.
LC-MAP returns several hypotheses - the best candidate of every feasible whole-period sheet, since a 2 s
burst rarely tells the sheets apart - and each starts a UKF of its own. Every update multiplies a
hypothesis's weight by its innovation likelihood N(y; 0, S); one that trails the best by
``filter.prune_log_ratio`` (natural log) is dropped, and so is one whose covariance stops being
positive definite or whose estimate leaves the physically possible region. The estimate reported is
the likeliest hypothesis's.

R. Each update uses R_eff = R_ac + H_r Sigma_r H_r^T, with H_r the receiver Jacobian of the filter's
own measurement model at the hypothesis's estimate (the paper's general form). Under multipath the
apparent RD and RRD move with the receiver far faster than the direct path's -u_m says, and a 5 cm
navigation error alone made a filter started at the truth diverge.

The phasor model's ripple. The exact tone model's multipath correction (apparent RD minus direct RD)
is a phase over k: it ripples on a fraction of a wavelength as the source moves, jumps by a wavelength
where a phasor sum winds round zero, and the measured track need not jump with it. So its RD
residuals are taken modulo the wavelength, each sigma point's correction is taken within half a
wavelength of the central point's, and a hypothesis too uncertain to resolve the ripple (position sd
above ``filter.ripple_lock_sd``, not yet ``resolved``) sees the correction at its mean for every
sigma point and the correction's spread as noise. When its sd falls below ``ripple_split_sd`` it picks
its point on the ripple from a small lattice weighed on the recent window (:meth:`_resolve_ripple`).
LC-MAP and the re-seed windows weigh candidates metres apart, with the direct path and the ripple's
spread over the volume (:func:`~aasl_gym.measurement_models.multipath_spread`) as robust (soft-L1) noise.
In signal mode the phasor model is the frame's mean and least-squares slope of the RD
(:func:`~aasl_gym.measurement_models.frame_averaged`): the tone front end measures those, and at an
interference null they differ from the frame centre's value by many sd.

Re-seeding. Two seconds seldom show *where* on its sheet the source is, so after an LC-MAP start
the bank is re-seeded every ``initializer.reseed_interval`` on the growing window, up to ``reseed_until``:
the running filters are refitted on it, and LC-MAP runs on it afresh, fitting the filter's motion model
(straight, turning or accelerating; see :mod:`aasl_gym.initializers`), unless a running filter explains
the window (its chi-square below ``reseed_search_quantile``; the fresh search is most of a re-seed's
cost and seldom beats such a filter). Fresh hypotheses and running filters are weighed on that window's
chi-square (a fresh one next to a running filter on its sheet yields to it), and with
``filter.window_fit`` the best ``initializer.hypotheses`` are refined by the sliding-window MAP
(:mod:`aasl_gym.window`; under the phasor model a second fit resolves the ripple, kept only where it
explains the window, and fits from different starts that land in one dip make one hypothesis).

The phasor search. Under reflections LC-MAP's coarse candidates land metres from a moving source,
outside the basin of the phasor model's window fit. Once an episode, at the first re-seed whose
window holds ``search.SEARCH_WINDOW`` seconds, :mod:`aasl_gym.search` fits those seconds with the
phasor model from a lattice over where the source can be (``initializer.search_spacing``); the fits
that explain them form a pool, which every re-seed refits beside its own fine fits (the pool's winners
join the bank). While the growing window is short, each re-seed (a recovery's too) also searches a small
lattice about the likeliest filter (a filter 2-4 m off can sit in a dip that explains the window); once
the window is longer than ``search.LEAD_IN`` seconds, those finds are fitted on its last ``LEAD_IN``
seconds before they join the pool, which leads them into the long window's narrow basin (:meth:`_lead_in`).

Recovery, at any time. When the likeliest filter's mean NIS over ``divergence_window`` exceeds
``divergence_nis`` (after ``reinit_cooldown``), the tracker re-seeds on the last ``reinit_window``
seconds, the running filters competing with their covariances widened by ``filter.recovery_inflation``
(once the phasor search from the prior has run, with the finds of a search of the ball about the filter, at most
every ``search.REGIONAL_COOLDOWN`` seconds: :meth:`_search_regionally`).
If a fresh hypothesis wins, the step reports a re-initialization and the new track re-seeds its
growing window as after a start. The window is short on purpose: a source the filter's motion model
does not fit (a turning source under the default straight-line filter) is found again on 10 s, not on
60 (the greedy planner's CTRV episodes: 6 of 10 against 1 of 10). When no hypothesis is left at all,
LC-MAP re-starts on that window. The paper's single filter (``initializer.reseed_interval: 0``) has no
re-seeding: an inconsistent filter is dropped and LC-MAP re-starts. The filter never raises into the
episode.

Whole-period sheets and the whole track. A filter one wavelength off explains each new measurement
almost as well as the truth and stays consistent for a long time. So after the growing window, every
``filter.sheet_check_interval`` and first thing in a recovery, the likeliest filter and its two
neighbouring sheets are refitted on its whole track since its start (``filter.track_fit``; else the
last ``reseed_until`` seconds; :meth:`_check_sheets`), where RD residuals are not circular (not under
the phasor model). Unless a neighbour wins, the filter adopts its own fit: the world's motions are
deterministic, and the filter's process noise forgets the close-range data of a source that has moved
away since, which the whole track's fit keeps. Once the growing window is over, a recovery whose check
leaves the filter at a fit that explains the track ends there (:meth:`_track_explained`). Under the
phasor model there are no sheets to check; a filter that resolved the ripple adopts its whole track's fine
fit where that fit explains the track (:meth:`_refit_track`); where it explains the track poorly, the track
search (:func:`~aasl_gym.search.search_track`, ``filter.track_search``) looks about the filter for a dip
that does.

Lost frames. A frame the sensor could not measure (NaN: dropped, or rejected by the front end's
detector) is not assimilated: the filters coast. The unwrapped RD track may have slipped by whole
periods across the gap, so the next measurement takes its period from the likeliest filter's
prediction (:meth:`_reanchor`).

The water column. In the free field the filter's mean reflects at the source region's depth bounds
once it is beyond one and moving away (as the world's sources do), and window trajectories fold
into the slab (:class:`~aasl_gym.filters.MotionModel`).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial

import numpy as np
from scipy import stats

from aasl_gym import geometry, kernels
from aasl_gym.config import EnvConfig
from aasl_gym.extra_pairs import ExtraPairs, PairFrame
from aasl_gym.filters import (
    UnscentedKalmanFilter,
    make_motion_model,
    merwe_weights,
    predict_together,
    stacked,
    update_together,
    whole_periods,
)
from aasl_gym.fisher import information_prior
from aasl_gym.initializers import (
    Burst,
    LCMAPInitializer,
    distinct_hypotheses,
    make_initializer,
    recent_samples,
    robust_loss,
    select_samples,
    subsample,
)
from aasl_gym.measurement_models import (
    FrameAveragedPhasor,
    PhasorModel,
    Propagation,
    direct_measurement,
    frame_offsets,
    multipath_measurement,
    multipath_spread,
    receiver_jacobian,
    receiver_noise,
    tone_period,
)
from aasl_gym.motion import Box, receiver_region
from aasl_gym.search import (
    LEAD_IN,
    LOCAL_HALF_WIDTH,
    LOCAL_POOL,
    LOCAL_SPACING,
    LOCAL_UNTIL,
    REGIONAL_COOLDOWN,
    REGIONAL_RADIUS,
    SEARCH_POOL,
    SEARCH_WINDOW,
    TRACK_SEARCH_GATE,
    distinct_best,
    local_lattice,
    prior_lattice,
    search,
    search_track,
)
from aasl_gym.sensors import received
from aasl_gym.window import WindowFit, fit_window, whitened_residuals

logger = logging.getLogger(__name__)

EXTRA_STATE_SD = {"cv": 0.0, "ca": 0.02, "ctrv": 0.1}  # initial sd of acceleration (m/s^2) / turn rate (rad/s)
RIPPLE_SAMPLES = 120  # a fine (phasor) window fit uses at most this many samples, evenly spaced
RIPPLE_FITS = 4  # window fits that go on to the phasor model's ripple (the best of the coarse fits)
RIPPLE_NIS_CAP = 2.5  # x filter.divergence_nis: the most one frame adds to that test's mean under the phasor model
RIPPLE_GATE = 3.0  # robust cost per residual a fine window fit may have (at the truth ~1.5, in a wrong dip ~9)
# s: a scheduled re-seed's window shorter than this always gets LC-MAP's fresh search (a short window is explained
# by many wrong states; without it the free field's sources converged 2-3 s later on tuning seeds, session 13).
FRESH_SEARCH_UNTIL = 10.0
# A re-started track's check takes the whole history where the earlier measurements add no more to the cost than
# this quantile of chi-square (two degrees of freedom a measurement) allows (:meth:`SourceTracker._with_earlier`).
EARLIER_QUANTILE = 0.999
# A window-fit start whose b_p lies further than this many of the prior's sd from the whole-period sheet the fit holds
# it to starts on that sheet (:meth:`SourceTracker._onto_sheets`).
SHEET_REACH = 5.0


@dataclass
class TrackerOutput:
    initialized: bool
    reinitialized: bool
    innovation: np.ndarray  # (2,), NaN before the filter runs
    innovation_sd: np.ndarray  # (2,), sqrt(diag S)


class MeasurementHistory:
    """The tracker's last ``capacity`` measurements, oldest first: rows (time, z, mobile, mobile velocity, R) as a
    deque keeps them, and the same columns as arrays, so that a window (:meth:`columns`) is a slice and not a
    stack of hundreds of small arrays. Rows are written on into arrays twice the capacity; when the end is
    reached the kept rows move to the front."""

    def __init__(self, capacity: int):
        self.rows: deque = deque(maxlen=capacity)
        size = 2 * max(capacity, 1)
        self._times, self._z, self._noise = np.empty(size), np.empty((size, 2)), np.empty((size, 2, 2))
        self._mobile, self._mobile_velocity = np.empty((size, 3)), np.empty((size, 3))
        # Each row's R: a new number where it is another object than the row before's, so that whether a
        # window's rows share one R is one comparison.
        self._runs = np.empty(size, dtype=np.int64)
        self._end = 0

    def __len__(self) -> int:
        return len(self.rows)

    def __iter__(self):
        return iter(self.rows)

    def __getitem__(self, index: int) -> tuple:
        return self.rows[index]

    def clear(self) -> None:
        self.rows.clear()
        self._end = 0

    def _columns(self) -> tuple[np.ndarray, ...]:
        return self._times, self._z, self._mobile, self._mobile_velocity, self._noise, self._runs

    def append(self, row: tuple) -> None:
        """Keep ``row`` = (time, z, mobile, mobile velocity, R); the oldest goes once ``capacity`` are kept."""
        previous = self.rows[-1][4] if self.rows else None
        self.rows.append(row)
        if self._end == len(self._times):
            kept = len(self.rows) - 1
            for column in self._columns():
                column[:kept] = column[self._end - kept : self._end]
            self._end = kept
        run = self._runs[self._end - 1] + (row[4] is not previous) if self._end else 0
        self._write(self._end, row)
        self._runs[self._end] = run
        self._end += 1

    def _write(self, at: int, row: tuple) -> None:
        self._times[at], self._z[at], self._mobile[at], self._mobile_velocity[at], self._noise[at] = row

    def replace_last(self, row: tuple) -> None:
        """The newest row becomes ``row`` (its R the same object as before)."""
        self.rows[-1] = row
        self._write(self._end - 1, row)

    def columns(self, length: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The newest ``length`` rows' times (K,), z (K, 2), mobile positions and velocities (K, 3) as fresh
        arrays, and their R: the rows' own where they share one object, else their mean. 0: every row (as a
        deque's ``[-0:]``)."""
        length = min(length, len(self.rows)) if length > 0 else len(self.rows)
        window = slice(self._end - length, self._end)
        times, z, mobile, mobile_velocity = (
            column[window].copy() for column in (self._times, self._z, self._mobile, self._mobile_velocity)
        )
        shared = self._runs[window.start] == self._runs[self._end - 1]
        noise = self.rows[-length][4] if shared else np.mean(self._noise[window], axis=0)
        return times, z, mobile, mobile_velocity, noise

    def count_since(self, start: float) -> int:
        """How many of the kept rows were taken at or after ``start`` (s); their times increase."""
        times = self._times[self._end - len(self.rows) : self._end]
        return len(times) - int(np.searchsorted(times, start - 1e-9, side="left"))


@dataclass
class Hypothesis:
    ukf: UnscentedKalmanFilter
    log_weight: float  # log likelihood of the data since its start, relative to the best hypothesis
    started: float  # s, when this hypothesis was (re)started
    nis: deque  # recent normalized innovations squared
    resolved: bool = False  # its point on the phasor model's ripple was chosen (:meth:`SourceTracker._resolve_ripple`)


def _covariances(information: np.ndarray, inflation: float) -> np.ndarray:
    """Symmetric covariances (H, n, n) from information matrices, times ``inflation``; NaN where an information is
    singular (a fit its window leaves undetermined in some direction, which can start no filter)."""
    try:
        covariances = np.linalg.inv(information) * inflation
    except np.linalg.LinAlgError:  # one by one: the same LAPACK call on each, NaN for the singular ones
        covariances = np.stack([_inverse_or_nan(matrix) for matrix in information]) * inflation
    return 0.5 * (covariances + covariances.transpose(0, 2, 1))


def _inverse_or_nan(matrix: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.inv(matrix)
    except np.linalg.LinAlgError:
        return np.full(matrix.shape, np.nan)


class SourceTracker:
    def __init__(self, config: EnvConfig, region: Box, noise_covariance: np.ndarray):
        self.config = config
        self.region = region
        self.noise_covariance = noise_covariance  # R_ac, the acoustic part of R_eff
        self.fixed = np.asarray(config.world.fixed_position, dtype=float)
        receiver = config.receiver
        compensate = config.filter.compensate_navigation
        self.navigation_sd = (receiver.nav_position_sd, receiver.velocity_sd) if compensate else (0.0, 0.0)
        f = config.filter
        self.propagation = Propagation.from_config(config.world, config.source.frequency)
        # The phasor model's correction RD_app - RD is a phase difference over k, defined modulo a
        # wavelength: it jumps where a receiver's phasor sum winds round zero and swings by up to half a
        # wavelength in one step near a null, so neither it nor the unwrapped measured track can be
        # trusted beyond a whole period. Its RD residuals are taken modulo the wavelength (circular).
        multipath = config.filter_multipath
        self.correction_period = config.wavelength if multipath == "phasor" else None
        self.ripple = self.correction_period is not None
        # The source stays in the water column: the filter's motion reflects where the world's does. Not
        # yet under the phasor model, whose tracks near the surface it unsettled (static sources, tuning
        # seeds 10000-10019: 10-11 of 20 found against 13).
        depth_bounds = None if self.ripple else (region.z_min, region.z_max)
        limit = config.filter_speed_limit
        self.model = make_motion_model(f, depth_bounds, fold_trajectories=True, speed_limit=limit)
        # A whole track does reflect, even under the phasor model: its fits fold the trajectories (a source that
        # bounced off the surface margin 50 s ago otherwise pulls the fit metres off, and the robust cost hides it).
        bounds = (region.z_min, region.z_max)
        self.track_model = (
            make_motion_model(f, bounds, fold_trajectories=True, speed_limit=limit) if self.ripple else self.model
        )
        # LC-MAP fits the filter's motion model: straight lines, turns or a constant acceleration.
        self.initializer = make_initializer(config.initializer.name, config.initializer, region, self.model.name)
        self.reinitializer = LCMAPInitializer(config.initializer, region, self.model.name)
        self.wavelength = tone_period(config)
        # The filter's measurement model (p, v, p_m, v_m, p_f) -> [RD, RRD], and the one windows (LC-MAP,
        # re-seeding) are weighed with: the direct path where the filter's model has a ripple (their
        # burst R then carries the ripple as noise, ``multipath_noise``). The direct path is the function
        # itself and the phasor model an object with its Jacobians, so that neither is differenced.
        self.measurement_function: Callable[..., np.ndarray]
        if multipath == "none":
            self.measurement_function = direct_measurement
        elif multipath == "phasor":
            self.measurement_function = PhasorModel(self.propagation)
        else:
            self.measurement_function = partial(multipath_measurement, multipath, self.propagation)
        if self.ripple and config.measurement.mode == "signal" and f.frame_samples > 1 and self.wavelength:
            # The front end's RD and RRD are a frame's mean and slope: at an interference null the phasor
            # model's centre value misses them by many sd (tuning seeds 0-2: 12 % of RD frames beyond 3 sd).
            offsets = frame_offsets(config.signal.frame_duration, f.frame_samples)
            self.measurement_function = FrameAveragedPhasor(self.propagation, offsets)
        self.window_function = direct_measurement if self.ripple else self.measurement_function
        self.sigma_spread = merwe_weights(self.model.dim, f.alpha, f.beta, f.kappa)[2]
        # What the phasor model's correction adds when unresolved: LC-MAP and the re-seed windows weigh
        # every candidate with the direct path and this as extra noise (their candidates are metres apart).
        self.multipath_noise = np.zeros((2, 2))
        if self.ripple:
            self.multipath_noise = multipath_spread(
                self.propagation,
                region,
                receiver_region(config.world, receiver),
                self.fixed,
                config.source.max_speed,
                receiver.max_speed,
            )
        rate = config.measurement.rate
        self.burst_length = max(1, int(round(config.initializer.burst_duration * rate)))
        self.reinit_length = max(2, int(round(f.reinit_window * rate)))
        ini = config.initializer
        self.reseed_length = int(round(ini.reseed_until * rate)) + 1 if ini.reseed_interval > 0 else 0
        self.nis_length = max(1, int(round(f.divergence_window * rate)))
        self.search_length = int(round(SEARCH_WINDOW * rate))
        # The phasor search (:mod:`aasl_gym.search`), where only the phasor model sees the source: part of an
        # LC-MAP start (the other initializers' filters meet LC-MAP only in a recovery, and stay comparable).
        self.searches = (
            self.ripple and ini.name == "lcmap" and ini.search_spacing > 0 and self.reseed_length > self.search_length
        )
        # A bank that re-seeds recovers from an inconsistent filter by searching again; the paper's single
        # filter (``reseed_interval: 0``) re-starts instead.
        self.recovers = ini.reseed_interval > 0
        # Each sheet check refits the likeliest filter's whole track (:meth:`_check_sheets`): the history
        # then keeps an episode's measurements, not only the longest window.
        tracks = f.track_fit and (self._sheets_checkable or self.ripple)
        self.track_length = int(round(config.episode.duration * rate)) + 1 if tracks else 0
        self.prior_mean, self.prior_covariance = information_prior(config)  # what is known before any measurement
        nis_cap = RIPPLE_NIS_CAP * f.divergence_nis if self.ripple else np.inf  # as :meth:`_inconsistent` caps
        self.extra_pairs = ExtraPairs(
            self.wavelength, self.nis_length, f.divergence_nis, nis_cap, self.navigation_sd, self.residual
        )
        self.reset()

    def reset(self) -> None:
        lengths = (self.burst_length, self.reinit_length, self.reseed_length, self.track_length)
        self.history = MeasurementHistory(max(lengths))
        self.bank: list[Hypothesis] = []
        self.initialized = False
        self.first_time = np.nan
        self.last_time = np.nan
        self.reinitializations = 0
        self.last_reseed = np.nan
        self.reseeding = False  # an LC-MAP start keeps re-running LC-MAP on its growing window
        self.window_start = np.nan  # s, first measurement of that window
        self.last_track_check = -np.inf  # s
        self.last_switch = np.nan  # s, when a sheet check last replaced the bank (:meth:`_check_sheets`)
        # The last fit of the whole track (:meth:`_carried_track_fit`): its state, its time, its track's start.
        self.last_track_fit: tuple[np.ndarray, float, float] | None = None
        self.gap = False  # frames were lost since the last measurement (see :meth:`_reanchor`)
        self.range_offset = 0.0  # m added to every measured RD: whole periods the track slipped by in gaps
        self.searched_prior = False  # the phasor search from the prior ran (once an episode)
        # The phasor searches' fine candidates (from the prior, then the local and regional searches'), which every
        # re-seed refits and keeps best first.
        self.pool = np.zeros((0, self.model.dim))
        self.pool_time = np.nan  # s, when the pool's states are given
        self.last_regional_search = -np.inf  # s, a recovery's (:meth:`_search_regionally`)
        self.extra_pairs.reset()
        self.main_measurement: PairFrame | None = None  # this step's z and R_ac, which every hypothesis took

    def _sigma_measurements(
        self,
        sigmas: np.ndarray,
        position_sd: np.ndarray,
        resolved: np.ndarray,
        mobile: np.ndarray,
        mobile_velocity: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """h at the sigma points (H, S, n) of every hypothesis at once, the state's offsets b_p, b_v added,
        and the noise each adds to R_ac: the navigation term H_r Sigma_r H_r^T at the hypothesis's mean
        (row 0), and what :meth:`_sigma_model` adds for a hypothesis that cannot resolve the ripple."""
        frame_model = self.measurement_function
        if self._compiled_measurement_route(sigmas, position_sd, resolved):
            assert isinstance(frame_model, FrameAveragedPhasor) and self.correction_period is not None
            # The common step in two compiled calls, not thirty NumPy ones: the same numbers as the route below.
            state = (sigmas[..., 0:3], self.model.velocity(sigmas), mobile, mobile_velocity, self.fixed)
            frame, receiver, direct, _ = kernels.frame_and_direct(*state, frame_model.offsets, frame_model.propagation)
            return kernels.ripple_measurements(
                frame, direct, receiver[:, 0], sigmas[..., -2:], self.correction_period, self.navigation_sd
            )
        z, noise, jacobian = self._sigma_model(sigmas, position_sd, resolved, mobile, mobile_velocity, self.fixed)
        return z + sigmas[..., -2:], noise + receiver_noise(jacobian, *self.navigation_sd)

    def _compiled_measurement_route(self, sigmas: np.ndarray, position_sd: np.ndarray, resolved: np.ndarray) -> bool:
        """Whether the bank's sigma points (H, S, n) take :meth:`_sigma_measurements`' compiled route: the
        frame model and the direct path in one pass (:meth:`_one_pass_models`), every hypothesis able to resolve
        the ripple (one that cannot sends the whole bank down the NumPy route)."""
        return self._one_pass_models(sigmas[..., 0].size) and not self._coarse(position_sd, resolved).any()

    def _coarse(self, position_sd: np.ndarray, resolved: np.ndarray) -> np.ndarray:
        """Which hypotheses cannot resolve the ripple (H,): position sd (m, largest axis) above
        ``filter.ripple_lock_sd`` and no point on the ripple chosen yet (``resolved``)."""
        return (position_sd > self.config.filter.ripple_lock_sd) & ~resolved

    def _one_pass_models(self, count: int) -> bool:
        """Whether ``count`` states take the frame model and the direct path in one compiled pass
        (:func:`aasl_gym.kernels.frame_and_direct`): under the ripple, in signal mode, one pass's worth of states."""
        frame_model = isinstance(self.measurement_function, FrameAveragedPhasor)
        return self.ripple and frame_model and count <= kernels.CHUNK

    def _sigma_model(
        self,
        sigmas: np.ndarray,
        position_sd: np.ndarray,
        resolved: np.ndarray,
        mobile: np.ndarray,
        mobile_velocity: np.ndarray,
        fixed: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The filter's model of the pair with hydrophone ``fixed`` at the sigma points (H, S, n), without the
        offsets; the noise the ripple adds (H, 2, 2); the receiver Jacobian at each mean (H, 2, 6).

        Under the phasor model each sigma point's multipath correction is first taken within half a
        wavelength of the central point's (a branch cut between them is not spread). A hypothesis whose
        position sd (``position_sd``, m, largest axis) exceeds ``filter.ripple_lock_sd`` cannot resolve the
        correction's ripple, whose scale is a fraction of a wavelength, unless its point on the ripple
        was chosen (``resolved``, by a window fit or a lattice): it gets the correction at its
        mean for every sigma point, and the correction's spread over the sigma points as noise instead.
        """
        position, velocity = sigmas[..., 0:3], self.model.velocity(sigmas)
        # A model with a closed-form linearization hands over its receiver Jacobian at every sigma point with
        # its values; the central point's is the one at the mean.
        linearize = getattr(self.measurement_function, "linearize", None)
        state = (position, velocity, mobile, mobile_velocity, fixed)
        direct = None  # the direct path's values and receiver Jacobian, where the ripple needs them
        direct_receiver = np.zeros(0)
        function = self.measurement_function
        if self._one_pass_models(position[..., 0].size):
            assert isinstance(function, FrameAveragedPhasor)
            # One pass for both models: a lone filter's step spent more on two calls' set-up than on the models.
            z, receiver, direct, direct_receiver = kernels.frame_and_direct(
                *state, function.offsets, function.propagation
            )
        elif function is direct_measurement:  # compiled, values and receiver Jacobian in one pass
            z, _, receiver = kernels.direct_path(*state)
        elif linearize is None:
            z, receiver = function(*state), None
        else:
            z, _, receiver = linearize(*state)
        noise = np.zeros((len(sigmas), 2, 2))
        coarse = np.zeros(len(sigmas), dtype=bool)
        if self.ripple:
            assert self.correction_period is not None  # the ripple is the phasor model's, which has one
            if direct is None:
                direct, _, direct_receiver = kernels.direct_path(*state)
            correction = z - direct
            centre = correction[:, :1]
            offset = geometry.wrap_to_period(correction[..., 0] - centre[..., 0], self.correction_period)
            correction[..., 0] = centre[..., 0] + offset
            z = direct + correction
            coarse = self._coarse(position_sd, resolved)
            if coarse.any():
                deviation = correction[coarse, 1:] - centre[coarse]
                # The Merwe weights of rows 1..2n, 1 / (2 (n + lambda)), about the central point.
                noise[coarse] = np.einsum("hsi,hsj->hij", deviation, deviation) / (2 * self.sigma_spread)
                z[coarse] = direct[coarse] + centre[coarse]
        fine = ~coarse
        if receiver is not None:
            jacobian = receiver[:, 0].copy()
        else:  # differences of the model (a dozen evaluations a row): only for the rows that keep them
            jacobian = np.zeros((len(sigmas), 2, 6))
            if fine.any():
                at_mean = position[fine, 0], velocity[fine, 0]
                jacobian[fine] = receiver_jacobian(self.measurement_function, *at_mean, mobile, mobile_velocity, fixed)
        if coarse.any():  # under the ripple alone, where the direct path's came with its values
            jacobian[coarse] = direct_receiver[coarse, 0]
        return z, noise, jacobian

    def residual(self, measured: np.ndarray, predicted: np.ndarray) -> np.ndarray:
        """z - h, with the RD part modulo the wavelength under the phasor model (see ``correction_period``); the
        filters' update takes it in its compiled form (:func:`aasl_gym.kernels.unscented_update`)."""
        difference = measured - predicted
        if self.correction_period is not None:
            difference[..., 0] = geometry.wrap_to_period(difference[..., 0], self.correction_period)
        return difference

    def _burst(self, length: int, fine: bool = False) -> Burst:
        """The last ``length`` measurements as a :class:`Burst`, weighed with the window model
        (``window_function``, the ripple as noise) or, ``fine``, with the filter's own model."""
        # An initializer weighs a burst with one R: the rows' own when they share it, else their mean
        # (signal mode: R follows each frame's SNR, which changes slowly over a burst).
        times, z, positions, velocities, noise = self.history.columns(length)
        model = self.measurement_function if fine else self.window_function
        noise = noise if fine else noise + self.multipath_noise
        return Burst(
            times,
            z,
            positions,
            velocities,
            self.fixed,
            noise,
            self.wavelength,
            model,
            self.correction_period,
            self.navigation_sd,
            robust=self.ripple,
        )

    def _reachable(self, time: float) -> Box:
        """Where the source can be at ``time``: the start region grown by the fastest plausible travel."""
        return replace(self.region, radius=self._reachable_radius(time))

    def _reachable_radius(self, time: float) -> float:
        """m, the radius of :meth:`_reachable` (what every update's plausibility test needs of it)."""
        return self.region.radius + self.config.initializer.max_source_speed * (time - self.first_time)

    def _lcmap_at(self, time: float) -> LCMAPInitializer:
        """LC-MAP for a re-start or re-seed at ``time``, bounded by where the source can be by then."""
        self.reinitializer.region = self._reachable(time)
        return self.reinitializer

    def _start(self, initializer, length: int, rng: np.random.Generator) -> None:
        burst = self._burst(length)
        estimate = initializer(burst, rng)
        self.reseeding = isinstance(initializer, LCMAPInitializer) and self.reseed_length > 0
        self.window_start = burst.times[0]
        time = self.history[-1][0]
        self.bank = [
            self._hypothesis(*self._embed(estimate, i), log_weight, time)
            for i, log_weight in enumerate(estimate.log_weights)
        ]
        self.initialized = True
        self.last_reseed = time

    def _embed(self, estimate, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Hypothesis ``index`` of an initializer's estimate in the filter's layout, with the turn rate or
        acceleration LC-MAP fitted (zero, with the broad sd of ``EXTRA_STATE_SD``, if none was)."""
        extra, extra_sd = 0.0, EXTRA_STATE_SD[self.model.name]
        ini = self.config.initializer
        if self.model.name == "ctrv" and estimate.turn_rates is not None:
            extra = estimate.turn_rates[index]
            extra_sd = 2 * ini.max_turn_rate / max(ini.turn_rate_steps - 1, 1)  # the grid's spacing
        elif self.model.name == "ca" and estimate.accelerations is not None:
            extra = estimate.accelerations[index]
        return self.model.embed(estimate.states[index], estimate.covariances[index], extra_sd, extra)

    def _hypothesis(self, x: np.ndarray, covariance: np.ndarray, log_weight: float, time: float) -> Hypothesis:
        """A fresh UKF at (x, covariance) in the model's layout, started at ``time``."""
        f = self.config.filter
        ukf = UnscentedKalmanFilter(self.model, f.alpha, f.beta, f.kappa)
        ukf.initialize(x, covariance)
        return Hypothesis(ukf, float(log_weight), time, deque(maxlen=self.nis_length))

    def _reseed_due(self, time: float) -> bool:
        """A scheduled re-seed: every ``reseed_interval`` while the window since the LC-MAP start grows."""
        ini = self.config.initializer
        return self.reseeding and self._growing(time) and time - self.last_reseed >= ini.reseed_interval - 1e-9

    def _growing(self, time: float) -> bool:
        """Whether the window since the LC-MAP start (or the last jump) is still growing: at most ``reseed_until``."""
        return time - self.window_start <= self.config.initializer.reseed_until + 1e-9

    def _samples_since(self, start: float) -> int:
        """How many of the kept measurements were taken at or after ``start`` (s)."""
        return self.history.count_since(start)

    def _window_length(self, time: float) -> int:
        """Samples of the re-seed window: since the LC-MAP start, at most the last ``reseed_until`` seconds."""
        return self._samples_since(max(self.window_start, time - self.config.initializer.reseed_until))

    def _window_chi_square(self, burst: Burst, states: np.ndarray) -> np.ndarray:
        """Chi-square of ``burst`` for model states (H, dim) given at its last time, each run back
        along its own motion model: puts running filters and fresh candidates on one scale. Each sample
        is weighed with the state's own R_eff there (the navigation term depends on where the source is);
        a robust burst sums the soft-L1 loss instead of the squares."""
        whitened = whitened_residuals(burst, self.model, states)
        velocity_prior = np.sum(self.model.velocity(states) ** 2, axis=1) / self.config.initializer.velocity_prior_sd**2
        return np.sum(robust_loss(whitened**2, burst.robust), axis=(1, 2)) + velocity_prior

    def _reseed(self, time: float, rng: np.random.Generator, inflation: float = 1.0, length: int | None = None) -> bool:
        """Run LC-MAP on the last ``length`` samples (the growing window of :meth:`_window_length` if
        None); its hypotheses compete with the filters. True if the likeliest hypothesis afterwards is
        a fresh one (the tracker jumped).

        Two seconds rarely show where on its sheet the source lies, so the first bank often has no
        hypothesis near the truth; a longer window does. Running filters and fresh candidates are
        weighed on the same window (its chi-square). Under the phasor model a fresh candidate on a
        running filter's sheet and within ``separation`` of it is dropped: the window weighs it with the
        direct path, the filter resolves the ripple. (In the free field the fresh one may win: the
        window fit uses all of its samples, the filter forgets through its process noise; keeping the
        filter there delayed convergence of CV sources by 36 s on average, 30 tuning seeds.)
        Under the phasor model a running filter that resolved the ripple always competes and is refitted
        with the phasor model as it is (:meth:`_fit_window`); the bank keeps at most
        ``initializer.hypotheses`` of the fits.
        The running filters' covariances are multiplied by ``inflation`` (a re-seed because they turned
        inconsistent lets them re-adapt).
        """
        self.last_reseed = time
        burst = self._burst(min(length or self._window_length(time), len(self.history)))
        running = [(h.ukf.x, h.ukf.P * inflation) for h in self.bank]
        chi_square = self._window_chi_square(burst, np.array([x for x, _ in running]))
        candidates: list[tuple[np.ndarray, np.ndarray]] = running
        if length is not None or not self._explained(burst, chi_square):
            fresh = self._lcmap_at(time)(burst, rng)
            embedded = [self._embed(fresh, i) for i in range(len(fresh.states))]
            chi_square = np.concatenate(
                [chi_square, self._window_chi_square(burst, np.array([x for x, _ in embedded]))]
            )
            candidates = running + embedded
        states = np.array([x for x, _ in candidates])
        base = states[:, self.model.base_index]
        separation = self.reinitializer.separation
        duplicate = self._next_to_running(base, len(running)) if self.ripple else np.zeros(len(candidates), dtype=bool)
        order = [i for i in np.argsort(chi_square, kind="stable") if np.isfinite(chi_square[i]) and not duplicate[i]]
        limit = self.config.initializer.hypotheses
        kept = distinct_hypotheses(order, base[:, :3], base[:, 6], limit, separation, self.wavelength)
        if not kept:
            return False
        if not self.config.filter.window_fit:
            self.bank = [
                self._hypothesis(*candidates[i], -0.5 * (chi_square[i] - chi_square[kept[0]]), time) for i in kept
            ]
            return kept[0] >= len(running)
        # A filter that resolved the ripple competes whatever the coarse ranking (which cannot tell it from
        # candidates metres off) and the diversity cut say.
        resolved_running = [i for i, h in enumerate(self.bank) if h.resolved and np.isfinite(chi_square[i])]
        kept += [i for i in resolved_running if i not in kept]
        resolved = [j for j, i in enumerate(kept) if i in resolved_running]
        pool = self._pool_at(time)
        fits = self._fit_window(len(burst.times), states[kept], resolved, pool)
        self._bank_from_fits(fits[:limit], time)
        if length is None and burst.times[0] <= self.window_start + 1e-9:  # the window holds the whole track
            self._remember_track_fit(fits[0][1], time)
        index = fits[0][0]
        return index < 0 or kept[index] >= len(running)

    def _explained(self, burst: Burst, chi_square: np.ndarray) -> bool:
        """Whether a running filter explains a scheduled re-seed's window: its window cost (``chi_square``,
        one per running filter) below the ``initializer.reseed_search_quantile`` quantile of the chi-square
        distribution with one degree of freedom per measurement (and, under the phasor model, the likeliest
        filter has resolved the ripple). Then LC-MAP's fresh search is skipped and the re-seed refits the
        running filters (and the phasor search's pool) alone. Its fresh candidates seldom beat a filter that
        explains the window; skipping them halved the free field's episode time and changed no outcome on
        tuning seeds (session 13, ``benchmarks/tracker_check.py``). A window under ``FRESH_SEARCH_UNTIL`` is
        never taken as explained."""
        quantile = self.config.initializer.reseed_search_quantile
        early = burst.times[-1] - burst.times[0] < FRESH_SEARCH_UNTIL - 1e-9
        if quantile == 0 or early or (self.ripple and not self.bank[0].resolved):
            return False
        return bool(np.min(chi_square) < stats.chi2.ppf(quantile, burst.measurements.size))

    def _pool_at(self, time: float) -> np.ndarray | None:
        """The phasor search's pool (:mod:`aasl_gym.search`) carried to ``time``, for a re-seed's fine fit;
        None where there is no search or once the pool is spent. The search from the prior runs once an
        episode (:meth:`_search_prior`); while the growing window since the last start or jump is under
        ``search.LOCAL_UNTIL``, a re-seed (a recovery's too) searches about the likeliest filter as well."""
        if not self.searches:
            return None
        if not self.searched_prior and self.window_start <= self.first_time + 1e-9:
            if self._window_length(time) < self.search_length:
                return None
            self._search_prior(time)
        elif self.searched_prior and self.bank and time - self.window_start <= LOCAL_UNTIL + 1e-9:
            self._search_locally(time)
        return self._carried_pool(time) if len(self.pool) else None

    def _carried_pool(self, time: float, count: int | None = None) -> np.ndarray:
        """The best ``count`` (all if None) of the pool run along the motion model to ``time``."""
        return self.model.trajectory(self.pool[:count], np.array([time - self.pool_time]))[:, 0]

    def _search_prior(self, time: float) -> None:
        """The search from the prior on the first ``SEARCH_WINDOW`` seconds of the growing window the
        episode's first start opened, latest first: the fits' states are given at its first sample, where the
        source is within ``source.initial_radius`` of its centre but for ``initializer.max_source_speed``
        since the episode began (a lattice a third the size of one at the window's end)."""
        self.searched_prior = True
        window = self._burst(self._window_length(time), fine=True)
        first = select_samples(window, slice(self.search_length - 1, None, -1))
        start = first.times[-1]
        ini = self.config.initializer
        radius = self.config.source.initial_radius + ini.max_source_speed * start
        reach = Box(radius, self.region.z_min, self.region.z_max)
        lattice = prior_lattice(reach, ini.search_spacing, np.asarray(self.config.source.initial_centre))
        starts = self._starts_at_rest(lattice)
        self.pool = search(first, self.model, starts, self._window_prior, RIPPLE_GATE * first.measurements.size)
        self.pool_time = start
        logger.debug("t = %.1f s: the phasor search keeps %d candidates", time, len(self.pool))

    def _search_locally(self, time: float) -> None:
        """The phasor search about the likeliest filter on the last ``SEARCH_WINDOW`` seconds; at most
        ``LOCAL_POOL`` of its finds join the pool, led in (:meth:`_lead_in`). A filter 2-4 m off the source can sit
        in a dip that explains the growing window; the truth's own dip is then within reach of a short window's fit."""
        x = self.ukf.x
        lattice = local_lattice(x[0:3], LOCAL_HALF_WIDTH, LOCAL_SPACING)
        starts = np.repeat(x[None], len(lattice), axis=0)
        starts[:, 0:3] = lattice
        found = self._lead_in(self._search_recent(starts)[:LOCAL_POOL], time)
        carried = self._carried_pool(time, SEARCH_POOL - len(found)) if len(self.pool) else found[:0]
        self.pool, self.pool_time = np.concatenate([carried, found]), time

    def _lead_in(self, finds: np.ndarray, time: float) -> np.ndarray:
        """``finds`` (F, n; states at the latest sample) of a search of the last ``SEARCH_WINDOW`` seconds, fitted on
        the last ``search.LEAD_IN`` seconds of the growing window where the growing window is longer; same order, not
        gated (the re-seed that refits them gates them). A short window's basins are wide, a long one's narrow: fitted
        on the whole window at once, a find next to the source can land in a wrong dip (spiral CTRV tuning seed 20160
        at 97 s: the local search found a candidate 0.07 m off the source, and no fit of the re-seed's 45 s window
        came within 3.5 m of the source). In a recovery, too, the finds are led in on the growing window, though the
        recovery's re-seed refits the pool on its last ``filter.reinit_window`` seconds."""
        if not len(finds):
            return finds
        # The whole growing window, cut after: the burst's R is its rows' mean, as in the re-seed's fit.
        burst = self._burst(self._window_length(time), fine=True)
        if burst.times[-1] - burst.times[0] <= LEAD_IN + 1e-9:
            return finds
        recent = subsample(recent_samples(burst, LEAD_IN), RIPPLE_SAMPLES)
        prior_mean, prior_sd = self._window_prior(finds)
        return fit_window(recent, self.model, finds, prior_mean, prior_sd, robust=True).states

    def _search_regionally(self, time: float) -> None:
        """In a recovery, the phasor search of the last ``SEARCH_WINDOW`` seconds from a lattice (at rest) filling
        the ball of ``search.REGIONAL_RADIUS`` about the likeliest filter, at most every ``search.REGIONAL_COOLDOWN``
        seconds and once the search from the prior has run; at most ``LOCAL_POOL`` of its finds lead the pool that
        the recovery's re-seed refits. The local cube reaches 3 m, while a filter that never found its source
        (spiral CTRV tuning seeds) sat 4-40 m off it, where its track searches and recoveries found only nearby
        dips."""
        if not (self.searches and self.searched_prior) or time - self.last_regional_search < REGIONAL_COOLDOWN:
            return
        self.last_regional_search = time
        ball = Box(REGIONAL_RADIUS, self.region.z_min, self.region.z_max)
        starts = self._starts_at_rest(prior_lattice(ball, self.config.initializer.search_spacing, self.ukf.x[0:3]))
        found = self._search_recent(starts)
        carried = self._carried_pool(time) if len(self.pool) else found[:0]
        self.pool = np.concatenate([found[:LOCAL_POOL], carried])[:SEARCH_POOL]
        self.pool_time = time

    def _search_recent(self, starts: np.ndarray) -> np.ndarray:
        """The phasor search (:func:`~aasl_gym.search.search`) of the last ``SEARCH_WINDOW`` seconds from
        ``starts`` (S, n) at the latest sample: its fine candidates there, best first."""
        burst = self._burst(min(self.search_length, len(self.history)), fine=True)
        return search(burst, self.model, starts, self._window_prior, RIPPLE_GATE * burst.measurements.size)

    def _starts_at_rest(self, positions: np.ndarray) -> np.ndarray:
        """Search starts (N, n) at ``positions`` (N, 3; m), at rest, the RD offset at the track's whole-period
        ``range_offset`` (the searches' velocity solve finds the motion)."""
        starts = np.zeros((len(positions), self.model.dim))
        starts[:, 0:3], starts[:, -2] = positions, self.range_offset
        return starts

    @property
    def _sheets_checkable(self) -> bool:
        """Whole-period sheets are told apart by the windows: a tone, and RD residuals that are not
        circular (under the phasor model a window cannot see b_p +- one wavelength)."""
        return self.wavelength is not None and not self.ripple

    def _track_check_due(self, time: float) -> bool:
        """A check of the track (:meth:`_check_track`) every ``filter.sheet_check_interval`` once the
        growing window's re-seeding is over (it weighs every sheet and refits the track itself)."""
        interval = self.config.filter.sheet_check_interval
        return (
            self.recovers
            and interval > 0
            and (self._sheets_checkable or self.track_length > 0)
            and not self._growing(time)
            and time - self.last_track_check >= interval - 1e-9
        )

    def _check_track(self, time: float) -> bool:
        """The whole-period sheets where the windows tell them apart (:meth:`_check_sheets`; True if the
        tracker switched), else the phasor model's track refit (:meth:`_refit_track`)."""
        self.last_track_check = time
        if self._sheets_checkable:
            return self._check_sheets(time)
        self._refit_track(time)
        return False

    def _remember_track_fit(self, state: np.ndarray, time: float) -> None:
        """Keep ``state``, a fit of this track's whole window given at ``time``, for :meth:`_carried_track_fit`."""
        self.last_track_fit = (state.copy(), time, self.window_start)

    def _adopt_track_fit(self, ukf: UnscentedKalmanFilter, state: np.ndarray, covariance: np.ndarray, time: float):
        """The filter ``ukf`` restarts at a fit of its whole track (given at ``time``), which is remembered."""
        ukf.initialize(state, covariance)
        self._remember_track_fit(state, time)

    def _carried_track_fit(self, time: float) -> np.ndarray:
        """The last fit of this track's whole window - a re-seed's best on the growing window, or an adopted
        track fit - carried along the motion model to ``time``: (1, n), or (0, n) if there is none."""
        if self.last_track_fit is None or self.last_track_fit[2] != self.window_start:
            return np.zeros((0, self.model.dim))
        state, fitted_at, _ = self.last_track_fit
        return self.track_model.trajectory(state[None], np.array([time - fitted_at]))[:, 0]

    def _refit_track(self, time: float) -> None:
        """Under the phasor model, the likeliest filter - once it resolved the ripple - adopts the fine fit
        of its whole track since its start, if that fit explains the track (the fine gate). Two starts: the
        filter, and the last adopted fit carried along the motion model. A 100 s phasor window's basin is a
        few mm/s in velocity, and the filter's own velocity, wandering with its process noise, can lie
        outside it (tuning seeds: a start 7 cm off fell into a dip 0.6 m off); the carried fit, which
        explained the track 10 s ago, does not. Where even the better of the two explains the track poorly,
        the track search looks about the filter (:meth:`_search_track`). The fit adopted is folded into the
        water column: the track's trajectories fold at its bounds, the filter's do not."""
        hypothesis = self.bank[0]
        if not hypothesis.resolved:
            return
        starts = np.concatenate([hypothesis.ukf.x[None], self._carried_track_fit(time)])
        burst = self._burst(self._samples_since(self.window_start), fine=True)
        prior_mean, prior_sd = self._window_prior(starts)
        fit = fit_window(burst, self.track_model, starts, prior_mean, prior_sd, robust=True)
        best = int(np.argmin(fit.costs))
        if self.config.filter.track_search and not fit.costs[best] <= TRACK_SEARCH_GATE * burst.measurements.size:
            fit, best = self._search_track(burst, hypothesis.ukf.x, fit, best)
        if not fit.costs[best] <= RIPPLE_GATE * burst.measurements.size:
            return
        state, information = self.track_model.fold_states(fit.states[best : best + 1], fit.information[best : best + 1])
        covariance = _covariances(information, self.config.initializer.covariance_inflation)[0]
        self._adopt_track_fit(hypothesis.ukf, state[0], covariance, time)

    def _search_track(self, burst: Burst, state: np.ndarray, refit: WindowFit, best: int) -> tuple[WindowFit, int]:
        """The track search (:func:`aasl_gym.search.search_track`) about the filter's ``state``, where the track
        refit (``refit``, its ``best`` fit) explains the track poorly: its best fit replaces the refit's if it
        explains the track better. A CV filter on a parked source drifts, and the refit from its state can stay
        in a wrong dip (spiral tuning seed 20015 at 88 s: the refit 1.2 m off at 0.78 per residual, the
        search's fit 0.05 m off at 0.62)."""
        found = search_track(burst, self.track_model, state, self._window_prior)
        costs = np.where(np.isfinite(found.costs), found.costs, np.inf)
        winner = int(np.argmin(costs))
        if not costs[winner] < refit.costs[best]:
            return refit, best
        logger.debug("the track search moved the filter %.2f m", np.linalg.norm(found.states[winner, 0:3] - state[0:3]))
        return found, winner

    def _sheet_neighbours(self, x: np.ndarray) -> np.ndarray:
        """``x`` moved onto the two neighbouring whole-period sheets (2, n): b_p -+ one wavelength, the position
        with it (:meth:`_bias_moved`)."""
        assert self.wavelength is not None  # only when the sheets are checkable: a tone
        return np.stack([self._bias_moved(x, periods * self.wavelength) for periods in (1.0, -1.0)])

    def _bias_moved(self, x: np.ndarray, shift: float) -> np.ndarray:
        """``x`` with b_p lowered by ``shift`` (m) and the position moved along the direct RD's gradient (Newton steps
        at the latest receiver position) so that the predicted RD + b_p stays what it was."""
        mobile = self.history[-1][2]
        moved = x.copy()
        moved[-2] -= shift
        target = geometry.range_difference(x[0:3], mobile, self.fixed) + shift
        for _ in range(3):
            (to_mobile, unit_mobile), (to_fixed, unit_fixed) = (
                geometry.ranges(moved[0:3], r) for r in (mobile, self.fixed)
            )
            gradient = unit_mobile - unit_fixed  # d RD / d p
            moved[0:3] += gradient * (target - (to_mobile - to_fixed)) / max(gradient @ gradient, 1e-6)
        return moved

    def _onto_sheets(self, states: np.ndarray) -> np.ndarray:
        """Window-fit starts (C, n) whose b_p lies further from the sheet a fit holds it to (:meth:`_sheet_of`) than
        ``SHEET_REACH`` of the prior's sd, moved onto that sheet (:meth:`_bias_moved`); the others as they are.
        The prior's 1 mm puts b_p on the sheet in a step, while the position, whose steps are capped, cannot follow
        in a fit's eight: naive's filter (free field, tuning seed 1065 CTRV, at 24 s 29 m off with b_p 0.54 m from
        its nearest sheet) gave fits on the sheets 36 m off, the sheet check switched to them, and the tracker
        re-started every 5 s until 75 s (11 times)."""
        sheets = self._sheet_of(states[:, -2])
        off = np.abs(states[:, -2] - sheets) > SHEET_REACH * self.config.initializer.range_bias_sd
        if not off.any():
            return states
        moved = states.copy()
        for i in np.flatnonzero(off):
            moved[i] = self._bias_moved(states[i], states[i, -2] - sheets[i])
        return moved

    def _check_sheets(self, time: float) -> bool:
        """Whether the likeliest filter sits on a wrong whole-period sheet: it and its two neighbours
        (:meth:`_sheet_neighbours`) are refitted (:meth:`_fit_window`) on its whole track since its start
        (``filter.track_fit``; else on the last ``reseed_until`` seconds); if a neighbour explains that
        better by more than the pruning ratio, the bank is replaced by the fits (a re-initialization;
        True). Otherwise, with ``track_fit``, the likeliest filter adopts its own fit.

        A filter on a neighbouring sheet explains each new measurement almost as well as the truth, so its
        innovations stay consistent and no recovery starts; a long window tells the sheets apart. And the
        world's motions are deterministic, so the whole track's fit is the efficient estimate (on 24 CV
        tuning seeds it ended within 3 cm of the fit started at the truth), while the filter's process
        noise forgets the early, close-range data of a source that has since moved 100 m away."""
        states = np.concatenate([self.ukf.x[None], self._sheet_neighbours(self.ukf.x), self._carried_track_fit(time)])
        since = self.window_start if self.track_length else time - self.config.initializer.reseed_until
        length = self._samples_since(since)
        fits = self._fit_window(length, states)
        # The filter's own sheet: itself and (index 3, after the two neighbours) the last whole-track fit carried on.
        running = next(fit for fit in fits if fit[0] in (0, 3))
        if running[3] > -self.config.filter.prune_log_ratio:
            if self.track_length:
                state, covariance = self._with_earlier(running[1], running[2], length)
                self._adopt_track_fit(self.ukf, state, covariance, time)
            return False
        logger.debug("t = %.1f s: a neighbouring whole-period sheet explains the window better; switching", time)
        self._bank_from_fits(fits[: self.config.initializer.hypotheses], time)
        self.last_switch = time
        return True

    def _with_earlier(self, state: np.ndarray, covariance: np.ndarray, length: int) -> tuple[np.ndarray, np.ndarray]:
        """After a re-start the track is the measurements since it (``length``, of which ``state`` is the fit): the
        whole history's fit from ``state`` instead, with its covariance, where the earlier measurements agree with it
        (they add at most the ``EARLIER_QUANTILE`` quantile of chi-square to the cost, and the fit stays in the track
        fit's region of that quantile). The first seconds, at close range, carry much of an episode's information:
        on tuning seeds re-started at 12 and 17 s (1323, 1195) the filter ended 1.0 and 1.4 m off, the whole
        history's fit 0.16 m."""
        earlier = len(self.history) - length
        if earlier <= 0 or not np.all(np.isfinite(covariance)):
            return state, covariance
        whole = self.fit_kept_track(state[None])  # sheet checks run without the ripple: the same models and prior
        covariance_whole = _covariances(whole.information, self.config.initializer.covariance_inflation)[0]
        both = np.stack([state, whole.states[0]])
        track_costs = fit_window(self._burst(length), self.model, both, *self._window_prior(both), iterations=0).costs
        agree = whole.costs[0] - track_costs[0] <= stats.chi2.ppf(EARLIER_QUANTILE, 2 * earlier)
        # ...and refine the track's fit rather than move it: within the track's own likelihood region of that quantile
        # (a speed-limited CA's whole history let a fit run 22 m off at no cost the chi-square would see, tuning seed
        # 1016). The region of the likelihood itself, not of the fit's covariance: far from the pod the cost's valley
        # curves, and the covariance's ellipse left out whole-history fits 0.2-0.6 m off that the track's own samples
        # found 10 worse than its fit 5 m off (tuning seed 1333 CV, 46-69 against 26 in the ellipse's measure).
        near = track_costs[1] - track_costs[0] <= stats.chi2.ppf(EARLIER_QUANTILE, len(state))
        if not (agree and near and np.all(np.isfinite(covariance_whole))):
            return state, covariance
        return whole.states[0], covariance_whole

    def _next_to_running(self, base: np.ndarray, running: int) -> np.ndarray:
        """Which of the states ``base`` (H, 8) after the first ``running`` lie on a running one's sheet
        (range biases within half a wavelength) and within LC-MAP's ``separation`` of it."""
        tolerance = 0.5 * self.wavelength if self.wavelength else np.inf
        same_sheet = np.abs(base[:, None, 6] - base[None, :running, 6]) < tolerance
        near = np.linalg.norm(base[:, None, :3] - base[None, :running, :3], axis=-1) < self.reinitializer.separation
        duplicate = np.any(same_sheet & near, axis=1)
        duplicate[:running] = False
        return duplicate

    def _fit_window(
        self,
        length: int,
        states: np.ndarray,
        resolved_starts: Sequence[int] | np.ndarray | None = None,
        pool: np.ndarray | None = None,
    ) -> list[tuple[int, np.ndarray, np.ndarray, float, bool]]:
        """The sliding-window MAP (:func:`aasl_gym.window.fit_window`) of the last ``length`` samples
        from each of ``states`` (H, n): (start index, state, covariance, log weight, resolved), best first.

        Under the phasor model the window is fitted twice: with the ripple as noise (robust), then the
        best ``RIPPLE_FITS`` of those with the phasor model itself. A fine fit that does not
        explain the window (robust cost per residual above ``RIPPLE_GATE``) sits in a wrong dip of the
        ripple: its coarse fit is kept instead, unresolved, after the fine fits that passed.
        ``resolved_starts`` (indices into ``states``: filters that resolved the ripple) also go to the
        fine fit as they are: the coarse fit is biased by the ripple it ignores (metres near the
        surface), and from there the fine fit can settle in a wrong dip that beats a right filter.
        So do the phasor search's ``pool`` (P, n) at the window's end (start index -1): those that pass
        become the pool (:meth:`_pool_at`). Of all fine fits that pass, those not within ``search.DISTINCT`` of a better
        one compete.
        """
        ini = self.config.initializer
        states = self._onto_sheets(states)
        prior_mean, prior_sd = self._window_prior(states)
        # Every sample: halving a 47 s window moved a CV fit from 0.17 m to 0.63 m off (the filter: 0.13 m).
        fit = fit_window(self._burst(length), self.model, states, prior_mean, prior_sd, robust=self.ripple)
        covariances = _covariances(fit.information, ini.covariance_inflation)
        order = np.argsort(fit.costs, kind="stable")
        coarse = [(i, fit.states[i], covariances[i], -0.5 * (fit.costs[i] - fit.costs[order[0]]), False) for i in order]
        if not self.ripple:
            return coarse
        burst = subsample(self._burst(length, fine=True), RIPPLE_SAMPLES)
        direct = np.array([], dtype=int) if resolved_starts is None else np.asarray(resolved_starts, dtype=int)
        pool = np.zeros((0, self.model.dim)) if pool is None else pool
        top = np.concatenate([order[:RIPPLE_FITS], direct, np.full(len(pool), -1)])
        starts = np.concatenate([fit.states[order[:RIPPLE_FITS]], states[direct], pool])
        starts_prior = np.concatenate([prior_mean[top[top >= 0]], self._window_prior(pool)[0]])
        fine = fit_window(burst, self.model, starts, starts_prior, prior_sd, robust=True)
        passed = np.flatnonzero(fine.costs <= RIPPLE_GATE * burst.measurements.size)
        if len(pool):
            from_pool = passed[top[passed] < 0]
            best = distinct_best(fine.states[from_pool], fine.costs[from_pool], SEARCH_POOL)
            self.pool = fine.states[from_pool[best]]
            self.pool_time = burst.times[-1]
        fine_covariances = _covariances(fine.information, ini.covariance_inflation)
        # A fit ten metres off can sit where the model's gradients nearly vanish and its information is singular (a
        # 2 m lake, a start 5 m above the surface): it starts no filter.
        passed = passed[np.isfinite(fine_covariances[passed]).all(axis=(1, 2))]
        if passed.size == 0:
            return coarse
        settled = top[passed]  # starts whose fine fit passed (one in a better fit's dip is resolved into it)
        # Fits from different starts in one dip are one hypothesis: a bank of copies of a filter costs as many updates
        # a step (3-6 copies through the second half of default-world CV episodes, session 28).
        passed = passed[distinct_best(fine.states[passed], fine.costs[passed], len(passed))]
        best_cost = fine.costs[passed[0]]
        resolved = [
            (top[i], fine.states[i], fine_covariances[i], -0.5 * (fine.costs[i] - best_cost), True) for i in passed
        ]
        # The coarse fits that were not resolved follow, half the pruning ratio behind the resolved ones.
        behind = -0.5 * self.config.filter.prune_log_ratio
        return resolved + [(i, x, p, w + behind, False) for i, x, p, w, _ in coarse if i not in settled]

    def _bank_from_fits(self, fits: list[tuple[int, np.ndarray, np.ndarray, float, bool]], time: float) -> None:
        """The bank becomes one fresh filter per window fit (:meth:`_fit_window`), started at ``time``."""
        self.bank = []
        for _, x, covariance, log_weight, resolved in fits:
            hypothesis = self._hypothesis(x, covariance, log_weight, time)
            hypothesis.resolved = resolved
            self.bank.append(hypothesis)

    def _window_prior(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The window fits' prior, mean (C, n) and sd (n,): slow, plausible turn rates or accelerations,
        small clock-rate bias; each start keeps its own whole-period sheet (b_p)."""
        ini = self.config.initializer
        prior_sd = np.full(self.model.dim, np.inf)
        # On components 3:6: for a speed-limited CA the velocity without the limit, which runs ahead of the
        # source's own once it reached the limit (by up to about 1.2 m/s: 0.01 m/s^2 for 120 s), while
        # :meth:`_window_chi_square` weighs the source's own.
        prior_sd[3:6] = ini.velocity_prior_sd
        if self.model.name == "ctrv":
            prior_sd[6] = ini.max_turn_rate
        elif self.model.name == "ca":
            prior_sd[6:9] = ini.acceleration_prior_sd
        prior_sd[-2:] = (self.config.wavelength if self.ripple else ini.range_bias_sd), ini.rate_bias_sd
        prior_mean = np.zeros_like(states)
        prior_mean[:, -2] = self._sheet_of(states[:, -2])
        return prior_mean, prior_sd

    def _sheet_of(self, range_bias: np.ndarray) -> np.ndarray:
        """The RD offset b_p (m) a window fit holds each start to: where it is, or, where b_p does not wander
        (``filter.range_bias_psd`` 0), the nearest whole period - what the sensor's offset is (SPEC 3). A start
        that knows no sheet (naive's, tdoa-ls's) would otherwise be held off every sheet."""
        if self.config.filter.range_bias_psd > 0 or self.ripple or not self.wavelength:
            return range_bias
        return self.wavelength * np.round(range_bias / self.wavelength)

    def _implausible(self, ukf: UnscentedKalmanFilter, time: float) -> bool:
        if not np.isfinite(ukf.x).all():
            return True
        p, v = ukf.x[0:3], self.model.velocity(ukf.x)
        slack = 10.0  # m beyond the reachable region before an estimate counts as impossible
        # Scalar math: this runs on every hypothesis at every update.
        return bool(
            math.hypot(p[0], p[1]) > self._reachable_radius(time) + slack
            or not self.region.z_min - slack <= p[2] <= self.region.z_max + slack
            or math.sqrt(v @ v) > 2 * self.config.initializer.max_source_speed
        )

    def _inconsistent(self, hypothesis: Hypothesis, time: float) -> bool:
        if time - hypothesis.started < self.config.filter.reinit_cooldown or len(hypothesis.nis) < self.nis_length:
            return False
        nis = np.asarray(hypothesis.nis)
        if self.ripple:
            # A frame at an interference null can miss by many sd: one such frame must not decide.
            nis = np.minimum(nis, RIPPLE_NIS_CAP * self.config.filter.divergence_nis)
        return float(nis.mean()) > self.config.filter.divergence_nis

    def _assimilate(
        self, dt: float, z: np.ndarray, noise: np.ndarray, mobile: np.ndarray, mobile_velocity: np.ndarray, time: float
    ) -> None:
        """Predict every hypothesis, then update it with R_ac (``noise``) plus what its model adds (see
        :meth:`_sigma_measurements`, which serves the whole bank in one call); drop those whose
        covariance breaks or that turn implausible, and - for the paper's single filter, which has no
        re-seeding to recover with - inconsistent."""
        predicted = self._predicted_bank(dt)
        if not predicted:
            self.bank = []
            return
        sigmas = stacked([h.ukf.sigmas_f for h in predicted])  # type: ignore[misc]  # set by predict(); only read
        unresolved = [self.ripple and not h.resolved for h in predicted]
        # Only a hypothesis that has yet to resolve the ripple needs its position sd (an eigen-decomposition).
        position_sd = np.array([self._position_sd(h.ukf.P) if u else 0.0 for h, u in zip(predicted, unresolved)])
        sigma_z, extra = self._sigma_measurements(sigmas, position_sd, ~np.array(unresolved), mobile, mobile_velocity)
        if self.gap:
            z = self._reanchor(z, predicted[0].ukf, sigma_z[0], noise + extra[0])
        self.main_measurement = PairFrame(z, noise, None)
        kept = []
        updated = update_together([h.ukf for h in predicted], sigma_z, z, noise + extra, self.correction_period)
        for hypothesis in (predicted[i] for i in updated):
            ukf = hypothesis.ukf
            hypothesis.log_weight += ukf.log_likelihood
            hypothesis.nis.append(ukf.nis)
            if not (self._implausible(ukf, time) or (not self.recovers and self._inconsistent(hypothesis, time))):
                if (
                    self.ripple
                    and not hypothesis.resolved
                    and self._position_sd(ukf.P) < self.config.filter.ripple_split_sd
                ):
                    hypothesis = self._resolve_ripple(hypothesis, time)
                kept.append(hypothesis)
        self.bank = kept

    def assimilate_pairs(
        self, frames: Sequence[PairFrame], mobile: np.ndarray, mobile_velocity: np.ndarray, shared: np.ndarray
    ) -> int:
        """After :meth:`step`, update the running hypotheses with extra pairs' frames of the same step (NaN
        where a pair did not hear), as :class:`~aasl_gym.extra_pairs.ExtraPairs` tests, places and
        conditions them on the main pair's frame of the step; ``shared`` is the acoustic covariance every
        pair of the frame shares (the robot's channel). Returns how many pairs updated the likeliest
        hypothesis. Each pair's h is the main pair's model with its hydrophone, with b_v (the robot's
        clock against the facility's one clock) but not b_p."""
        if not self.initialized:
            return 0

        def model(hypothesis: Hypothesis, sigmas: np.ndarray, hydrophone: np.ndarray | None):
            if self.ripple and not hypothesis.resolved:
                return None  # too uncertain for the ripple: it sees the main pair's model coarsely, as noise
            fixed = self.fixed if hydrophone is None else hydrophone
            resolved = np.array([True])
            z, _, jacobian = self._sigma_model(sigmas[None], np.zeros(1), resolved, mobile, mobile_velocity, fixed)
            z[0, :, 1] += sigmas[:, -1]
            if hydrophone is None:
                z[0, :, 0] += sigmas[:, -2]
            return z[0], jacobian[0]

        return self.extra_pairs.assimilate(self.bank, frames, model, self.main_measurement, shared)

    def _reanchor(
        self, z: np.ndarray, ukf: UnscentedKalmanFilter, sigma_z: np.ndarray, noise: np.ndarray
    ) -> np.ndarray:
        """``z`` after a gap, its RD moved by whole wavelengths to the one the likeliest filter (``ukf``,
        its sigma points' measurements ``sigma_z``, R ``noise``) predicts, if that is sharp enough.

        A sensor unwraps the tone's RD frame to frame; across lost or undetected frames the track can
        slip by whole periods, which a filter would take for a jump of the source. Where the predicted
        RD's sd is under a quarter wavelength the prediction knows the period better than the
        unwrapper did; the offset is kept for every later measurement (and this one in the history)."""
        self.gap = False
        if self.wavelength is None:
            return z
        periods = whole_periods(z[0], sigma_z[:, 0], ukf, noise[0, 0], self.wavelength)
        if not periods:  # none, or too wide to tell
            return z
        logger.debug("the RD track slipped %+d periods across a gap; re-anchored", periods)
        self.range_offset -= periods * self.wavelength
        z = z.copy()
        z[0] -= periods * self.wavelength
        self.history.replace_last((self.history[-1][0], z) + self.history[-1][2:])
        return z

    def _coast(self, time: float, rng: np.random.Generator) -> TrackerOutput:
        """A step without a measurement (a dropped or undetected frame): the filters predict; nothing is
        kept. Before the filter starts, the burst collected so far is discarded at the next measurement
        (its RD track may have slipped across the gap)."""
        self.gap = True
        nan2 = np.full(2, np.nan)
        if not self.initialized:
            return TrackerOutput(False, False, nan2, nan2)
        self.bank = self._predicted_bank(time - self.last_time)
        self.last_time = time
        restarted = not self.bank
        if restarted:
            self._restart(time, rng)
        return TrackerOutput(True, restarted, nan2, nan2)

    def _predicted_bank(self, dt: float) -> list[Hypothesis]:
        """Every hypothesis predicted ``dt`` seconds on; one whose covariance breaks is dropped."""
        return [self.bank[i] for i in predict_together([h.ukf for h in self.bank], dt)]

    def _restart(self, time: float, rng: np.random.Generator) -> None:
        """No hypothesis is left: LC-MAP re-starts on the last ``reinit_window``; the new filters stand at
        the latest measurement's time."""
        logger.debug("every hypothesis diverged at t = %.1f s; re-initializing with LC-MAP", time)
        self.reinitializations += 1
        self._start(self._lcmap_at(time), min(self.reinit_length, len(self.history)), rng)
        self.last_time = self.history[-1][0]

    def _resolve_ripple(self, hypothesis: Hypothesis, time: float) -> Hypothesis:
        """Where a hypothesis's position sd has just fallen within reach of the ripple
        (``filter.ripple_split_sd``), pick its point on the ripple: a 3 x 3 x 3 lattice of states at 0 and
        +-1 sd along the principal axes of its position covariance, each weighed on the recent window
        (``ripple_window``) with the filter's own model and R_eff; the best continues, with the
        lattice cell (a third of the sd) as its position spread, resolving the ripple from then on."""
        ukf = hypothesis.ukf
        variances, axes = np.linalg.eigh(ukf.P[0:3, 0:3])
        steps = np.stack(np.meshgrid(*[np.array([-1.0, 0.0, 1.0])] * 3, indexing="ij"), -1).reshape(-1, 3)
        states = np.repeat(ukf.x[None], len(steps), axis=0)
        states[:, 0:3] += (steps * np.sqrt(variances)) @ axes.T
        burst = self._burst(self._samples_since(time - self.config.filter.ripple_window), fine=True)
        chi_square = self._window_chi_square(burst, states)
        best = int(np.argmin(chi_square))
        covariance = ukf.P.copy()
        shrink = axes @ np.diag(np.full(3, 1 / 3)) @ axes.T  # the cell: a third of the sd along each axis
        covariance[0:3, :] = shrink @ covariance[0:3, :]
        covariance[:, 0:3] = covariance[:, 0:3] @ shrink.T
        fresh = self._hypothesis(states[best], covariance, hypothesis.log_weight, hypothesis.started)
        fresh.nis.extend(hypothesis.nis)
        fresh.resolved = True
        return fresh

    @staticmethod
    def _position_sd(covariance: np.ndarray) -> float:
        """sd (m) of the position along its least certain axis."""
        return float(np.sqrt(np.linalg.eigvalsh(covariance[0:3, 0:3])[-1]))

    def _prune(self) -> None:
        best = max(h.log_weight for h in self.bank)
        self.bank = [h for h in self.bank if h.log_weight > best - self.config.filter.prune_log_ratio]
        for h in self.bank:
            h.log_weight -= best  # keep the weights relative, the best at 0
        self.bank.sort(key=lambda h: -h.log_weight)

    def step(
        self,
        time: float,
        z: np.ndarray,
        mobile: np.ndarray,
        mobile_velocity: np.ndarray,
        rng: np.random.Generator,
        noise_covariance: np.ndarray | None = None,
    ) -> TrackerOutput:
        """Assimilate one measurement ``z = [RD, RRD]`` taken at ``time`` with the reported receiver state;
        ``noise_covariance`` is this measurement's acoustic R (the tracker's fixed one if None); each
        hypothesis adds the navigation term at its own estimate."""
        z = np.asarray(z, dtype=float)
        self.main_measurement = None
        if not received(z):
            return self._coast(time, rng)
        if self.gap and not self.initialized:
            self.history.clear()
            self.gap = False
        z = z + [self.range_offset, 0.0]
        noise = self.noise_covariance if noise_covariance is None else np.asarray(noise_covariance, dtype=float)
        self.history.append((time, z, np.asarray(mobile, dtype=float), np.asarray(mobile_velocity, dtype=float), noise))
        self.main_measurement = PairFrame(z, noise, None)  # a start's window holds it too
        if np.isnan(self.first_time):
            self.first_time = time
        nan2 = np.full(2, np.nan)
        if not self.initialized:
            if len(self.history) >= self.burst_length:
                self._start(self.initializer, self.burst_length, rng)
            self.last_time = time
            return TrackerOutput(self.initialized, False, nan2, nan2)
        dt = time - self.last_time
        self.last_time = time
        self._assimilate(dt, z, noise, mobile, mobile_velocity, time)
        if not self.bank:
            self._restart(time, rng)
            return TrackerOutput(True, True, nan2, nan2)
        self._prune()
        jumped = False
        if self.recovers and self._inconsistent(self.bank[0], time):
            jumped = self._recover(time, rng)
        elif self._reseed_due(time):
            self._reseed(time, rng)
        elif self._track_check_due(time):
            jumped = self._check_track(time)
        self.reinitializations += jumped
        ukf = self.ukf
        return TrackerOutput(True, jumped, ukf.y.copy(), np.sqrt(ukf.S.diagonal()))

    def _recover(self, time: float, rng: np.random.Generator) -> bool:
        """The likeliest filter stopped explaining the data: search again on the recent window, at any time.
        True if the tracker jumped to a new track, whose growing window is then re-seeded as after a start."""
        logger.debug("inconsistent at t = %.1f s; re-seeding on the recent window", time)
        # A filter on a neighbouring whole-period sheet drifts off slowly: the long window tells first.
        if self._sheets_checkable and not self._switch_failed():
            if self._check_track(time):
                return True
            if self._track_explained(time):
                self._restart_clock(self.bank[0], time)
                return False
        self._search_regionally(time)
        if not self._reseed(time, rng, self.config.filter.recovery_inflation, self.reinit_length):
            return False
        self.window_start = self.history[-min(self.reinit_length, len(self.history))][0]
        self.reseeding = self.reseed_length > 0
        return True

    def _track_explained(self, time: float) -> bool:
        """Whether the likeliest filter, which the recovery's sheet check has just restarted at its track's fit,
        explains the track since its start (:meth:`_explained`) once the growing window is over: the recovery ends
        there. A filter drifts off its track's fit between checks and turns inconsistent; the fit brings it back, and
        a re-seed on the last 10 s could then jump away: free field, CV tuning seed 1375, 6 m off at 97 s after a
        bounce at the surface margin, 0.2 m after the check, 75 m after the re-seed, 5 m off at the end. While the
        window grows a fit can explain a short track from a wrong basin (the paper's multipath study, trial 800006
        at 17 s, 20 m off), and the re-seed's fresh hypotheses are what find the source."""
        if not self.track_length or self._growing(time):
            return False
        burst = self._burst(self._samples_since(self.window_start))
        return self._explained(burst, self._window_chi_square(burst, self.ukf.x[None]))

    def _restart_clock(self, hypothesis: Hypothesis, time: float) -> None:
        """``hypothesis``, restarted at a fit, is judged as a fresh filter: its cool-down and NIS window start at
        ``time`` (the NIS of the drift it was brought back from would start a recovery at every step)."""
        hypothesis.started = time
        hypothesis.nis.clear()

    def _switch_failed(self) -> bool:
        """Whether the likeliest filter, now inconsistent, is one the last sheet switch made (:meth:`_check_sheets`):
        that switch did not explain the data, and a recovery then goes straight to its re-seed. From a filter metres
        off, every sheet's fit lies metres off; switching again at every recovery, 5 s apart, kept LC-MAP from ever
        running again (naive's filter, free field, tuning seed 1046 CTRV: 16 re-starts from 22 s on, 4.3 m off at the
        end)."""
        return self.bank[0].started == self.last_switch

    def fit_kept_track(self, states: np.ndarray) -> WindowFit:
        """The MAP fit of every kept measurement (the whole episode's where the tracker keeps its track:
        ``track_length`` > 0) from each of ``states`` (C, n; the filter's layout at the last measurement's
        time), under the models, loss and window prior of the track checks (:meth:`_check_sheets`,
        :meth:`_refit_track`); a re-started track's check takes it in (:meth:`_with_earlier`). For studies: started
        at the truth, it is what an estimator that never has to search for its basin reaches
        (``benchmarks/crb_bound.py --oracle``)."""
        burst = self._burst(len(self.history), fine=self.ripple)
        prior_mean, prior_sd = self._window_prior(states)
        return fit_window(burst, self.track_model, states, prior_mean, prior_sd, robust=self.ripple)

    @property
    def ukf(self) -> UnscentedKalmanFilter:
        """The likeliest hypothesis's filter (only once initialized)."""
        return self.bank[0].ukf

    @property
    def hypotheses(self) -> int:
        return len(self.bank)

    @property
    def position(self) -> np.ndarray:
        """The likeliest hypothesis's position (m); the prior's mean until the filter starts."""
        return (self.ukf.x if self.initialized else self.prior_mean)[0:3].copy()

    @property
    def velocity(self) -> np.ndarray:
        """The likeliest hypothesis's velocity (m/s); the prior's mean until the filter starts."""
        return self.model.velocity(self.ukf.x).copy() if self.initialized else self.prior_mean[3:6].copy()

    @property
    def position_covariance(self) -> np.ndarray:
        """Its position covariance (m^2); the prior's until the filter starts."""
        return (self.ukf.P if self.initialized else self.prior_covariance)[0:3, 0:3].copy()
