"""Compiled loops (numba) for the places where the pipeline spent its time on arithmetic: the tone's
envelope at every frame sample, the phasor model - the apparent RD and its gradients at every frame
sample of every trial state of every window fit, and the frame's mean and slope with their Jacobians - and
what a window fit does with them at every sample (R_eff's whitener, the whitened residual, the chained
Jacobian).

Why compiled. NumPy's float64 ``sin`` and ``cos`` call the C library one element at a time (15 ns an
element on the development machine), and the phasor model written as array expressions streamed some sixty
temporaries through memory. A loop that evaluates sin and cos by polynomial and keeps every intermediate
in registers is vectorised by LLVM (AVX-512 / AVX2): the apparent RD with its gradients runs about 15 times
faster than its NumPy form, and whole default-world episodes run about twice as fast. The results agree with
the NumPy forms (:func:`aasl_gym.geometry.phasor_multipath`, :func:`aasl_gym.measurement_models.frame_averaged`,
``np.sin``) to a few units in the last place, not to the last bit (``tests/test_kernels.py``,
``tests/test_properties.py``).

Sine and cosine. ``x = q pi/2 + r`` with ``|r| <= pi/4`` (Cody-Waite: pi/2 in three parts, exact products
for ``|q| < 2^20``), then the minimax polynomials of fdlibm's ``__kernel_sin`` and ``__kernel_cos``
(Sun Microsystems, 1993) on ``r``, swapped and negated by the quadrant ``q mod 4``. Within 2 ulp of the C
library for ``|x| <= SINCOS_LIMIT``; beyond it :func:`sincos` hands the array to NumPy.

What keeps LLVM from vectorising a loop, found the hard way: Python's error model (a division tests for
zero and raises; ``error_model="numpy"`` gives inf or NaN as NumPy does), a tuple indexed by a loop
variable, and reading more than a few arrays (each needs a run-time overlap check; past LLVM's limit it
gives up). So the loops read one array of rows and the fixed hydrophone as one point.

The window fit's per-sample algebra (:func:`window_terms`, :func:`whitened_chain`) is a few dozen flops on
2 x 2 and 2 x 6 blocks per sample; as NumPy expressions it was two dozen calls on small arrays and stacked
matrix products of 2 x 6 blocks, which NumPy loops over one by one (a third of a fit's time, session 27).

The tone's complex envelope (:func:`tone_envelope`) runs the synthesis's NumPy expressions operation for
operation and is the same to the last bit (LLVM does not contract a multiply and an add into one rounding
unless told to); the loops above only agree with their NumPy forms to a few units in the last place.

Compiled code is cached next to this file (``cache=True``): the first run on a machine compiles (about
two seconds), later processes load it (about 0.1 s, at the first call).
"""

from __future__ import annotations

import math

import numba
import numpy as np

# States per pass of the frame model: its scratch arrays then stay small enough for malloc's heap. A call's arrays
# beyond glibc's mmap threshold come as fresh pages, whose faults cost more than the loops: 5,000 states at once
# took 375 ns a state, in blocks of 2,000 or fewer 67-73 ns.
CHUNK = 1024
SINCOS_LIMIT = 1.0e6  # rad: |x| up to which the polynomial sine and cosine are used (exact reduction to 2^20 pi/2)
_TWO_OVER_PI = 6.36619772367581382433e-01
# pi/2 as three parts of 33, 33 and 53 bits: q times each of the first two is exact for |q| < 2^20.
_PIO2_1, _PIO2_2, _PIO2_3 = 1.57079632673412561417e00, 6.07710050630396597660e-11, 2.02226624871116645580e-21
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11

_compile = numba.njit(cache=True, error_model="numpy")


@numba.njit(inline="always", error_model="numpy")
def _sincos(x: float) -> tuple[float, float]:
    """(sin x, cos x) for |x| <= SINCOS_LIMIT, branch-free so that a loop calling it vectorises."""
    quadrant = math.floor(x * _TWO_OVER_PI + 0.5)
    r = ((x - quadrant * _PIO2_1) - quadrant * _PIO2_2) - quadrant * _PIO2_3
    z = r * r
    sine = r + r * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    # fdlibm's cosine: 1 - z/2 split so that the rounding of 1 - z/2 is carried into the tail.
    half = 0.5 * z
    head = 1.0 - half
    tail = z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    cosine = head + (((1.0 - head) - half) + tail)
    n = np.int64(quadrant) & 3
    odd = (n & 1) == 1
    s, c = (cosine if odd else sine), (sine if odd else cosine)
    return (-s if (n & 2) == 2 else s), (-c if ((n + 1) & 2) == 2 else c)


