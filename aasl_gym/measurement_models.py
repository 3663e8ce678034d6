"""The filter's measurement models: what [RD, RRD] a source state produces and how noisy the filter
takes it to be.

``z = [RD, RRD]`` in metres and m/s (SPEC section 2). :func:`direct_measurement` is the direct path;
:func:`multipath_measurement` adds the surface and bed images under the first-order ``linear`` or the
exact narrowband ``phasor`` model; a tracker runs the latter as :class:`PhasorModel` (a geometric world's) or
:class:`FrameAveragedPhasor` (averaged over a frame, as a tone front end measures), each with its Jacobians. The
receiver Jacobians and :func:`receiver_noise` turn the robot's navigation errors into measurement noise (R_eff);
:func:`multipath_spread` is the phasor ripple a filter that cannot yet resolve it treats as noise. The noise side:
:func:`navigation_covariance`, the SNR model (:func:`model_snr`), the sd the filter is told at a frame's SNRs
(:func:`signal_noise_sd`) and the R a planner expects ahead of a frame (:func:`expected_noise_covariance`). The
sensors that produce z are in :mod:`aasl_gym.sensors`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aasl_gym import geometry, kernels
from aasl_gym.config import EnvConfig, WorldConfig
from aasl_gym.frontend import tone_measurement_sd
from aasl_gym.synthesis import carrier_frequency, receiver_band


@dataclass(frozen=True)
class Propagation:
    """What the multipath models need to know about the channel."""

    water_depth: float  # m
    surface_reflection: float
    bed_reflection: float
    wavenumber: float  # rad/m, 2 pi f0 / c

    @property
    def channel(self) -> tuple[float, float, float, float]:
        """(water_depth, surface_reflection, bed_reflection, wavenumber): the phasor model's channel arguments, in the
        order :mod:`aasl_gym.geometry`'s and :mod:`aasl_gym.kernels`' phasor functions take them."""
        return self.water_depth, self.surface_reflection, self.bed_reflection, self.wavenumber

    @classmethod
    def from_config(cls, world: WorldConfig, frequency: float) -> Propagation:
        return cls(
            world.water_depth, world.surface_reflection, world.bed_reflection, 2 * np.pi * frequency / world.sound_speed
        )


def tone_period(config: EnvConfig) -> float | None:
    """m, the period a tone's RD is known modulo (one wavelength); None for a sweep or hop (unambiguous)."""
    return config.wavelength if config.source.waveform == "tone" else None


def direct_measurement(position, velocity, mobile, mobile_velocity, fixed) -> np.ndarray:
    """Noise-free direct-path [RD, RRD], shape ``(..., 2)``."""
    # The geometry's RD and RRD, sharing the two ranges and unit vectors (this runs once per sigma point).
    distance_mobile, unit_mobile = geometry.ranges(position, mobile)
    distance_fixed, unit_fixed = geometry.ranges(position, fixed)
    rd = distance_mobile - distance_fixed
    rrd = geometry.range_rate(unit_mobile, velocity, mobile_velocity) - geometry.range_rate(
        unit_fixed, velocity, geometry.ZERO3
    )
    return np.stack([rd, rrd], axis=-1)


def multipath_measurement(
    model: str, propagation: Propagation, position, velocity, mobile, mobile_velocity, fixed
) -> np.ndarray:
    """[RD, RRD] under ``model``: ``none`` (direct path), ``linear`` (first-order) or ``phasor`` (exact tone)."""
    if model == "none":
        return direct_measurement(position, velocity, mobile, mobile_velocity, fixed)
    p = propagation
    if model == "linear":
        rd, rrd = geometry.linear_multipath(
            position, velocity, mobile, mobile_velocity, fixed, p.water_depth, p.surface_reflection, p.bed_reflection
        )
    elif model == "phasor":  # compiled: geometry.phasor_multipath to rounding, several times faster
        return kernels.phasor_measurement(position, velocity, mobile, mobile_velocity, fixed, *p.channel)
    else:
        raise ValueError(f"unknown multipath model {model!r}; allowed: ['none', 'linear', 'phasor']")
    return np.stack([rd, rrd], axis=-1)


