"""Range-difference geometry: RD, RRD, their Jacobians, image sources and the two multipath models.

Pure functions on numpy arrays. Positions are in metres, velocities in m/s, in the world frame (z up,
surface at z = 0, bed at z = -D). Every function broadcasts over leading dimensions, so the same code
serves one state and a whole set of sigma points: ``source`` may be ``(3,)`` or ``(N, 3)``. (The compiled
phasor RD, :func:`phasor_range_difference` and its linearization, takes one fixed hydrophone ``(3,)``.)

Conventions (SPEC section 2), with p_s the source, p_m the mobile and p_f the fixed hydrophone:

* ``RD = |p_s - p_m| - |p_s - p_f|`` (metres); ``TDOA = RD / c`` is the arrival at the mobile
  hydrophone minus the arrival at the fixed one.
* ``RRD = (v_s - v_m) . u_m - (v_s - v_f) . u_f`` with ``u = (p_s - p_r) / |p_s - p_r|``: the difference of
  the two range rates (m/s).
* ``FDOA = f_fixed - f_mobile = (f0 / c) * RRD``: a receiver whose range grows hears a lower tone.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from aasl_gym import kernels

ZERO3 = np.zeros(3)


def vector_norm(vector: np.ndarray) -> float:
    """|v| of one vector (any unit): ``np.linalg.norm``'s own formula for it, sqrt(v . v), to the last bit, without its
    dispatch (a few of these run every step)."""
    return math.sqrt(vector.dot(vector))


def ranges(source: np.ndarray, receiver: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (m) and unit vector from ``receiver`` to ``source``."""
    offset = source - receiver
    distance = np.sqrt(np.einsum("...i,...i->...", offset, offset))
    return distance, offset / distance[..., None]


def range_rate(unit: np.ndarray, source_velocity: np.ndarray, receiver_velocity: np.ndarray) -> np.ndarray:
    """Rate of change of the source-receiver distance, m/s (positive = opening)."""
    return np.einsum("...i,...i->...", source_velocity - receiver_velocity, unit)