@_compile
def _sincos_loop(x, sine, cosine):
    for i in range(x.shape[0]):
        sine[i], cosine[i] = _sincos(x[i])


def sincos(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sin x, cos x) of an array of angles (rad), each the shape of ``x``."""
    x = np.asarray(x, dtype=float)
    flat = np.ascontiguousarray(x).reshape(-1)
    if flat.size and not np.max(np.abs(flat)) <= SINCOS_LIMIT:  # beyond the exact reduction, or NaN
        return np.sin(x), np.cos(x)
    sine, cosine = np.empty_like(flat), np.empty_like(flat)
    _sincos_loop(flat, sine, cosine)
    return sine.reshape(x.shape), cosine.reshape(x.shape)


@numba.njit(inline="always", error_model="numpy")
def _receiver(sx, sy, sz, rx, ry, rz, depth, surface_gain, bed_gain, k):
    """At one receiver (rx, ry, rz) for the source (sx, sy, sz): the horizontal offset source - receiver
    (x, y), the direct range d, the multipath factor M = 1 + sum_i T_i (real, imaginary; T_i = a_i (d / r_i)
    exp(-j k (r_i - d)) over the surface and bed images) and the gradient of the apparent range d - phase(M)/k
    in the source's position in three parts: the scale of the horizontal offset, the direct path's vertical
    part and the images' (see :func:`aasl_gym.geometry.phasor_range_difference_linearized`)."""
    ox, oy, oz = sx - rx, sy - ry, sz - rz
    horizontal = ox * ox + oy * oy
    d = math.sqrt(horizontal + oz * oz)
    surface_vertical, bed_vertical = -sz - rz, -2.0 * depth - sz - rz
    surface_range = math.sqrt(horizontal + surface_vertical * surface_vertical)
    bed_range = math.sqrt(horizontal + bed_vertical * bed_vertical)
    # The path-length differences are bounded by the water column (k (r_i - d) <= 2 k D, hundreds of rad), far
    # inside SINCOS_LIMIT, so the loop calls the polynomial directly.
    surface_sin, surface_cos = _sincos(k * (surface_range - d))
    bed_sin, bed_cos = _sincos(k * (bed_range - d))
    surface_amplitude, bed_amplitude = surface_gain * d / surface_range, bed_gain * d / bed_range
    t1r, t1i = surface_amplitude * surface_cos, -surface_amplitude * surface_sin
    t2r, t2i = bed_amplitude * bed_cos, -bed_amplitude * bed_sin
    factor_real, factor_imag = 1.0 + t1r + t2r, t1i + t2i
    power = factor_real * factor_real + factor_imag * factor_imag
    # w_i = T_i / M; the phase's gradient is A u - sum_i B_i S u_i with A = sum_i (Im w_i / d + k Re w_i)
    # and B_i = Im w_i / r_i + k Re w_i (u, u_i the unit vectors to the source and its images).
    w1r, w1i = (t1r * factor_real + t1i * factor_imag) / power, (t1i * factor_real - t1r * factor_imag) / power
    w2r, w2i = (t2r * factor_real + t2i * factor_imag) / power, (t2i * factor_real - t2r * factor_imag) / power
    inverse = 1.0 / d
    direct_scale = (w1i + w2i) * inverse + k * (w1r + w2r)
    surface_scale, bed_scale = w1i / surface_range + k * w1r, w2i / bed_range + k * w2r
    image_horizontal = surface_scale / surface_range + bed_scale / bed_range
    image_vertical = surface_scale * surface_vertical / surface_range + bed_scale * bed_vertical / bed_range
    horizontal_scale = inverse - (direct_scale * inverse - image_horizontal) / k
    direct_vertical = oz * (inverse - direct_scale * inverse / k)
    return ox, oy, d, factor_real, factor_imag, horizontal_scale, direct_vertical, -image_vertical / k