def frame_averaged(
    range_difference_function,
    offsets: np.ndarray,
    wavenumber: float,
    position,
    velocity,
    mobile,
    mobile_velocity,
    fixed,
) -> np.ndarray:
    """[RD, RRD] (..., 2) as a tone front end measures them over one frame: the mean and the least-squares
    time slope of the RD (``range_difference_function``: (p, p_m, p_f) -> RD, m) at ``offsets`` (s, about
    the frame's centre), the source and the mobile hydrophone moving straight on at their velocities
    meanwhile; the RD track unwrapped across the offsets (wavenumber k, rad/m) as the front end unwraps its
    windows' delays.

    Where a receiver's multipath sum passes near zero its phase turns by up to pi within a frame: the
    centre's RD and instantaneous RRD then differ from the frame's mean and slope by many sd.
    """
    offsets = _check_offsets(offsets)
    velocity, mobile_velocity = np.asarray(velocity, dtype=float), np.asarray(mobile_velocity, dtype=float)
    along = offsets[:, None]
    rd = range_difference_function(
        np.asarray(position, dtype=float)[..., None, :] + along * velocity[..., None, :],
        np.asarray(mobile, dtype=float)[..., None, :] + along * mobile_velocity[..., None, :],
        fixed,
    )
    return _frame_mean_and_slope(rd, offsets, wavenumber)


def _check_offsets(offsets) -> np.ndarray:
    """``offsets`` (s) as an array, if they are two or more times about a frame's centre (a slope needs two)."""
    offsets = np.asarray(offsets, dtype=float)
    if offsets.ndim != 1 or len(offsets) < 2 or abs(offsets.mean()) > 1e-9 * np.ptp(offsets):
        raise ValueError(f"frame offsets must be two or more times about the frame's centre, got {offsets}")
    return offsets


def _frame_mean_and_slope(rd: np.ndarray, offsets: np.ndarray, wavenumber: float) -> np.ndarray:
    """[mean, least-squares slope] (..., 2) of a frame's RD track (..., S) sampled at ``offsets``,
    unwrapped across them (wavenumber k, rad/m)."""
    rd = geometry.unwrap_to_period(rd, 2 * np.pi / wavenumber)
    mean = rd.mean(axis=-1)
    slope = (rd - mean[..., None]) @ offsets / (offsets @ offsets)
    return np.stack([mean, slope], axis=-1)


def phasor_range_difference(propagation: Propagation, position, mobile, fixed) -> np.ndarray:
    """The phasor model's apparent RD (m) alone (:func:`~aasl_gym.geometry.phasor_range_difference`)."""
    return geometry.phasor_range_difference(position, mobile, fixed, *propagation.channel)


def frame_offsets(duration: float, samples: int) -> np.ndarray:
    """Centres (s) of ``samples`` equal parts of a frame of ``duration`` s, about its centre."""
    return ((np.arange(samples) + 0.5) / samples - 0.5) * duration


