"""The two measurement modes (SPEC section 3) behind one interface, :class:`Sensor`: each step the env
asks the sensor for ``z = [RD, RRD]`` (m, m/s) from the true geometry, then for the acoustic noise
covariance the filter is told for that frame and the frame's SNRs.

For a tone the RD is known only modulo one wavelength: the first value is wrapped to
[-lambda/2, lambda/2) and every later one is unwrapped to the whole number of wavelengths nearest the
previous unwrapped value (:class:`~aasl_gym.frontend.Unwrapper`), so the track carries a whole-period
offset fixed at the episode's start; the estimator holds it in its range-difference bias ``b_p``.
A lost frame (dropped by the ``fault`` option, or in signal mode one the detector does not hear) is NaN.

A facility's extra pairs (:meth:`Sensor.measure_pairs`) pair further fixed hydrophones with the robot's
hydrophone in the same frame. In signal mode they share the robot's recording, so their errors are
correlated through its channel (:meth:`Sensor.shared_covariance`); in geometric mode each is drawn alone.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from aasl_gym.config import EnvConfig
from aasl_gym.frontend import FrontEnd, Unwrapper
from aasl_gym.measurement_models import (
    Propagation,
    model_snr,
    multipath_measurement,
    robot_channel_sd,
    signal_noise_sd,
    tone_period,
)
from aasl_gym.synthesis import FrameFault


def received(z: np.ndarray) -> bool:
    """Whether a step's [RD, RRD] ``z`` is a frame: a lost one (dropped, unheard, or none yet) is NaN."""
    return bool(np.isfinite(z).all())  # the method, not np.all: this runs several times a step