@numba.njit(inline="always", error_model="numpy")
def _pair(sx, sy, sz, mx, my, mz, fx, fy, fz, depth, surface_gain, bed_gain, k):
    """The 11 rows of :func:`_phasor_loop` for one source (sx, sy, sz), mobile and fixed receiver."""
    hx, hy, hd, hr, hi, hs, hv, himg = _receiver(sx, sy, sz, mx, my, mz, depth, surface_gain, bed_gain, k)
    gx, gy, gd, gr, gi, gs, gv, gimg = _receiver(sx, sy, sz, fx, fy, fz, depth, surface_gain, bed_gain, k)
    # With respect to the receiver every horizontal term and the direct path's vertical one change sign,
    # but an image's vertical offset (-z_s - 2 n D - z_r) falls with the receiver's z as with the source's.
    return (
        hd - gd,
        hr,
        hi,
        gr,
        gi,
        hx * hs - gx * gs,
        hy * hs - gy * gs,
        (hv + himg) - (gv + gimg),
        -hx * hs,
        -hy * hs,
        -hv + himg,
    )


@_compile
def _phasor_loop(points, fixed, depth, surface_gain, bed_gain, k, out):
    """Rows of ``out`` (11, N) for the columns of ``points`` (6, N: the source's position, then the mobile's)
    and the fixed receiver (3,): d_m - d_f; the mobile's and the fixed receiver's M (real, imaginary); the
    apparent RD's gradient in the source's position (3) and in the mobile's (3). The rows are stored one by
    one (see the module's note on vectorising)."""
    fx, fy, fz = fixed[0], fixed[1], fixed[2]
    for i in range(points.shape[1]):
        row = _pair(
            points[0, i], points[1, i], points[2, i], points[3, i], points[4, i], points[5, i],
            fx, fy, fz, depth, surface_gain, bed_gain, k,
        )  # fmt: skip
        out[0, i], out[1, i], out[2, i], out[3, i] = row[0], row[1], row[2], row[3]
        out[4, i], out[5, i], out[6, i], out[7, i] = row[4], row[5], row[6], row[7]
        out[8, i], out[9, i], out[10, i] = row[8], row[9], row[10]


@_compile
def _frame_combine(range_difference, paths, offsets, period, out):
    """A frame's [mean, least-squares slope] of the RD track (``range_difference``, (S, N), unwrapped across
    the offsets by whole ``period``s as the front end unwraps its windows' delays) and their derivatives in
    [p, v] and [p_m, v_m] from the gradients in ``paths`` (rows 5:11 of :func:`_phasor_loop`'s output, (11, S, N)):
    ``out`` (26, N) = [mean, slope], then d[mean, slope]/d[p, v] (2 x 6) and d[mean, slope]/d[p_m, v_m]
    (2 x 6), row by row. The samples at x + tau x' make d/dx' the tau-weighted sums of d/dx."""
    count, samples = range_difference.shape[1], offsets.shape[0]
    spread = 0.0
    for s in range(samples):
        spread += offsets[s] * offsets[s]
    out[:] = 0.0
    slips = np.zeros(count)
    unwrapped = np.empty_like(range_difference)
    # Every inner loop runs over the columns i, so that it vectorises.
    for s in range(samples):
        for i in range(count):
            if s > 0:
                slips[i] += np.rint((range_difference[s, i] - range_difference[s - 1, i]) / period)
            unwrapped[s, i] = range_difference[s, i] - slips[i] * period
            out[0, i] += unwrapped[s, i] / samples
    for s in range(samples):
        slope_weight = offsets[s] / spread
        for i in range(count):
            out[1, i] += (unwrapped[s, i] - out[0, i]) * slope_weight
    for gradient, first in ((5, 2), (8, 14)):  # the source's gradient rows, the mobile's
        for c in range(3):
            for s in range(samples):
                tau = offsets[s]
                mean_weight, slope_weight = 1.0 / samples, tau / spread
                for i in range(count):
                    g = paths[gradient + c, s, i]
                    out[first + c, i] += g * mean_weight  # d mean / d x
                    out[first + 3 + c, i] += g * mean_weight * tau  # d mean / d x'
                    out[first + 6 + c, i] += g * slope_weight  # d slope / d x
                    out[first + 9 + c, i] += g * slope_weight * tau  # d slope / d x'


def _rows(*vectors) -> tuple[tuple[int, ...], np.ndarray]:
    """The common leading shape of 3-vectors (..., 3) and their components as the rows (3 V, N) of one
    contiguous array (V the number of vectors), as :func:`_phasor_loop` reads them."""
    arrays = [np.asarray(v, dtype=float) for v in vectors]
    shape = np.broadcast_shapes(*(a.shape for a in arrays))[:-1]
    rows = np.empty((3 * len(arrays), *shape))
    for i, vector in enumerate(arrays):
        for axis in range(3):  # each component broadcast into its row: no broadcast copies, no transposes
            rows[3 * i + axis] = vector[..., axis]
    return shape, rows.reshape(3 * len(arrays), -1)