@dataclass(frozen=True, eq=False)
class PhasorModel:
    """The phasor model's instantaneous [RD, RRD] (:func:`multipath_measurement`'s ``phasor``, a geometric world's),
    with both of its Jacobians (:func:`aasl_gym.kernels.phasor_linearized`): R_eff's navigation term and the window's
    chi-square take them from one call instead of differencing the model in every state component, and a window fit
    runs the same model in its compiled pass (:func:`aasl_gym.kernels.fit_terms`). A measurement function:
    (p, v, p_m, v_m, p_f) -> (..., 2)."""

    propagation: Propagation

    def __call__(self, position, velocity, mobile, mobile_velocity, fixed) -> np.ndarray:
        return multipath_measurement("phasor", self.propagation, position, velocity, mobile, mobile_velocity, fixed)

    def linearize(
        self, position, velocity, mobile, mobile_velocity, fixed
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """[RD, RRD] (..., 2), d[RD, RRD] / d[p, v] and d[RD, RRD] / d[p_m, v_m] (..., 2, 6 each)."""
        return kernels.phasor_linearized(position, velocity, mobile, mobile_velocity, fixed, *self.propagation.channel)

    def state_jacobian(self, position, velocity, mobile, mobile_velocity, fixed) -> np.ndarray:
        """d[RD, RRD] / d[p, v], shape (..., 2, 6)."""
        return self.linearize(position, velocity, mobile, mobile_velocity, fixed)[1]

    def receiver_jacobian(self, position, velocity, mobile, mobile_velocity, fixed) -> np.ndarray:
        """d[RD, RRD] / d[p_m, v_m], shape (..., 2, 6)."""
        return self.linearize(position, velocity, mobile, mobile_velocity, fixed)[2]


@dataclass(frozen=True, eq=False)
class FrameAveragedPhasor:
    """The phasor model's [RD, RRD] over one frame as a tone front end measures them
    (:func:`frame_averaged` of :func:`phasor_range_difference` at ``offsets``, s), with both of its
    Jacobians in closed form. A measurement function: (p, v, p_m, v_m, p_f) -> (..., 2)."""

    propagation: Propagation
    offsets: np.ndarray

    def __post_init__(self):
        _check_offsets(self.offsets)

    def __call__(self, position, velocity, mobile, mobile_velocity, fixed) -> np.ndarray:
        return self.linearize(position, velocity, mobile, mobile_velocity, fixed)[0]

    def linearize(
        self, position, velocity, mobile, mobile_velocity, fixed
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """[RD, RRD] (..., 2), d[RD, RRD] / d[p, v] and d[RD, RRD] / d[p_m, v_m] (..., 2, 6 each) from one
        set of multipath factors: a window fit needs all three at every trial state. One compiled pass
        (:func:`aasl_gym.kernels.frame_phasor`); the tests hold it to :func:`frame_averaged`, the frame's
        mean and slope written with NumPy, and its Jacobians to central differences."""
        state = (position, velocity, mobile, mobile_velocity, fixed)
        return kernels.frame_phasor(*state, self.offsets, self.propagation)

    def state_jacobian(self, position, velocity, mobile, mobile_velocity, fixed) -> np.ndarray:
        """d[RD, RRD] / d[p, v], shape (..., 2, 6)."""
        return self.linearize(position, velocity, mobile, mobile_velocity, fixed)[1]

    def receiver_jacobian(self, position, velocity, mobile, mobile_velocity, fixed) -> np.ndarray:
        """d[RD, RRD] / d[p_m, v_m], shape (..., 2, 6)."""
        return self.linearize(position, velocity, mobile, mobile_velocity, fixed)[2]


def state_jacobian_function(measurement_function):
    """A measurement model's own d[RD, RRD] / d[p, v], (p, v, p_m, v_m, p_f) -> (..., 2, 6) - closed forms, but for
    the phasor model's RRD position columns (:func:`aasl_gym.kernels.phasor_linearized`) - or None where it has none
    (the state Jacobian is then taken by differences of the model)."""
    if measurement_function is direct_measurement:
        return geometry.direct_jacobian
    if isinstance(measurement_function, (PhasorModel, FrameAveragedPhasor)):
        return measurement_function.state_jacobian
    return None


RECEIVER_STEP = 1e-3  # m: central-difference step of the receiver Jacobian (a wavelength is 1.5 m)
RECEIVER_RATE_STEP = 1e-3  # m/s: its step in the receiver's velocity (a frame moves it by 0.1 mm)


def direct_receiver_jacobian(position, velocity, mobile, mobile_velocity) -> np.ndarray:
    """d[RD, RRD] / d[p_m, v_m] of the direct path in closed form, shape ``(..., 2, 6)``: dRD/dp_m = -u_m,
    dRD/dv_m = 0, dRRD/dv_m = -u_m, dRRD/dp_m = -(I - u_m u_m^T)(v_s - v_m) / d_m."""
    distance, unit = geometry.ranges(np.asarray(position, dtype=float), np.asarray(mobile, dtype=float))
    relative = np.asarray(velocity, dtype=float) - mobile_velocity
    along = np.einsum("...i,...i->...", relative, unit)
    jacobian = np.zeros(np.broadcast_shapes(unit.shape, relative.shape)[:-1] + (2, 6))
    jacobian[..., 0, :3] = -unit
    jacobian[..., 1, 3:] = -unit
    jacobian[..., 1, :3] = -(relative - unit * along[..., None]) / distance[..., None]
    return jacobian


def receiver_jacobian(measurement_function, position, velocity, mobile, mobile_velocity, fixed) -> np.ndarray:
    """d[RD, RRD] / d[p_m, v_m] of a measurement model, shape ``(..., 2, 6)``: the closed form for the
    direct path, the phasor models' own (:class:`PhasorModel`, :class:`FrameAveragedPhasor`), else central
    differences in the mobile hydrophone's position (``RECEIVER_STEP``) and velocity (``RECEIVER_RATE_STEP``).
    ``measurement_function`` is (p, v, p_m, v_m, p_f) -> (..., 2).

    Under multipath the apparent RD moves with the receiver's position far faster than the direct
    path's -u_m near an interference null, which is why R_eff needs the model's own H_r. A frame's
    model is not linear in the receiver's velocity (it moves the receiver across the frame), so the
    velocity is differenced too, with a small step.
    """
    if measurement_function is direct_measurement:
        return direct_receiver_jacobian(position, velocity, mobile, mobile_velocity)
    if isinstance(measurement_function, (PhasorModel, FrameAveragedPhasor)):
        return measurement_function.receiver_jacobian(position, velocity, mobile, mobile_velocity, fixed)
    position, velocity = np.asarray(position, dtype=float), np.asarray(velocity, dtype=float)
    batch = np.broadcast_shapes(
        position.shape[:-1], velocity.shape[:-1], np.shape(mobile)[:-1], np.shape(mobile_velocity)[:-1]
    )
    # Rows 0-5 move p_m by +-step along each axis, rows 6-11 move v_m by +-step.
    offsets, rate_offsets = np.zeros((12, 3)), np.zeros((12, 3))
    offsets[0:3], offsets[3:6] = RECEIVER_STEP * np.eye(3), -RECEIVER_STEP * np.eye(3)
    rate_offsets[6:9], rate_offsets[9:12] = RECEIVER_RATE_STEP * np.eye(3), -RECEIVER_RATE_STEP * np.eye(3)
    expand = (slice(None),) * len(batch) + (None,)
    z = measurement_function(
        np.broadcast_to(position, batch + (3,))[expand],
        np.broadcast_to(velocity, batch + (3,))[expand],
        np.broadcast_to(mobile, batch + (3,))[expand] + offsets,
        np.broadcast_to(mobile_velocity, batch + (3,))[expand] + rate_offsets,
        fixed,
    )  # (..., 12, 2)
    jacobian = np.empty(batch + (2, 6))
    jacobian[..., :3] = np.swapaxes(z[..., 0:3, :] - z[..., 3:6, :], -1, -2) / (2 * RECEIVER_STEP)
    jacobian[..., 3:] = np.swapaxes(z[..., 6:9, :] - z[..., 9:12, :], -1, -2) / (2 * RECEIVER_RATE_STEP)
    return jacobian


def receiver_noise(jacobian: np.ndarray, position_sd: float, velocity_sd: float) -> np.ndarray:
    """H_r Sigma_r H_r^T (..., 2, 2): what white navigation errors of sd ``position_sd`` (m, per axis) and
    ``velocity_sd`` (m/s) in the reported receiver state add to the measurement covariance."""
    # Three dot products of the scaled rows: a batched (2, 6) @ (6, 2) product costs four times as much.
    scaled = jacobian * np.array((position_sd,) * 3 + (velocity_sd,) * 3)
    rd_row, rrd_row = scaled[..., 0, :], scaled[..., 1, :]
    noise = np.empty(jacobian.shape[:-2] + (2, 2))
    noise[..., 0, 0] = np.einsum("...i,...i->...", rd_row, rd_row)
    noise[..., 1, 1] = np.einsum("...i,...i->...", rrd_row, rrd_row)
    noise[..., 0, 1] = noise[..., 1, 0] = np.einsum("...i,...i->...", rd_row, rrd_row)
    return noise


def multipath_spread(
    propagation: Propagation, sources, receivers, fixed, source_speed: float, receiver_speed: float, samples: int = 4000
) -> np.ndarray:
    """diag of the phasor model's multipath correction's variance (RD m^2, RRD m^2/s^2) over the
    surveillance volume: sources uniform in the ``sources`` box, receivers in ``receivers`` (motion Boxes),
    random velocities up to the given speeds. The RD correction is taken modulo the wavelength about
    its circular mean. What a filter that cannot yet resolve the ripple must treat as noise (of the
    instantaneous model; signal mode's filter averages that model over the frame).

    Deterministic (a fixed-seed sample): a property of the world, not of an episode.
    """
    rng = np.random.default_rng(0)

    def inside(box) -> np.ndarray:
        radius = box.radius * np.sqrt(rng.uniform(size=samples))
        angle = rng.uniform(0, 2 * np.pi, samples)
        depth = rng.uniform(box.z_min, box.z_max, samples)
        return np.stack([radius * np.cos(angle), radius * np.sin(angle), depth], -1)

    def velocities(speed: float) -> np.ndarray:
        direction = rng.normal(size=(samples, 3))
        return speed * rng.uniform(size=(samples, 1)) * direction / np.linalg.norm(direction, axis=1, keepdims=True)

    arguments = (
        inside(sources),
        velocities(source_speed),
        inside(receivers),
        velocities(receiver_speed),
        np.asarray(fixed, dtype=float),
    )
    # NumPy's form of the phasor model (the compiled one's reference): the default world's committed rows were made
    # with this estimate, which the compiled form would move in its last bits.
    phasor = np.stack(geometry.phasor_multipath(*arguments, *propagation.channel), axis=-1)
    correction = phasor - direct_measurement(*arguments)
    period = 2 * np.pi / propagation.wavenumber
    phase = np.angle(np.mean(np.exp(2j * np.pi * correction[:, 0] / period)))
    rd = geometry.wrap_to_period(correction[:, 0] - phase * period / (2 * np.pi), period)
    return np.diag([np.mean(rd**2), np.var(correction[:, 1])])


def navigation_covariance(config: EnvConfig) -> np.ndarray:
    """The navigation term of R_eff, diag(sigma_rov^2, sigma_vel^2) (zero without compensation): what the
    robot's reported position and velocity errors add to the direct path's RD and RRD to first order, the RRD's
    from the velocity error only (the position error adds sigma_rov^2 |(I - u_m u_m^T)(v_s - v_m)|^2 / r_m^2 to
    it, under 2 % of sigma_vel^2 at 1 m/s and 20 m with the default navigation errors)."""
    receiver = config.receiver
    if not config.filter.compensate_navigation:
        return np.zeros((2, 2))
    return np.diag([receiver.nav_position_sd**2, receiver.velocity_sd**2])


def signal_noise_sd(config: EnvConfig, snr_mobile, snr_fixed) -> np.ndarray:
    """sd of [RD, RRD] (m, m/s), shape (..., 2), the filter is told for a frame at these in-band SNRs
    (linear): the Cramer-Rao sd of :func:`~aasl_gym.frontend.tone_measurement_sd` at the carrier's
    wavelength over the receiver band, times ``signal.sd_inflation``, floored at ``signal.min_*_sd``
    (see :class:`~aasl_gym.sensors.SignalSensor`)."""
    sig = config.signal
    sd = _inflated_tone_sd(config, snr_mobile, snr_fixed)
    return np.maximum(sd, [sig.min_range_difference_sd, sig.min_range_rate_difference_sd])


def _inflated_tone_sd(config: EnvConfig, snr_mobile, snr_fixed) -> np.ndarray:
    source = config.source
    band = receiver_band(source.waveform, source.frequency)
    wavelength = config.world.sound_speed / carrier_frequency(source.waveform, source.frequency)
    sd = tone_measurement_sd(snr_mobile, snr_fixed, wavelength, band[1] - band[0], config.signal.frame_duration)
    return config.signal.sd_inflation * np.stack(sd, axis=-1)


def robot_channel_sd(config: EnvConfig, snr_mobile) -> np.ndarray:
    """The share of :func:`signal_noise_sd` that the robot's channel alone makes (m, m/s; (..., 2)): its
    term of the Cramer-Rao variance, times ``signal.sd_inflation``, without floors. Every pair of one
    frame shares this error (they pair their fixed channels with the same robot recording)."""
    return _inflated_tone_sd(config, snr_mobile, np.inf)


def model_snr(config: EnvConfig, source_position: np.ndarray, receiver_position: np.ndarray) -> np.ndarray:
    """The SNR model's in-band SNR (linear) at a receiver: source level - 20 log10(range / 1 m) - noise
    level (dB), the range floored at 1 m; broadcasts over leading dimensions."""
    distance = np.maximum(np.linalg.norm(np.asarray(source_position) - np.asarray(receiver_position), axis=-1), 1.0)
    return 10 ** ((config.source.source_level_db - 20 * np.log10(distance) - config.world.noise_level_db) / 10)


def received_snr(config: EnvConfig, source_position: np.ndarray, receiver_position: np.ndarray) -> np.ndarray:
    """In-band SNR (linear) at a receiver through the multipath sum: :func:`model_snr` times |M|^2, M the
    tone's multipath factor (:func:`~aasl_gym.geometry.multipath_factor`) where the world has reflections;
    broadcasts over leading dimensions."""
    snr = model_snr(config, source_position, receiver_position)
    if not config.world.reflections:
        return snr
    channel = Propagation.from_config(config.world, config.source.frequency)
    source, receiver = np.broadcast_arrays(source_position, receiver_position)
    factor = geometry.multipath_factor(
        source, receiver, channel.water_depth, channel.surface_reflection, channel.bed_reflection, channel.wavenumber
    )
    return snr * np.abs(factor) ** 2


def expected_noise_covariance(config: EnvConfig, source_position: np.ndarray, mobile: np.ndarray) -> np.ndarray:
    """R_eff (..., 2, 2) a measurement would have with the source at ``source_position`` and the mobile
    hydrophone at ``mobile`` (m; broadcasts): geometric mode's fixed sd, or in signal mode the sd of
    :func:`signal_noise_sd` at the SNR model's SNRs; plus the navigation term. For planning ahead,
    where no frame has been measured yet."""
    fixed = np.asarray(config.world.fixed_position, dtype=float)
    if config.measurement.mode == "signal":
        sd = signal_noise_sd(
            config, model_snr(config, source_position, mobile), model_snr(config, source_position, fixed)
        )
    else:
        shape = np.broadcast_shapes(np.shape(source_position), np.shape(mobile))[:-1]
        measurement = config.measurement
        sd = np.broadcast_to([measurement.range_difference_sd, measurement.range_rate_difference_sd], shape + (2,))
    covariance = np.zeros(sd.shape + (2,))
    covariance[..., 0, 0], covariance[..., 1, 1] = sd[..., 0] ** 2, sd[..., 1] ** 2
    return covariance + navigation_covariance(config)