@runtime_checkable
class Sensor(Protocol):
    """One measurement mode as the env drives it: :meth:`reset` at an episode's start, :meth:`measure`
    once a step; :meth:`covariance` and :meth:`snr` then describe the frame just measured."""

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """A new episode: the unwrapping starts over (and whatever the sensor draws per episode is drawn)."""

    def measure(
        self,
        rng: np.random.Generator,
        time: float,
        source_position,
        source_velocity,
        mobile,
        mobile_velocity,
        fixed,
        range_rate_bias: float = 0.0,
    ) -> np.ndarray:
        """z (m, m/s) of the frame at ``time`` (s) from the true source and receiver states (m, m/s), with
        ``range_rate_bias`` (m/s, a clock-rate offset) added to RRD; NaN for a lost frame."""

    def measure_pairs(
        self,
        rng: np.random.Generator,
        source_position,
        source_velocity,
        mobile,
        mobile_velocity,
        hydrophones: dict[int, np.ndarray],
        range_rate_bias: float = 0.0,
    ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """After :meth:`measure`, the same frame's further pairs (the true states as :meth:`measure` took
        them): the robot's hydrophone with each fixed one in ``hydrophones`` (a key, e.g. a pod's index ->
        its position (3,); m), as z and R_ac by key, each RD unwrapped on a track of its own; z is NaN where
        a pair's frame is lost."""

    def covariance(self) -> np.ndarray:
        """R_ac (2x2; m^2, m^2/s^2): the acoustic noise covariance the filter is told for the latest frame
        (the navigation term of R_eff is added by whoever uses it)."""

    def shared_covariance(self) -> np.ndarray:
        """The part of R_ac (2x2) that every pair of the latest frame shares (:meth:`measure_pairs`): the
        error of the robot's own channel."""

    def snr(self) -> np.ndarray:
        """In-band SNR (linear) of the latest frame at the (mobile, fixed) hydrophones; NaN where unknown."""


class GeometricSensor:
    """z = h(true state) + Gaussian noise of sd ``measurement.range_difference_sd`` and
    ``range_rate_difference_sd``, with the tone's whole-period ambiguity (SPEC section 3).

    With reflections on, the true [RD, RRD] is that of ``world.reflection_model``: the phasor model's by
    default (what a tone front end measures), or the reference paper's first-order (linear) model. Its
    R is that fixed noise; its SNRs are the SNR model's (:func:`~aasl_gym.measurement_models.model_snr`)
    at the frame's true geometry. A frame the ``fault`` drops is NaN (its noise is still drawn, so later
    frames match a run without it).
    """

    def __init__(self, config: EnvConfig, period: float | None):
        measurement = config.measurement
        self.config = config
        self.sd = np.array([measurement.range_difference_sd, measurement.range_rate_difference_sd])
        self.propagation = Propagation.from_config(config.world, config.source.frequency)
        self.model = config.world.reflection_model if config.world.reflections else "none"
        self.unwrapper = Unwrapper(period)
        self.pair_unwrappers = PairUnwrappers(period)
        self.fault = config.fault
        self._covariance = np.diag(self.sd**2)
        self._snr = np.full(2, np.nan)  # linear, (mobile, fixed), of the latest frame
        self.dropped = False  # the fault option dropped the latest frame

    def reset(self, rng: np.random.Generator | None = None) -> None:
        self.unwrapper.reset()
        self.pair_unwrappers.clear()

    def measure(
        self,
        rng: np.random.Generator,
        time: float,
        source_position,
        source_velocity,
        mobile,
        mobile_velocity,
        fixed,
        range_rate_bias: float = 0.0,
    ) -> np.ndarray:
        """z at ``time`` (s; the geometry is taken as given) from the true source and receiver states."""
        truth = multipath_measurement(
            self.model, self.propagation, source_position, source_velocity, mobile, mobile_velocity, fixed
        )
        noisy = truth + self.sd * rng.normal(0.0, 1.0, 2)
        self._snr = model_snr(self.config, source_position, np.array([mobile, fixed]))
        self.dropped = self.fault.active(time)
        if self.dropped:
            return np.full(2, np.nan)
        return np.array([self.unwrapper(noisy[0]), noisy[1] + range_rate_bias])

    def measure_pairs(
        self,
        rng: np.random.Generator,
        source_position,
        source_velocity,
        mobile,
        mobile_velocity,
        hydrophones: dict[int, np.ndarray],
        range_rate_bias: float = 0.0,
    ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Each further pair's z with noise of its own (this mode has no channels to share: the pairs'
        errors are independent, which a shared robot recording would not make them); lost with the frame."""
        pairs = {}
        for key, fixed in hydrophones.items():
            truth = multipath_measurement(
                self.model, self.propagation, source_position, source_velocity, mobile, mobile_velocity, fixed
            )
            noisy = truth + self.sd * rng.normal(0.0, 1.0, 2)
            z = np.full(2, np.nan) if self.dropped else self.pair_unwrappers.measurement(key, noisy, range_rate_bias)
            pairs[key] = (z, self._covariance)
        return pairs

    def covariance(self) -> np.ndarray:
        return self._covariance

    def shared_covariance(self) -> np.ndarray:
        return np.zeros((2, 2))  # each pair's noise is drawn on its own

    def snr(self) -> np.ndarray:
        return self._snr


class SignalSensor:
    """z from the acoustic front end (SPEC section 3, :mod:`aasl_gym.synthesis` and
    :mod:`aasl_gym.frontend`): one synthesized frame per step, centred on the step's time, its RD
    unwrapped like the geometric sensor's.

    It also says how noisy that z is: :meth:`covariance` is the Cramer-Rao covariance of a tone frame at
    the two channels' *measured* SNRs (:func:`~aasl_gym.frontend.tone_measurement_sd`), times
    ``signal.sd_inflation`` in sd, floored at ``signal.min_*_sd``; the env gives it to the filter as
    this step's R (plus the navigation term). A sweep or hop gets the same formula at its carrier's
    wavelength over its whole band: its delay also comes from the correlation phase, and its measured
    spread is 1.0-1.3x that sd (``tests/test_frontend.py``), within the inflation. The tone's spread is
    0.8-1.3x its bound. ``range_rate_bias`` (a clock-rate offset) is added to RRD.

    A frame is no measurement (z is NaN) when the ``fault`` option drops it (its SNRs are then NaN too),
    or when the detector does not hear the source in it (:meth:`~aasl_gym.frontend.FrontEnd.heard`: a
    channel clipped, or one whose narrowband detection statistic is below ``signal.detection_snr_db``,
    e.g. a silent hydrophone). A dropped frame is still synthesized, so that later frames see the same
    noise as without the fault.
    """

    def __init__(self, config: EnvConfig, period: float | None):
        world, source, sig = config.world, config.source, config.signal
        self.config = config
        self.front_end = FrontEnd(
            waveform_kind=source.waveform,
            frequency=source.frequency,
            path=sig.path,
            frame=sig.frame_duration,
            guard=sig.guard,
            sample_rate=sig.sample_rate,
            envelope_rate=sig.envelope_rate,
            windows=sig.windows,
            sound_speed=world.sound_speed,
            source_level_db=source.source_level_db,
            noise_level_db=world.noise_level_db,
            reflections=world.reflections,
            water_depth=world.water_depth,
            surface_reflection=world.surface_reflection,
            bed_reflection=world.bed_reflection,
            max_delay=2.5 * world.region_radius / world.sound_speed,
            detection_snr_db=sig.detection_snr_db,
        )
        self.unwrapper = Unwrapper(period)
        self.pair_unwrappers = PairUnwrappers(period)
        self.fault = config.fault
        self._snr = np.full(2, np.nan)  # linear, (mobile, fixed), of the latest frame
        self._covariance = np.diag([sig.min_range_difference_sd**2, sig.min_range_rate_difference_sd**2])
        self.dropped = False  # the latest frame was dropped (the fault option)

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """A new episode; with ``rng``, a fresh random waveform phase (else drawn at the first frame)."""
        self.unwrapper.reset()
        self.pair_unwrappers.clear()
        self.front_end.waveform, self.front_end.channel = None, None
        if rng is not None:
            self.front_end.reset(rng)

    def measure(
        self,
        rng: np.random.Generator,
        time: float,
        source_position,
        source_velocity,
        mobile,
        mobile_velocity,
        fixed,
        range_rate_bias: float = 0.0,
    ) -> np.ndarray:
        fault = self.fault if self.fault.active(time) else None
        corrupt = None
        if fault is not None and fault.kind != "dropped":  # a dropped frame is synthesized intact
            corrupt = FrameFault(fault.kind, fault.channels, fault.clip_level)
        result, self._snr, heard = self.front_end.measure(
            rng, time, source_position, source_velocity, mobile, mobile_velocity, fixed, corrupt
        )
        self._covariance = np.diag(signal_noise_sd(self.config, self._snr[0], self._snr[1]) ** 2)
        self.dropped = bool(fault and fault.kind == "dropped")
        if self.dropped:
            self._snr = np.full(2, np.nan)
            return np.full(2, np.nan)
        if not heard:
            return np.full(2, np.nan)
        return np.array([self.unwrapper(result.range_difference), result.range_rate_difference + range_rate_bias])

    def measure_pairs(
        self,
        rng: np.random.Generator,
        source_position,
        source_velocity,
        mobile,
        mobile_velocity,
        hydrophones: dict[int, np.ndarray],
        range_rate_bias: float = 0.0,
    ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Each further hydrophone's channel of the latest frame, with noise of its own, paired with that
        frame's robot channel (:meth:`~aasl_gym.frontend.FrontEnd.measure_pairs`: the robot's noise, and a
        fault on its channel, are every pair's); R_ac at each pair's measured SNRs. All are lost with a
        dropped frame; one is lost where the detector does not hear its pair."""
        keys = list(hydrophones)
        positions = np.array([hydrophones[key] for key in keys]).reshape(-1, 3)
        frames = self.front_end.measure_pairs(rng, source_position, source_velocity, positions)
        pairs = {}
        for key, (result, snr, heard) in zip(keys, frames):
            measured = np.array([result.range_difference, result.range_rate_difference])
            lost = self.dropped or not heard
            z = np.full(2, np.nan) if lost else self.pair_unwrappers.measurement(key, measured, range_rate_bias)
            pairs[key] = (z, np.diag(signal_noise_sd(self.config, *snr) ** 2))
        return pairs

    def covariance(self) -> np.ndarray:
        return self._covariance

    def shared_covariance(self) -> np.ndarray:
        """The robot channel's term of the Cramer-Rao variance (the fixed channel's SNR infinite), times
        ``signal.sd_inflation`` squared: at most any pair's R_ac, floors and all."""
        if not np.isfinite(self._snr[0]):
            return np.zeros((2, 2))
        return np.diag(robot_channel_sd(self.config, self._snr[0]) ** 2)

    def snr(self) -> np.ndarray:
        return self._snr


class PairUnwrappers(dict):
    """One :class:`~aasl_gym.frontend.Unwrapper` per further pair, by key, made at its first frame."""

    def __init__(self, period: float | None):
        super().__init__()
        self.period = period

    def measurement(self, key: int, measured: np.ndarray, range_rate_bias: float) -> np.ndarray:
        """z of pair ``key`` from its [RD, RRD] ``measured``: the RD unwrapped on its track, the bias added."""
        unwrapper = self.setdefault(key, Unwrapper(self.period))
        return np.array([unwrapper(measured[0]), measured[1] + range_rate_bias])


SENSORS: dict[str, type] = {"geometric": GeometricSensor, "signal": SignalSensor}  # by ``measurement.mode``


def make_sensor(config: EnvConfig) -> Sensor:
    """The sensor of ``config.measurement.mode``, unwrapping a tone's RD by its wavelength."""
    return SENSORS[config.measurement.mode](config, tone_period(config))
