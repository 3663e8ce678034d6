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

from aasl_gym import geometry
from aasl_gym.config import EnvConfig
from aasl_gym.filters import UnscentedKalmanFilter, make_motion_model
from aasl_gym.fisher import information_prior
from aasl_gym.initializers import Burst, LCMAPInitializer, distinct_hypotheses, make_initializer, trajectory_whitener, whiten
from aasl_gym.measurements import Propagation, multipath_measurement, receiver_jacobian, receiver_noise
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
        self.noise_covariance = noise_covariance  # R_ac, the acoustic part of R_eff
        receiver = config.receiver
        compensate = config.filter.compensate_navigation
        self.navigation_sd = (receiver.nav_position_sd, receiver.velocity_sd) if compensate else (0.0, 0.0)
        f = config.filter
        self.propagation = Propagation.from_config(config.world, config.source.frequency)
        self.model = make_motion_model(f)
        # LC-MAP fits the filter's motion model: straight lines, turns or a constant acceleration.
        self.initializer = make_initializer(config.initializer.name, config.initializer, region, self.model.name)
        self.reinitializer = LCMAPInitializer(config.initializer, region, self.model.name)
        self.wavelength = config.wavelength if config.source.waveform == "tone" else None
        # The phasor model's correction RD_app - RD is a phase difference over k, defined modulo a
        # wavelength: it jumps where a receiver's phasor sum winds round zero and swings by up to half a
        # wavelength in one step near a null, so neither it nor the unwrapped measured track can be
        # trusted beyond a whole period. Its RD residuals are taken modulo the wavelength (circular).
        self.correction_period = config.wavelength if f.multipath == "phasor" else None
        self.fixed = np.asarray(config.world.fixed_position, dtype=float)
        rate = config.measurement.rate
        self.burst_length = max(1, int(round(config.initializer.burst_duration * rate)))
        self.reinit_length = max(2, int(round(f.reinit_window * rate)))
        ini = config.initializer
        self.reseed_length = int(round(ini.reseed_until * rate)) + 1 if ini.reseed_interval > 0 else 0
        self.nis_length = max(1, int(round(f.divergence_window * rate)))
        self.prior_mean, self.prior_covariance = information_prior(config)  # what is known before any measurement
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
        """The UKF's h: under the phasor model each sigma point's multipath correction is taken within
        half a wavelength of the central point's, so that a branch cut between them cannot pose as spread."""
        def hx(states: np.ndarray) -> np.ndarray:
            z = self.measurement_function(states[:, 0:3], states[:, 3:6], mobile, mobile_velocity, self.fixed)
            if self.correction_period is not None:
                direct = geometry.range_difference(states[:, 0:3], mobile, self.fixed)
                correction = z[:, 0] - direct
                z[:, 0] = direct + correction[0] + geometry.wrap_to_period(correction - correction[0], self.correction_period)
            return z + states[:, -2:]

        return hx

    def residual(self, measured: np.ndarray, predicted: np.ndarray) -> np.ndarray:
        """z - h, with the RD part modulo the wavelength under the phasor model (see ``correction_period``)."""
        difference = measured - predicted
        if self.correction_period is not None:
            difference[..., 0] = geometry.wrap_to_period(difference[..., 0], self.correction_period)
        return difference

    def _burst(self, length: int) -> Burst:
        rows = list(self.history)[-length:]
        times, z, positions, velocities = (np.array(column) for column in list(zip(*rows))[:4])
        # An initializer weighs a burst with one R: the rows' own when they share it, else their mean
        # (signal mode: R follows each frame's SNR, which changes slowly over a burst).
        covariances = [row[4] for row in rows]
        shared = all(c is covariances[0] for c in covariances)
        noise = covariances[0] if shared else np.mean(covariances, axis=0)
        return Burst(times, z, positions, velocities, self.fixed, noise, self.wavelength, self.measurement_function,
                     self.correction_period, self.navigation_sd)

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
        along its own motion model: puts running filters and fresh candidates on one scale. Each sample
        is weighed with the state's own R_eff there (the navigation term depends on where the source is)."""
        lags = burst.times - burst.times[-1]  # <= 0
        trajectory = np.stack([self.model.transition(states, lag) for lag in lags], axis=1)  # (H, K, dim)
        position, velocity = trajectory[..., 0:3], trajectory[..., 3:6]
        predicted = self.measurement_function(
            position, velocity, burst.receiver_positions[None], burst.receiver_velocities[None], self.fixed
        ) + trajectory[..., -2:]
        whitened = whiten(trajectory_whitener(burst, position, velocity), self.residual(burst.measurements[None], predicted))
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

    def _navigation_noise(self, means: np.ndarray, mobile: np.ndarray, mobile_velocity: np.ndarray) -> np.ndarray:
        """H_r Sigma_r H_r^T (H, 2, 2) of the filter's own measurement model at each hypothesis's mean:
        the navigation term of R_eff (the paper's general form; the direct path's is nearly diagonal)."""
        position_sd, velocity_sd = self.navigation_sd
        if position_sd == 0 and velocity_sd == 0:
            return np.zeros((len(means), 2, 2))
        jacobian = receiver_jacobian(self.measurement_function, means[:, 0:3], means[:, 3:6], mobile, mobile_velocity, self.fixed)
        return receiver_noise(jacobian, position_sd, velocity_sd)

    def _assimilate(self, dt: float, z: np.ndarray, noise: np.ndarray, mobile: np.ndarray, mobile_velocity: np.ndarray, time: float) -> None:
        """Predict every hypothesis, then update it with R_eff = ``noise`` + its navigation term; drop
        those whose covariance breaks or that turn implausible or inconsistent."""
        predicted = []
        for hypothesis in self.bank:
            try:
                hypothesis.ukf.predict(dt)
            except np.linalg.LinAlgError:
                continue
            predicted.append(hypothesis)
        if not predicted:
            self.bank = []
            return
        navigation = self._navigation_noise(np.array([h.ukf.x for h in predicted]), mobile, mobile_velocity)
        hx = self._hx(mobile, mobile_velocity)
        kept = []
        for hypothesis, extra in zip(predicted, navigation):
            ukf = hypothesis.ukf
            try:
                ukf.update(z, noise + extra, hx, self.residual)
            except np.linalg.LinAlgError:
                continue
            hypothesis.log_weight += ukf.log_likelihood
            hypothesis.nis.append(ukf.nis)
            if not (self._implausible(ukf, time) or self._inconsistent(hypothesis, time)):
                kept.append(hypothesis)
        self.bank = kept

    def _prune(self) -> None:
        best = max(h.log_weight for h in self.bank)
        self.bank = [h for h in self.bank if h.log_weight > best - self.config.filter.prune_log_ratio]
        for h in self.bank:
            h.log_weight -= best  # keep the weights relative, the best at 0
        self.bank.sort(key=lambda h: -h.log_weight)

    def step(self, time: float, z: np.ndarray, mobile: np.ndarray, mobile_velocity: np.ndarray, rng: np.random.Generator,
             noise_covariance: np.ndarray | None = None) -> TrackerOutput:
        """Assimilate one measurement ``z = [RD, RRD]`` taken at ``time`` with the reported receiver state;
        ``noise_covariance`` is this measurement's acoustic R (the tracker's fixed one if None); each
        hypothesis adds the navigation term at its own estimate."""
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
        self._assimilate(dt, z, noise, mobile, mobile_velocity, time)
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
        """The likeliest hypothesis's position (m); the prior's mean until the filter starts."""
        return (self.ukf.x if self.initialized else self.prior_mean)[0:3].copy()

    @property
    def velocity(self) -> np.ndarray:
        """The likeliest hypothesis's velocity (m/s); the prior's mean until the filter starts."""
        return (self.ukf.x if self.initialized else self.prior_mean)[3:6].copy()

    @property
    def position_covariance(self) -> np.ndarray:
        """Its position covariance (m^2); the prior's until the filter starts."""
        return (self.ukf.P if self.initialized else self.prior_covariance)[0:3, 0:3].copy()
