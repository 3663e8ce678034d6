"""The source tracker: burst collection, initialization, the UKF, divergence detection and re-start.

One call of :meth:`SourceTracker.step` per measurement. Until the initialization burst is complete the
tracker only collects; then the chosen initializer starts the UKF. A filter that diverges - mean NIS over
a window far above its expected value of 2, a covariance that is no longer positive definite, or an
estimate far outside the physically possible region - is re-started with LC-MAP on the most recent
measurements; the step reports it. The filter never raises into the episode.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass

import numpy as np

from aasl_gym.config import EnvConfig
from aasl_gym.filters import UnscentedKalmanFilter, make_motion_model
from aasl_gym.initializers import Burst, LCMAPInitializer, make_initializer
from aasl_gym.measurements import Propagation, multipath_measurement
from aasl_gym.motion import Box

logger = logging.getLogger(__name__)

EXTRA_STATE_SD = {"cv": 0.0, "ca": 0.02, "ctrv": 0.05}  # initial sd of acceleration (m/s^2) / turn rate (rad/s)


@dataclass
class TrackerOutput:
    initialized: bool
    reinitialized: bool
    innovation: np.ndarray  # (2,), NaN before the filter runs
    innovation_sd: np.ndarray  # (2,), sqrt(diag S)


class SourceTracker:
    def __init__(self, config: EnvConfig, region: Box, noise_covariance: np.ndarray):
        self.config = config
        self.region = region
        self.noise_covariance = noise_covariance  # R_eff (or R_ac without navigation compensation)
        f = config.filter
        self.propagation = Propagation.from_config(config.world, config.source.frequency)
        self.model = make_motion_model(f)
        self.ukf = UnscentedKalmanFilter(self.model, f.alpha, f.beta, f.kappa)
        self.initializer = make_initializer(config.initializer.name, config.initializer, region)
        self.reinitializer = LCMAPInitializer(config.initializer, region)
        self.wavelength = config.wavelength if config.source.waveform == "tone" else None
        self.fixed = np.asarray(config.world.fixed_position, dtype=float)
        rate = config.measurement.rate
        self.burst_length = max(1, int(round(config.initializer.burst_duration * rate)))
        self.reinit_length = max(2, int(round(f.reinit_window * rate)))
        self.nis_window = deque(maxlen=max(1, int(round(f.divergence_window * rate))))
        self.reset()

    def reset(self) -> None:
        self.history: deque = deque(maxlen=max(self.burst_length, self.reinit_length))
        self.initialized = False
        self.time_started = np.nan
        self.last_time = np.nan
        self.reinitializations = 0
        self.nis_window.clear()

    def measurement_function(self, position, velocity, mobile, mobile_velocity, fixed) -> np.ndarray:
        return multipath_measurement(self.config.filter.multipath, self.propagation, position, velocity, mobile, mobile_velocity, fixed)

    def _hx(self, mobile: np.ndarray, mobile_velocity: np.ndarray):
        def hx(states: np.ndarray) -> np.ndarray:
            z = self.measurement_function(states[:, 0:3], states[:, 3:6], mobile, mobile_velocity, self.fixed)
            return z + states[:, -2:]

        return hx

    def _burst(self, length: int) -> Burst:
        rows = list(self.history)[-length:]
        times, z, positions, velocities = (np.array(column) for column in zip(*rows))
        return Burst(times, z, positions, velocities, self.fixed, self.noise_covariance, self.wavelength, self.measurement_function)

    def _start(self, initializer, length: int, rng: np.random.Generator) -> None:
        estimate = initializer(self._burst(length), rng)
        extra_sd = EXTRA_STATE_SD[self.model.name]
        x, covariance = self.model.embed(estimate.state, estimate.covariance, extra_sd)
        self.ukf.initialize(x, covariance)
        self.initialized = True
        self.time_started = self.history[-1][0]
        self.nis_window.clear()

    def _diverged(self, time: float) -> bool:
        if not np.all(np.isfinite(self.ukf.x)):
            return True
        p, v = self.ukf.x[0:3], self.ukf.x[3:6]
        slack = 10.0  # m beyond the region before an estimate counts as impossible
        if (
            np.hypot(p[0], p[1]) > self.region.radius + slack
            or not self.region.z_min - slack <= p[2] <= self.region.z_max + slack
            or np.linalg.norm(v) > 2 * self.config.initializer.max_source_speed
        ):
            return True
        if time - self.time_started < self.config.filter.reinit_cooldown or len(self.nis_window) < self.nis_window.maxlen:
            return False
        return float(np.mean(self.nis_window)) > self.config.filter.divergence_nis

    def step(self, time: float, z: np.ndarray, mobile: np.ndarray, mobile_velocity: np.ndarray, rng: np.random.Generator) -> TrackerOutput:
        """Assimilate one measurement ``z = [RD, RRD]`` taken at ``time`` with the reported receiver state."""
        self.history.append((time, np.asarray(z, dtype=float), np.asarray(mobile, dtype=float), np.asarray(mobile_velocity, dtype=float)))
        nan2 = np.full(2, np.nan)
        if not self.initialized:
            if len(self.history) >= self.burst_length:
                self._start(self.initializer, self.burst_length, rng)
            self.last_time = time
            return TrackerOutput(self.initialized, False, nan2, nan2)
        dt = time - self.last_time
        self.last_time = time
        try:
            self.ukf.predict(dt)
            self.ukf.update(z, self.noise_covariance, self._hx(mobile, mobile_velocity))
            self.nis_window.append(self.ukf.nis)
            diverged = self._diverged(time)
        except np.linalg.LinAlgError:
            diverged = True
        if diverged:
            logger.debug("filter diverged at t = %.1f s; re-initializing with LC-MAP", time)
            self.reinitializations += 1
            self._start(self.reinitializer, min(self.reinit_length, len(self.history)), rng)
            return TrackerOutput(True, True, nan2, nan2)
        return TrackerOutput(True, False, self.ukf.y.copy(), np.sqrt(np.diag(self.ukf.S)))

    @property
    def position(self) -> np.ndarray:
        return self.ukf.x[0:3].copy() if self.initialized else np.full(3, np.nan)

    @property
    def velocity(self) -> np.ndarray:
        return self.ukf.x[3:6].copy() if self.initialized else np.full(3, np.nan)

    @property
    def position_covariance(self) -> np.ndarray:
        return self.ukf.P[0:3, 0:3].copy() if self.initialized else np.full((3, 3), np.nan)