def _fixed_point(fixed) -> np.ndarray:
    """The fixed hydrophone (m) as the one point (3,) the loops take: read once, not per column, so that they
    vectorise (a third set of columns to read kept LLVM from it)."""
    fixed = np.array(fixed, dtype=float)  # a fresh contiguous copy: one compiled signature for every caller
    if fixed.shape != (3,):
        raise ValueError(f"fixed must be one hydrophone position of shape (3,), got shape {fixed.shape}")
    return fixed


def _apparent(paths: np.ndarray, wavenumber: float) -> np.ndarray:
    """RD_app = (d_m - d_f) + (phi_f - phi_m) / k from the loops' rows 0:5. atan2 stays with NumPy, which
    vectorises it: it is the one call the loops could not."""
    return paths[0] + (np.arctan2(paths[4], paths[3]) - np.arctan2(paths[2], paths[1])) / wavenumber


def phasor_paths(
    source, mobile, fixed, water_depth: float, surface_reflection: float, bed_reflection: float, wavenumber: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The phasor model's apparent RD (m) and its gradients (..., 3) in the source's and the mobile
    hydrophone's positions, for a source and a mobile (..., 3; m) that broadcast together and one fixed
    hydrophone (3,); see :func:`aasl_gym.geometry.phasor_range_difference_linearized` for the model."""
    shape, points = _rows(source, mobile)
    out = _paths(points, _fixed_point(fixed), water_depth, surface_reflection, bed_reflection, wavenumber)
    gradients = out[5:11].T
    return (
        _apparent(out, wavenumber).reshape(shape)[()],  # [()]: a scalar for one point, as NumPy's ufuncs give
        gradients[:, 0:3].reshape(shape + (3,)),
        gradients[:, 3:6].reshape(shape + (3,)),
    )


def _paths(
    points: np.ndarray, fixed: np.ndarray, water_depth, surface_reflection, bed_reflection, wavenumber
) -> np.ndarray:
    """:func:`_phasor_loop`'s rows (11, N) for ``points`` (6, N) and the fixed point of :func:`_fixed_point`."""
    out = np.empty((11, points.shape[1]))
    channel = float(water_depth), float(surface_reflection), float(bed_reflection), float(wavenumber)
    _phasor_loop(points, fixed, *channel, out)
    return out


def frame_phasor(
    position, velocity, mobile, mobile_velocity, fixed, offsets: np.ndarray, propagation
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The phasor model's [RD, RRD] (..., 2) over one frame as a tone front end measures them - the mean and
    the least-squares slope of the apparent RD at ``offsets`` (s, about the frame's centre), the source and
    the mobile moving straight on meanwhile - and its Jacobians d[RD, RRD]/d[p, v] and d[RD, RRD]/d[p_m, v_m]
    (..., 2, 6 each); the states broadcast together, ``fixed`` is one point (3,). ``propagation`` is an
    :class:`aasl_gym.measurement_models.Propagation`; see :class:`aasl_gym.measurement_models.FrameAveragedPhasor`
    for the model."""
    shape, rows = _rows(position, mobile, velocity, mobile_velocity)
    offsets, fixed = np.asarray(offsets, dtype=float), _fixed_point(fixed)
    count = rows.shape[1]
    if count <= CHUNK:
        out = _frame_block(rows, fixed, offsets, propagation)
    else:
        # Each block straight into its columns: a list of blocks, concatenated, held the whole twice over and copied it
        # (the search from the prior's 27,000 columns: 6.8 -> 1.9 ms a pass).
        out = np.empty((26, count))
        for start in range(0, count, CHUNK):
            out[:, start : start + CHUNK] = _frame_block(rows[:, start : start + CHUNK], fixed, offsets, propagation)
    columns = out.T
    return (
        columns[:, 0:2].reshape(shape + (2,)),
        columns[:, 2:14].reshape(shape + (2, 6)),
        columns[:, 14:26].reshape(shape + (2, 6)),
    )


def _frame_block(rows: np.ndarray, fixed: np.ndarray, offsets: np.ndarray, propagation) -> np.ndarray:
    """:func:`_frame_combine`'s rows (26, N) for the states in ``rows`` (12, N: the source's and the mobile's
    positions, then their velocities)."""
    # The source and the mobile at every offset, sample-major: (6, S N).
    points = (rows[0:6, None, :] + offsets[:, None] * rows[6:12, None, :]).reshape(6, -1)
    p = propagation
    paths = _paths(points, fixed, p.water_depth, p.surface_reflection, p.bed_reflection, p.wavenumber)
    paths = paths.reshape(11, len(offsets), -1)
    out = np.empty((26, rows.shape[1]))
    _frame_combine(_apparent(paths, p.wavenumber), paths, offsets, 2 * np.pi / p.wavenumber, out)
    return out


@_compile
def _tone_angles(relative, relative_velocity, scales, offsets, times, mixer_phase, tone, angles, pressures):
    """Each path's (P), receiver's (R) and sample's (N) angle after the mixer and pressure (``angles``,
    ``pressures``, (P, R, N)) as :func:`aasl_gym.synthesis.received_pressure` computes them, operation for
    operation; whether every angle is within ``SINCOS_LIMIT`` (False for NaN too)."""
    phase, angular, sound_speed = tone[0], tone[1], tone[2]
    largest = 0.0
    for p in range(relative.shape[0]):
        for r in range(relative.shape[1]):
            x0, y0, z0 = relative[p, r, 0], relative[p, r, 1], relative[p, r, 2]
            vx, vy, vz = relative_velocity[p, r, 0], relative_velocity[p, r, 1], relative_velocity[p, r, 2]
            for n in range(times.shape[0]):
                x, y, z = x0 + vx * offsets[n], y0 + vy * offsets[n], z0 + vz * offsets[n]
                distance = math.sqrt(x * x + y * y + z * z)
                angle = (phase + angular * (times[n] - distance / sound_speed)) - mixer_phase[n]
                angles[p, r, n], pressures[p, r, n] = angle, scales[p] / distance
                largest = max(largest, abs(angle))
    return largest <= SINCOS_LIMIT


@_compile
def _add_phasors(angles, pressures, real, imaginary):
    """``real`` and ``imaginary`` (R, N) plus every path's pressure times cos and sin of its angle, path by path."""
    for p in range(angles.shape[0]):
        for r in range(angles.shape[1]):
            for n in range(angles.shape[2]):
                sine, cosine = _sincos(angles[p, r, n])
                real[r, n] += pressures[p, r, n] * cosine
                imaginary[r, n] += pressures[p, r, n] * sine


def tone_envelope(
    relative: np.ndarray,
    relative_velocity: np.ndarray,
    scales: np.ndarray,
    offsets: np.ndarray,
    times: np.ndarray,
    mixer_phase: np.ndarray,
    tone: tuple[float, float, float],
) -> np.ndarray | None:
    """A tone's complex envelope (R, N) at R receivers from P paths: each path's source (an image for a reflected
    one) at ``relative`` (P, R, 3; m) from each receiver, moving at ``relative_velocity`` (P, R, 3; m/s), its gain
    times the peak pressure at 1 m in ``scales`` (P,); sampled at ``times`` (N,; s), ``offsets`` (N,; s) from the
    frame's centre, mixed down by ``mixer_phase`` (N,; rad); ``tone`` = (phase (rad), 2 pi f0 (rad/s), sound
    speed (m/s)). The same to the last bit as :func:`aasl_gym.synthesis.received_pressure`'s NumPy form; None
    where an angle is beyond the polynomial's range (the caller then takes NumPy's sine)."""
    shape = relative.shape[:2] + times.shape
    angles, pressures = np.empty(shape), np.empty(shape)
    constants = np.array(tone, dtype=float)
    if not _tone_angles(relative, relative_velocity, scales, offsets, times, mixer_phase, constants, angles, pressures):
        return None
    real, imaginary = np.zeros(shape[1:]), np.zeros(shape[1:])
    _add_phasors(angles, pressures, real, imaginary)
    envelope = np.empty(shape[1:], dtype=complex)
    envelope.real, envelope.imag = real, imaginary
    return envelope


@_compile
def _window_terms(values, receiver, biases, measured, noise, variances, period, white, residual):
    """For every start c and sample k: R_eff = R_ac + H_r diag(variances) H_r^T, its whitener W = L^-1 (R_eff =
    L L^T; lower triangular) into ``white`` (C, K, 2, 2), and W (z_k - h_ck - b_c) into ``residual`` (C, K, 2),
    the RD difference wrapped to [-period/2, period/2) where ``period`` > 0."""
    position_variance, velocity_variance = variances[0], variances[1]
    for c in range(values.shape[0]):
        for k in range(values.shape[1]):
            r00, r01, r11 = noise[0, 0], noise[1, 0], noise[1, 1]
            for j in range(6):
                variance = position_variance if j < 3 else velocity_variance
                rd, rrd = receiver[c, k, 0, j], receiver[c, k, 1, j]
                r00 += variance * rd * rd
                r01 += variance * rd * rrd
                r11 += variance * rrd * rrd
            a = math.sqrt(r00)
            b = r01 / a
            d = math.sqrt(r11 - b * b)
            w00, w10, w11 = 1.0 / a, -b / (a * d), 1.0 / d
            white[c, k, 0, 0], white[c, k, 0, 1], white[c, k, 1, 0], white[c, k, 1, 1] = w00, 0.0, w10, w11
            rd_error = measured[k, 0] - (values[c, k, 0] + biases[c, 0])
            rrd_error = measured[k, 1] - (values[c, k, 1] + biases[c, 1])
            if period > 0.0:
                rd_error = (rd_error + 0.5 * period) % period - 0.5 * period
            residual[c, k, 0] = w00 * rd_error
            residual[c, k, 1] = w10 * rd_error + w11 * rrd_error


def window_terms(
    values: np.ndarray,
    receiver: np.ndarray,
    biases: np.ndarray,
    measured: np.ndarray,
    noise: np.ndarray,
    navigation_sd: tuple[float, float],
    period: float | None,
) -> tuple[np.ndarray, np.ndarray]:
    """A window fit's per-sample terms for C starts along K samples: the whitener W (C, K, 2, 2) of R_eff = R_ac +
    H_r Sigma_r H_r^T and the whitened residual W (z - h - b) (C, K, 2).

    ``values`` (C, K, 2) are the model's [RD, RRD] (m, m/s) along each start's trajectory, ``receiver`` (C, K, 2, 6)
    its Jacobian in the receiver's [p_m, v_m], ``biases`` (C, 2) each start's [b_p, b_v], ``measured`` (K, 2) the
    window's measurements, ``noise`` (2, 2) R_ac, ``navigation_sd`` (m, m/s) the reported receiver state's white
    error; the RD difference is wrapped to [-period/2, period/2) (m) unless ``period`` is None. The same as
    :func:`aasl_gym.initializers.trajectory_whitener` and :func:`aasl_gym.initializers.whiten` of
    :func:`aasl_gym.initializers.periodic_residual` to a few units in the last place."""
    count, samples = values.shape[:2]
    white, residual = np.empty((count, samples, 2, 2)), np.empty((count, samples, 2))
    variances = np.square(np.asarray(navigation_sd, dtype=float))
    period = 0.0 if period is None else float(period)
    noise = np.asarray(noise, dtype=float)
    _window_terms(values, receiver, biases, measured, noise, variances, period, white, residual)
    return white, residual


@_compile
def _whitened_chain(local, motion, white, out):
    """``out`` (C, K, 2, n) = W_ck [local_ck motion_ck | I_2] for the lower-triangular whiteners ``white``."""
    moving, dim = motion.shape[3], out.shape[3]
    for c in range(motion.shape[0]):
        for k in range(motion.shape[1]):
            w00, w10, w11 = white[c, k, 0, 0], white[c, k, 1, 0], white[c, k, 1, 1]
            for j in range(moving):
                rd, rrd = 0.0, 0.0
                for m in range(6):
                    rd += local[c, k, 0, m] * motion[c, k, m, j]
                    rrd += local[c, k, 1, m] * motion[c, k, m, j]
                out[c, k, 0, j], out[c, k, 1, j] = w00 * rd, w10 * rd + w11 * rrd
            out[c, k, 0, dim - 2], out[c, k, 1, dim - 2] = w00, w10  # the biases' unit columns, whitened
            out[c, k, 0, dim - 1], out[c, k, 1, dim - 1] = 0.0, w11


def whitened_chain(local: np.ndarray, motion: np.ndarray, white: np.ndarray) -> np.ndarray:
    """A window fit's Jacobian at every sample, whitened: W_k [d[RD, RRD]/d[p, v] @ d[p, v](t_k)/d x | I_2]
    (C, K, 2, n), from the measurement model's ``local`` (C, K, 2, 6), the motion model's trajectory Jacobian
    ``motion`` (C, K, 6, n - 2; a broadcast view will do) and lower-triangular whiteners ``white`` (C, K, 2, 2).
    The two bias columns are unit vectors before whitening (the biases add to the prediction)."""
    count, samples, _, moving = motion.shape
    out = np.empty((count, samples, 2, moving + 2))
    _whitened_chain(local, motion, white, out)
    return out
