"""Range-difference geometry: RD, RRD, their Jacobians, image sources and the two multipath models.

Pure functions on numpy arrays. Positions are in metres, velocities in m/s, in the world frame (z up,
surface at z = 0, bed at z = -D). Every function broadcasts over leading dimensions, so the same code
serves one state and a whole set of sigma points: ``source`` may be ``(3,)`` or ``(N, 3)``.

Conventions (SPEC section 2), with p_s the source, p_m the mobile and p_f the fixed hydrophone:

* ``RD = |p_s - p_m| - |p_s - p_f|`` (metres); ``TDOA = RD / c`` is the arrival at the mobile
  hydrophone minus the arrival at the fixed one.
* ``RRD = (v_s - v_m) . u_m - (v_s - v_f) . u_f`` with ``u = (p_s - p_r) / |p_s - p_r|``: the difference of
  the two range rates (m/s).
* ``FDOA = f_fixed - f_mobile = (f0 / c) * RRD``: a receiver whose range grows hears a lower tone.
"""

from __future__ import annotations

import numpy as np

ZERO3 = np.zeros(3)


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


def _multipath_phase(
    source: np.ndarray,
    source_velocity: np.ndarray,
    receiver: np.ndarray,
    receiver_velocity: np.ndarray,
    images: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
    gains: tuple[float, float],
    wavenumber: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Phase (rad) of the multipath factor M = S / S_direct at one receiver and its rate (rad/s), with
    the direct path's range (m) and range rate (m/s); ``images`` from :func:`image_sources`.

    S = sum_k a_k / r_k exp(-j k r_k) over the direct path (a = 1) and the images, so
    M = 1 + sum_images a_i (d / r_i) exp(-j k (r_i - d)).
    """
    factor, direct, unit, terms = _multipath_factor(source, receiver, images, gains, wavenumber)
    direct_rate = range_rate(unit, source_velocity, receiver_velocity)
    factor_rate = np.zeros(np.shape(direct), dtype=complex)
    for (term, image_range, image_unit), (_, image_velocity) in zip(terms, images):
        image_rate = range_rate(image_unit, image_velocity, receiver_velocity)
        log_rate = direct_rate / direct - image_rate / image_range - 1j * wavenumber * (image_rate - direct_rate)
        factor_rate = factor_rate + term * log_rate
    return np.angle(factor), np.imag(factor_rate / factor), direct, direct_rate


def _multipath_factor(
    source: np.ndarray,
    receiver: np.ndarray,
    images: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
    gains: tuple[float, float],
    wavenumber: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """The multipath factor M = 1 + sum_images a_i (d / r_i) exp(-j k (r_i - d)) at ``receiver``, the
    direct path's range d (m) and unit vector, and each image's term with its range r_i (m) and unit vector."""
    direct, unit = ranges(source, receiver)
    factor = np.ones(np.shape(direct), dtype=complex)
    terms = []
    for (image, _), gain in zip(images, gains):
        image_range, image_unit = ranges(image, receiver)
        term = gain * direct / image_range * np.exp(-1j * wavenumber * (image_range - direct))
        factor = factor + term
        terms.append((term, image_range, image_unit))
    return factor, direct, unit, terms


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
    gains = (surface_reflection, bed_reflection)
    return _stationary_factors(source, (receiver,), water_depth, gains, wavenumber)[0][0]


def _stationary_factors(
    source: np.ndarray,
    receivers: tuple[np.ndarray, ...],
    water_depth: float,
    gains: tuple[float, float],
    wavenumber: float,
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]]:
    """:func:`_multipath_factor` at each of ``receivers``, the images made once; their velocities are
    not needed (what uses this takes no rates)."""
    images = image_sources(source, np.zeros_like(source), water_depth)
    return [_multipath_factor(source, receiver, images, gains, wavenumber) for receiver in receivers]


def phasor_range_difference(
    source: np.ndarray,
    mobile: np.ndarray,
    fixed: np.ndarray,
    water_depth: float,
    surface_reflection: float,
    bed_reflection: float,
    wavenumber: float,
) -> np.ndarray:
    """The apparent RD (m) of :func:`phasor_multipath` alone, to the last bit, without the rates: what a
    frame's RD track is made of (its slope is the frame's RRD), at about two thirds of the cost."""
    gains = (surface_reflection, bed_reflection)
    return _apparent_range_difference(
        _stationary_factors(source, (mobile, fixed), water_depth, gains, wavenumber), wavenumber
    )


def _apparent_range_difference(factors: list, wavenumber: float) -> np.ndarray:
    """RD_app = (d_m - d_f) + (phi_f - phi_m) / k from the mobile's and the fixed hydrophone's
    :func:`_multipath_factor` results."""
    (factor_m, range_m, _, _), (factor_f, range_f, _, _) = factors
    return (range_m - range_f) + (np.angle(factor_f) - np.angle(factor_m)) / wavenumber


def phasor_range_difference_linearized(
    source: np.ndarray,
    mobile: np.ndarray,
    fixed: np.ndarray,
    water_depth: float,
    surface_reflection: float,
    bed_reflection: float,
    wavenumber: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`phasor_range_difference` (m, to the last bit) and its gradients (..., 3) with respect to the
    source position and the mobile hydrophone's position, from one set of multipath factors.

    RD_app = (d_m - d_f) + (phi_f - phi_m) / k with phi the phase of a receiver's multipath factor
    M = 1 + sum_i T_i, T_i = a_i (d / r_i) exp(-j k (r_i - d)). A small move changes log T_i by
    dd / d - dr_i / r_i - j k (dr_i - dd), so dphi = Im(sum_i (T_i / M) dlog T_i). With respect to the
    source dd = u . dp and dr_i = (S u_i) . dp (S the image's mirror, diag(1, 1, -1)); with respect to
    the receiver dd = -u . dr and dr_i = -u_i . dr (u, u_i the unit vectors from the receiver).
    """
    gains = (surface_reflection, bed_reflection)
    mirror = np.array([1.0, 1.0, -1.0])
    factors = _stationary_factors(source, (mobile, fixed), water_depth, gains, wavenumber)
    gradients = []
    for (factor, direct, unit, terms), mobile_receiver in zip(factors, (True, False)):
        phase_source = np.zeros(np.shape(unit))
        phase_receiver = np.zeros(np.shape(unit))  # stays zero for the fixed one, which does not move
        for term, image_range, image_unit in terms:
            weight = term / factor
            sine, cosine = weight.imag[..., None], weight.real[..., None]
            along_direct, along_image = unit / direct[..., None], image_unit / image_range[..., None]
            mirrored, mirrored_along = mirror * image_unit, mirror * along_image
            phase_source += sine * (along_direct - mirrored_along) - wavenumber * cosine * (mirrored - unit)
            if mobile_receiver:
                phase_receiver += sine * (along_image - along_direct) - wavenumber * cosine * (unit - image_unit)
        gradients.append((unit, phase_source, phase_receiver))
    range_difference = _apparent_range_difference(factors, wavenumber)
    (unit_m, source_m, receiver_m), (unit_f, source_f, _) = gradients
    source_gradient = (unit_m - unit_f) + (source_f - source_m) / wavenumber
    mobile_gradient = -unit_m - receiver_m / wavenumber
    return range_difference, source_gradient, mobile_gradient


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
    """
    gains = (surface_reflection, bed_reflection)
    # The images and the direct ranges are shared by the two receivers' factors and the direct RD and
    # RRD: this model runs on every LC-MAP candidate at every burst sample, where it dominates the cost.
    images = image_sources(source, source_velocity, water_depth)
    phase_m, phase_rate_m, range_m, range_rate_m = _multipath_phase(
        source, source_velocity, mobile, mobile_velocity, images, gains, wavenumber
    )
    phase_f, phase_rate_f, range_f, range_rate_f = _multipath_phase(
        source, source_velocity, fixed, ZERO3, images, gains, wavenumber
    )
    rd = (range_m - range_f) + (phase_f - phase_m) / wavenumber
    rrd = (range_rate_m - range_rate_f) + (phase_rate_f - phase_rate_m) / wavenumber
    return rd, rrd


def wrap_to_period(value: np.ndarray | float, period: float) -> np.ndarray | float:
    """Map to the principal interval [-period/2, period/2)."""
    return (np.asarray(value) + 0.5 * period) % period - 0.5 * period