def range_difference(source: np.ndarray, mobile: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """RD = |p_s - p_m| - |p_s - p_f|, metres."""
    return ranges(source, mobile)[0] - ranges(source, fixed)[0]


def range_rate_difference(
    source: np.ndarray,
    source_velocity: np.ndarray,
    mobile: np.ndarray,
    mobile_velocity: np.ndarray,
    fixed: np.ndarray,
    fixed_velocity: np.ndarray = ZERO3,
) -> np.ndarray:
    """RRD = d|p_s - p_m|/dt - d|p_s - p_f|/dt, m/s."""
    _, unit_mobile = ranges(source, mobile)
    _, unit_fixed = ranges(source, fixed)
    return range_rate(unit_mobile, source_velocity, mobile_velocity) - range_rate(
        unit_fixed, source_velocity, fixed_velocity
    )


def fdoa_from_rrd(range_rate_difference_mps: np.ndarray, frequency: float, sound_speed: float) -> np.ndarray:
    """FDOA = f_fixed - f_mobile in Hz, from RRD in m/s (first order in v / c)."""
    return frequency / sound_speed * range_rate_difference_mps


def direct_jacobian(
    source: np.ndarray,
    source_velocity: np.ndarray,
    mobile: np.ndarray,
    mobile_velocity: np.ndarray,
    fixed: np.ndarray,
) -> np.ndarray:
    """d[RD, RRD] / d[p_s, v_s] for the direct path: shape ``(..., 2, 6)``.

    dRD/dp = u_m - u_f, dRD/dv = 0, dRRD/dv = u_m - u_f and
    dRRD/dp = (I - u_m u_m^T)(v_s - v_m) / d_m - (I - u_f u_f^T) v_s / d_f.
    """
    d_m, u_m = ranges(source, mobile)
    d_f, u_f = ranges(source, fixed)
    rel_m = source_velocity - mobile_velocity
    drrd_dp = (rel_m - u_m * range_rate(u_m, source_velocity, mobile_velocity)[..., None]) / d_m[..., None] - (
        source_velocity - u_f * range_rate(u_f, source_velocity, ZERO3)[..., None]
    ) / d_f[..., None]
    gradient = u_m - u_f
    shape = np.broadcast_shapes(gradient.shape, drrd_dp.shape)[:-1]
    jac = np.zeros(shape + (2, 6))
    jac[..., 0, :3] = gradient
    jac[..., 1, :3] = drrd_dp
    jac[..., 1, 3:] = gradient
    return jac


def image_sources(
    source: np.ndarray, source_velocity: np.ndarray, water_depth: float
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Surface image (x, y, -z) and bed image (x, y, -2D - z) with their velocities (vx, vy, -vz)."""
    mirror = np.array([1.0, 1.0, -1.0])
    surface = source * mirror
    bed = source * mirror - np.array([0.0, 0.0, 2.0 * water_depth])
    mirrored_velocity = source_velocity * mirror
    return (surface, mirrored_velocity), (bed, mirrored_velocity)


def linear_multipath(
    source: np.ndarray,
    source_velocity: np.ndarray,
    mobile: np.ndarray,
    mobile_velocity: np.ndarray,
    fixed: np.ndarray,
    water_depth: float,
    surface_reflection: float,
    bed_reflection: float,
) -> tuple[np.ndarray, np.ndarray]:
    """First-order multipath model of the reference paper: ``(RD_mp, RRD_mp)``.

    RD_mp = RD + a_surf * delta_surf + a_bed * delta_bed, where delta_* is the range difference of the
    image source to the two receivers; RRD_mp is its time derivative (the same weights on the image
    sources' range-rate differences).
    """
    rd = range_difference(source, mobile, fixed)
    rrd = range_rate_difference(source, source_velocity, mobile, mobile_velocity, fixed)
    for (image, image_velocity), weight in zip(
        image_sources(source, source_velocity, water_depth), (surface_reflection, bed_reflection)
    ):
        rd = rd + weight * range_difference(image, mobile, fixed)
        rrd = rrd + weight * range_rate_difference(image, image_velocity, mobile, mobile_velocity, fixed)
    return rd, rrd


class _ImagePath(NamedTuple):
    """One image's share of a receiver's multipath factor (see :class:`_ReceiverPaths`)."""

    vertical: np.ndarray  # m, the image's z less the receiver's
    range: np.ndarray  # m, r_i
    term_real: np.ndarray  # Re T_i
    term_imag: np.ndarray  # Im T_i


class _ReceiverPaths(NamedTuple):
    """What the phasor model with its rates (:func:`phasor_multipath`) needs at one receiver, in real
    arithmetic (the RD alone and its gradients are compiled: :mod:`aasl_gym.kernels`): the offset from the
    receiver to the source (..., 3), the direct range d (m), each image's vertical offset, range r_i (m) and term
    T_i = a_i (d / r_i) exp(-j k (r_i - d)) as real and imaginary parts, and the multipath factor
    M = 1 + sum_i T_i likewise. The images share the direct path's horizontal offset."""

    offset: np.ndarray
    direct: np.ndarray
    images: list[_ImagePath]
    factor_real: np.ndarray
    factor_imag: np.ndarray

    @property
    def phase(self) -> np.ndarray:
        """rad, the phase of M in (-pi, pi]."""
        return np.arctan2(self.factor_imag, self.factor_real)


def _receiver_paths(
    source: np.ndarray, receiver: np.ndarray, water_depth: float, gains: tuple[float, float], wavenumber: float
) -> _ReceiverPaths:
    """:class:`_ReceiverPaths` at ``receiver`` for the surface image (x, y, -z) and the bed image
    (x, y, -2D - z) of :func:`image_sources`, with reflection coefficients ``gains``."""
    offset = np.asarray(source, dtype=float) - receiver
    horizontal = offset[..., 0] ** 2 + offset[..., 1] ** 2
    direct = np.sqrt(horizontal + offset[..., 2] ** 2)
    receiver_z = np.asarray(receiver, dtype=float)[..., 2]
    source_z = np.asarray(source, dtype=float)[..., 2]
    factor_real, factor_imag = np.ones(np.shape(direct)), np.zeros(np.shape(direct))
    images = []
    surface_vertical, bed_vertical = -source_z - receiver_z, -2.0 * water_depth - source_z - receiver_z
    for vertical, gain in ((surface_vertical, gains[0]), (bed_vertical, gains[1])):
        image_range = np.sqrt(horizontal + vertical**2)
        delay_phase = wavenumber * (image_range - direct)
        amplitude = gain * direct / image_range
        term_real, term_imag = amplitude * np.cos(delay_phase), -amplitude * np.sin(delay_phase)
        factor_real, factor_imag = factor_real + term_real, factor_imag + term_imag
        images.append(_ImagePath(vertical, image_range, term_real, term_imag))
    return _ReceiverPaths(offset, direct, images, factor_real, factor_imag)


def _multipath_phase(
    source: np.ndarray,
    source_velocity: np.ndarray,
    receiver: np.ndarray,
    receiver_velocity: np.ndarray,
    water_depth: float,
    gains: tuple[float, float],
    wavenumber: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Phase (rad) of the multipath factor M = S / S_direct at one receiver and its rate (rad/s), with
    the direct path's range (m) and range rate (m/s).

    S = sum_k a_k / r_k exp(-j k r_k) over the direct path (a = 1) and the images, so
    M = 1 + sum_images a_i (d / r_i) exp(-j k (r_i - d)), and dM/dt = sum_i T_i dlog T_i / dt with
    dlog T_i / dt = d'/d - r_i'/r_i - j k (r_i' - d'); the images move with the source mirrored.
    """
    paths = _receiver_paths(source, receiver, water_depth, gains, wavenumber)
    source_velocity = np.asarray(source_velocity, dtype=float)
    receiver_velocity = np.asarray(receiver_velocity, dtype=float)
    relative = source_velocity - receiver_velocity
    offset, direct = paths.offset, paths.direct
    horizontal_rate = offset[..., 0] * relative[..., 0] + offset[..., 1] * relative[..., 1]
    direct_rate = (horizontal_rate + offset[..., 2] * relative[..., 2]) / direct
    # An image moves with the source mirrored in z: its vertical offset changes at -v_z less the receiver's.
    image_vertical_velocity = -source_velocity[..., 2] - receiver_velocity[..., 2]
    rate_real, rate_imag = np.zeros(np.shape(direct)), np.zeros(np.shape(direct))
    for vertical, image_range, term_real, term_imag in paths.images:
        image_rate = (horizontal_rate + vertical * image_vertical_velocity) / image_range
        log_real = direct_rate / direct - image_rate / image_range
        log_imag = -wavenumber * (image_rate - direct_rate)
        rate_real = rate_real + term_real * log_real - term_imag * log_imag
        rate_imag = rate_imag + term_real * log_imag + term_imag * log_real
    power = paths.factor_real**2 + paths.factor_imag**2
    phase_rate = (rate_imag * paths.factor_real - rate_real * paths.factor_imag) / power
    return paths.phase, phase_rate, direct, direct_rate


def multipath_factor(
    source: np.ndarray,
    receiver: np.ndarray,
    water_depth: float,
    surface_reflection: float,
    bed_reflection: float,
    wavenumber: float,
) -> np.ndarray:
    """M = S / S_direct (complex) at ``receiver``: the tone through the surface and bed images relative to
    the direct path alone (|M| scales the received amplitude, its phase the apparent range)."""
    paths = _receiver_paths(source, receiver, water_depth, (surface_reflection, bed_reflection), wavenumber)
    return paths.factor_real + 1j * paths.factor_imag


def phasor_range_difference(
    source: np.ndarray,
    mobile: np.ndarray,
    fixed: np.ndarray,
    water_depth: float,
    surface_reflection: float,
    bed_reflection: float,
    wavenumber: float,
) -> np.ndarray:
    """The apparent RD (m) of :func:`phasor_multipath` alone, without the rates: what a frame's RD track is
    made of (its slope is the frame's RRD). Compiled (:func:`aasl_gym.kernels.phasor_paths`): it agrees
    with :func:`phasor_multipath` to a few units in the last place. ``fixed`` is one point (3,)."""
    gains = (surface_reflection, bed_reflection)
    return kernels.phasor_paths(source, mobile, fixed, water_depth, *gains, wavenumber)[0]


def phasor_range_difference_linearized(
    source: np.ndarray,
    mobile: np.ndarray,
    fixed: np.ndarray,
    water_depth: float,
    surface_reflection: float,
    bed_reflection: float,
    wavenumber: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`phasor_range_difference` (m) and its gradients (..., 3) with respect to the source position
    and the mobile hydrophone's position, from one set of multipath factors; ``fixed`` is one point (3,).

    RD_app = (d_m - d_f) + (phi_f - phi_m) / k with phi the phase of a receiver's multipath factor
    M = 1 + sum_i T_i, T_i = a_i (d / r_i) exp(-j k (r_i - d)). A small move changes log T_i by
    dd / d - dr_i / r_i - j k (dr_i - dd), so dphi = Im(sum_i (T_i / M) dlog T_i). With respect to the
    source dd = u . dp and dr_i = (S u_i) . dp (S the image's mirror, diag(1, 1, -1)); with respect to
    the receiver dd = -u . dr and dr_i = -u_i . dr (u, u_i the unit vectors from the receiver). The
    images share the direct path's horizontal offset, so each gradient's horizontal part is that offset
    times one scalar. Written as one compiled loop (:func:`aasl_gym.kernels.phasor_paths`): this runs on
    every window-fit trial state at every sample, where it dominated the tracker's cost.
    """
    gains = (surface_reflection, bed_reflection)
    return kernels.phasor_paths(source, mobile, fixed, water_depth, *gains, wavenumber)


def phasor_multipath(
    source: np.ndarray,
    source_velocity: np.ndarray,
    mobile: np.ndarray,
    mobile_velocity: np.ndarray,
    fixed: np.ndarray,
    water_depth: float,
    surface_reflection: float,
    bed_reflection: float,
    wavenumber: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact narrowband model: the RD (m) and RRD (m/s) a tone front end measures with multipath.

    Each receiver hears the phasor sum of the direct path and the surface and bed images,
    ``a_k / r_k exp(-j 2 pi f0 r_k / c)``; the apparent RD is minus the phase difference of the two sums
    divided by the wavenumber k = 2 pi f0 / c. It is returned continuous (unwrapped about the direct RD:
    RD_app = RD + (phi_f - phi_m) / k with phi the phase of each receiver's multipath factor), and the
    apparent RRD is its exact time derivative.

    This is the model written with NumPy, each receiver's phase differentiated in time. The sensors and filters
    run its compiled form (:func:`aasl_gym.kernels.phasor_measurement`, through
    :func:`aasl_gym.measurement_models.multipath_measurement`), which the tests hold to this one.
    """
    gains = (surface_reflection, bed_reflection)
    # Each receiver's direct range and range rate come with its factor: this model runs on every LC-MAP
    # candidate at every burst sample, where it dominates the cost.
    phase_m, phase_rate_m, range_m, range_rate_m = _multipath_phase(
        source, source_velocity, mobile, mobile_velocity, water_depth, gains, wavenumber
    )
    phase_f, phase_rate_f, range_f, range_rate_f = _multipath_phase(
        source, source_velocity, fixed, ZERO3, water_depth, gains, wavenumber
    )
    rd = (range_m - range_f) + (phase_f - phase_m) / wavenumber
    rrd = (range_rate_m - range_rate_f) + (phase_rate_f - phase_rate_m) / wavenumber
    return rd, rrd


def unwrap_to_period(values: np.ndarray, period: float) -> np.ndarray:
    """``values`` (..., S) made continuous along the last axis: each step between neighbours moved by
    whole periods into [-period/2, period/2] (``np.unwrap`` in the values' own unit, at a third of its cost)."""
    values = np.asarray(values, dtype=float)
    slips = np.cumsum(np.round((values[..., 1:] - values[..., :-1]) / period), axis=-1) * period  # np.diff's terms
    unwrapped = values.copy()
    unwrapped[..., 1:] -= slips
    return unwrapped


def wrap_to_period(value: np.ndarray | float, period: float) -> np.ndarray | float:
    """Map to the principal interval [-period/2, period/2)."""
    return (np.asarray(value) + 0.5 * period) % period - 0.5 * period
