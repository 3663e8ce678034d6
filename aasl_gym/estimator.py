"""The source tracker: burst collection, initialization, a bank of UKFs, divergence detection and re-start.

One call of :meth:`SourceTracker.step` per measurement. Until the initialization burst is complete the
tracker only collects; then the chosen initializer starts the filter. LC-MAP returns several
hypotheses - the best candidate of every feasible whole-period sheet, since a 2 s burst rarely tells
the sheets apart - and each starts a UKF of its own. Every update multiplies a hypothesis's weight by
its innovation likelihood N(y; 0, S); one that trails the best by ``filter.prune_log_ratio`` (natural
log) is dropped, and so is one whose mean NIS over ``divergence_window`` exceeds ``divergence_nis``, whose
covariance stops being positive definite, or whose estimate leaves the physically possible region.
The estimate reported is the likeliest hypothesis's. Two seconds seldom show *where* on its sheet the
source is, so after an LC-MAP start LC-MAP re-runs every ``initializer.reseed_interval`` on the growing
window, up to ``reseed_until``, fitting the filter's motion model (straight, turning or accelerating; see
:mod:`aasl_gym.initializers`), even when a filter already looks confident (a confident
filter can sit on a wrong, self-consistent solution); its fresh hypotheses and the running filters are
weighed on that window's chi-square and the best ``initializer.hypotheses`` continue. When no
hypothesis is left the tracker re-starts with LC-MAP on the most recent ``reinit_window`` of
measurements, and the step says so. The filter never raises into the episode.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from aasl_gym.config import EnvConfig
from aasl_gym.filters import UnscentedKalmanFilter, make_motion_model
from aasl_gym.initializers import Burst, LCMAPInitializer, distinct_hypotheses, make_initializer, whitener
from aasl_gym.measurements import Propagation, multipath_measurement
from aasl_gym.motion import Box

logger = logging.getLogger(__name__)

EXTRA_STATE_SD = {"cv": 0.0, "ca": 0.02, "ctrv": 0.1}  # initial sd of acceleration (m/s^2) / turn rate (rad/s)


@dataclass
class TrackerOutput:
    initialized: bool
    reinitialized: bool
    innovation: np.ndarray  # (2,), NaN before the filter runs
    innovation_sd: np.ndarray  # (2,), sqrt(diag S)


@dataclass
class Hypothesis:
    ukf: UnscentedKalmanFilter
    log_weight: float  # log likelihood of the data since its start, relative to the best hypothesis
    started: float  # s, when this hypothesis was (re)started
    nis: deque  # recent normalized innovations squared


class SourceTracker:
    def __init__(self, config: EnvConfig, region: Box, noise_covariance: np.ndarray):
        self.config = config
        self.region = region
        self.noise_covariance = noise_covariance  # R_eff (or R_ac without navigation compensation)
        f = config.filter
        self.propagation = Propagation.from_config(config.world, config.source.frequency)
        self.model = make_motion_model(f)
        # LC-MAP fits the filter's motion model: straight lines, turns or a constant acceleration.
        self.initializer = make_initializer(config.initializer.name, config.initializer, region, self.model.name)
        self.reinitializer = LCMAPInitializer(config.initializer, region, self.model.name)
        self.wavelength = config.wavelength if config.source.waveform == "tone" else None
        self.fixed = np.asarray(config.world.fixed_position, dtype=float)
        rate = config.measurement.rate
        self.burst_length = max(1, int(round(config.initializer.burst_duration * rate)))
        self.reinit_length = max(2, int(round(f.reinit_window * rate)))
        ini = config.initializer
        self.reseed_length = int(round(ini.reseed_until * rate)) + 1 if ini.reseed_interval > 0 else 0
        self.nis_length = max(1, int(round(f.divergence_window * rate)))
        self.reset()

    def reset(self) -> None:
        self.history: deque = deque(maxlen=max(self.burst_length, self.reinit_length, self.reseed_length))
        self.bank: list[Hypothesis] = []
        self.initialized = False
        self.first_time = np.nan
        self.last_time = np.nan
        self.reinitializations = 0
        self.last_reseed = np.nan
        self.reseeding = False  # an LC-MAP start keeps re-running LC-MAP on its growing window
        self.window_start = np.nan  # s, first measurement of that window

    def measurement_function(self, position, velocity, mobile, mobile_velocity, fixed) -> np.ndarray:
        return multipath_measurement(self.config.filter.multipath, self.propagation, position, velocity, mobile, mobile_velocity, fixed)

    def _hx(self, mobile: np.ndarray, mobile_velocity: np.ndarray):
        def hx(states: np.ndarray) -> np.ndarray:
            z = self.measurement_function(states[:, 0:3], states[:, 3:6], mobile, mobile_velocity, self.fixed)
            return z + states[:, -2:]

        return hx

    def _burst(self, length: int) -> Burst:
        rows = list(self.history)[-length:]
        times, z, positions, velocities = (np.array(column) for column in list(zip(*rows))[:4])
        # An initializer weighs a burst with one R: the rows' own when they share it, else their mean
        # (signal mode: R follows each frame's SNR, which changes slowly over a burst).
        covariances = [row[4] for row in rows]
        shared = all(c is covariances[0] for c in covariances)
        noise = covariances[0] if shared else np.mean(covariances, axis=0)
        return Burst(times, z, positions, velocities, self.fixed, noise, self.wavelength, self.measurement_function)

    def _reachable(self, time: float) -> Box:
        """Where the source can be at ``time``: the start region grown by the fastest plausible travel."""
        growth = self.config.initializer.max_source_speed * (time - self.first_time)
        return replace(self.region, radius=self.region.radius + growth)

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
            self._hypothesis(*self._embed(estimate, i), log_weight, time) for i, log_weight in enumerate(estimate.log_weights)
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
        ini = self.config.initializer
        return (
            self.reseeding
            and time - self.window_start <= ini.reseed_until + 1e-9
            and time - self.last_reseed >= ini.reseed_interval - 1e-9
        )

    def _window_chi_square(self, burst: Burst, states: np.ndarray) -> np.ndarray:
        """Chi-square of ``burst`` for model states (H, dim) given at its last time, each run back
        along its own motion model: puts running filters and fresh candidates on one scale."""
        lags = burst.times - burst.times[-1]  # <= 0
        trajectory = np.stack([self.model.transition(states, lag) for lag in lags], axis=1)  # (H, K, dim)
        predicted = self.measurement_function(
            trajectory[..., 0:3], trajectory[..., 3:6], burst.receiver_positions[None], burst.receiver_velocities[None], self.fixed
        ) + trajectory[..., -2:]
        whitened = (burst.measurements[None] - predicted) @ whitener(burst).T
        velocity_prior = np.sum(states[:, 3:6] ** 2, axis=1) / self.config.initializer.velocity_prior_sd**2
        return np.sum(whitened**2, axis=(1, 2)) + velocity_prior

    def _reseed(self, time: float, rng: np.random.Generator) -> None:
        """Run LC-MAP on the window since the last LC-MAP start; its hypotheses compete with the filters.

        Two seconds rarely show where on its sheet the source lies, so the first bank often has no
        hypothesis near the truth; a longer window does. Running filters and fresh candidates are
        weighed on the same window (its chi-square); near-duplicates on one sheet keep the better.
        """
        self.last_reseed = time
        burst = self._burst(sum(1 for row in self.history if row[0] >= self.window_start))
        fresh = self._lcmap_at(time)(burst, rng)
        candidates = [(h.ukf.x, h.ukf.P) for h in self.bank]
        candidates += [self._embed(fresh, i) for i in range(len(fresh.states))]
        states = np.array([x for x, _ in candidates])
        base = states[:, self.model.base_index]
        chi_square = self._window_chi_square(burst, states)
        order = [i for i in np.argsort(chi_square, kind="stable") if np.isfinite(chi_square[i])]
        kept = distinct_hypotheses(order, base[:, :3], base[:, 6], self.config.initializer.hypotheses, self.reinitializer.separation, self.wavelength)
        if kept:
            self.bank = [self._hypothesis(*candidates[i], -0.5 * (chi_square[i] - chi_square[kept[0]]), time) for i in kept]

    def _implausible(self, ukf: UnscentedKalmanFilter, time: float) -> bool:
        if not np.all(np.isfinite(ukf.x)):
            return True
        p, v = ukf.x[0:3], ukf.x[3:6]
        region = self._reachable(time)
        slack = 10.0  # m beyond the reachable region before an estimate counts as impossible
        return bool(
            np.hypot(p[0], p[1]) > region.radius + slack
            or not region.z_min - slack <= p[2] <= region.z_max + slack
            or np.linalg.norm(v) > 2 * self.config.initializer.max_source_speed
        )

    def _inconsistent(self, hypothesis: Hypothesis, time: float) -> bool:
        if time - hypothesis.started < self.config.filter.reinit_cooldown or len(hypothesis.nis) < self.nis_length:
            return False
        return float(np.mean(hypothesis.nis)) > self.config.filter.divergence_nis

    def _assimilate(self, hypothesis: Hypothesis, time: float, dt: float, z: np.ndarray, noise: np.ndarray, hx) -> bool:
        """Predict and update one hypothesis with measurement noise covariance ``noise``; False if it must be dropped."""
        ukf = hypothesis.ukf
        try:
            ukf.predict(dt)
            ukf.update(z, noise, hx)
        except np.linalg.LinAlgError:
            return False
        hypothesis.log_weight += ukf.log_likelihood
        hypothesis.nis.append(ukf.nis)
        return not (self._implausible(ukf, time) or self._inconsistent(hypothesis, time))

    def _prune(self) -> None:
        best = max(h.log_weight for h in self.bank)
        self.bank = [h for h in self.bank if h.log_weight > best - self.config.filter.prune_log_ratio]
        for h in self.bank:
            h.log_weight -= best  # keep the weights relative, the best at 0
        self.bank.sort(key=lambda h: -h.log_weight)

    def step(self, time: float, z: np.ndarray, mobile: np.ndarray, mobile_velocity: np.ndarray, rng: np.random.Generator,
             noise_covariance: np.ndarray | None = None) -> TrackerOutput:
        """Assimilate one measurement ``z = [RD, RRD]`` taken at ``time`` with the reported receiver state;
        ``noise_covariance`` is this measurement's R (the tracker's fixed one if None)."""
        noise = self.noise_covariance if noise_covariance is None else np.asarray(noise_covariance, dtype=float)
        self.history.append((time, np.asarray(z, dtype=float), np.asarray(mobile, dtype=float), np.asarray(mobile_velocity, dtype=float), noise))
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
        hx = self._hx(mobile, mobile_velocity)
        self.bank = [h for h in self.bank if self._assimilate(h, time, dt, z, noise, hx)]
        if self.bank:
            self._prune()
            if self._reseed_due(time):
                self._reseed(time, rng)
        else:
            logger.debug("every hypothesis diverged at t = %.1f s; re-initializing with LC-MAP", time)
            self.reinitializations += 1
            self._start(self._lcmap_at(time), min(self.reinit_length, len(self.history)), rng)
            return TrackerOutput(True, True, nan2, nan2)
        ukf = self.ukf
        return TrackerOutput(True, False, ukf.y.copy(), np.sqrt(np.diag(ukf.S)))

    @property
    def ukf(self) -> UnscentedKalmanFilter:
        """The likeliest hypothesis's filter (only once initialized)."""
        return self.bank[0].ukf

    @property
    def hypotheses(self) -> int:
        return len(self.bank)

    @property
    def position(self) -> np.ndarray:
        return self.ukf.x[0:3].copy() if self.initialized else np.full(3, np.nan)

    @property
    def velocity(self) -> np.ndarray:
        return self.ukf.x[3:6].copy() if self.initialized else np.full(3, np.nan)

    @property
    def position_covariance(self) -> np.ndarray:
        return self.ukf.P[0:3, 0:3].copy() if self.initialized else np.full((3, 3), np.nan)
