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
variable, reading more than a few arrays (each needs a run-time overlap check; past LLVM's limit it
gives up), a test of a constant inside the loop (a mode: soft-L1 or not, a period, a fold) and a running maximum.
So the loops read one array of rows and the fixed hydrophone as one point, and such tests sit outside them (session
41: a window fit's per-sample terms a loop per mode, 12 % off a fit; the tone's angles and their maximum in two
loops, the tone envelope's time halved). Where each lane needs its own small solve, the solve runs over the lanes as
well (:func:`_lane_solves`: every lane's Levenberg-Marquardt step at once, its row swaps as selects; 7 % more off a
fit).

The window fit's per-sample algebra (:func:`window_terms`, :func:`whitened_chain`) is a few dozen flops on
2 x 2 and 2 x 6 blocks per sample; as NumPy expressions it was two dozen calls on small arrays and stacked
matrix products of 2 x 6 blocks, which NumPy loops over one by one (a third of a fit's time, session 27).
A window fit now runs in one pass per start (:func:`fit_terms`, and :func:`fit` for the whole
Levenberg-Marquardt): the measurement model (the frame-averaged phasor model, a geometric world's instantaneous one
or the direct path), R_eff's whitener, the chained Jacobian and the normal equations of a
block of starts, sample by sample, in cache, with no array between the stages. Every stage's innermost loop runs
over the block's starts, so it vectorises, and each start sums its own samples in order, so the result does not
depend on the vector width. The arctangent is a polynomial too (:func:`_atan2`): in a loop the C library's is a
call per element. A search from the prior's 1,076 starts went from 104 to 31 ms (session 31).

The tone's complex envelope (:func:`tone_envelope`) runs the synthesis's NumPy expressions operation for
operation and is the same to the last bit (LLVM does not contract a multiply and an add into one rounding
unless told to); the loops above only agree with their NumPy forms to a few units in the last place.

A geometric world's phasor model, [RD, RRD] (:func:`phasor_measurement`), is the apparent RD's pass with its rate
taken along the RD's gradients: a geometric default-world episode (CV, helix, seeds 0-2) ran 45 steps/s with NumPy's
form and 112 with this one (session 45). Its window fits run in the fit's pass (:func:`_phasor_at_sample`, session
50: the geometric default world's whole episodes some 18 % faster than with NumPy's Levenberg-Marquardt).

The direct path runs in the same pass (:func:`_direct`: the values and both Jacobians in closed form), for window
fits from one start on (session 32: a lone start runs unpadded), and in one pass over LC-MAP's grid
(:func:`lcmap_grid`: a thousand candidates or more along twenty samples, each one's velocity solve and score in
cache; 26 -> 9 ms an LC-MAP run; since session 41 in blocks of candidates, each stage's loop over a block as in the
window fit, 45 % less again). The unscented filters' sigma points, moments and update (:func:`sigma_points`,
:func:`sigma_moments`, :func:`unscented_update`), a channel's clipping count (:func:`peak_counts`), a tone frame's
estimate (:func:`tone_estimate`), the reward's Fisher information step (:func:`information_step`) and the greedy
planner's horizon (:func:`horizon_information`) are compiled too: each was a dozen NumPy calls on arrays of a few
dozen numbers, every step. So is a filter bank's
whole step, once for all its filters: a CV bank's prediction (:func:`constant_velocity_prediction`), the measurement
model under the phasor model (:func:`frame_and_direct`, :func:`ripple_measurements`: the frame model and the direct
path at every sigma point in one pass, the ripple's correction and R_eff's navigation term in another, NumPy's
arctangent between them) and the update (:func:`unscented_updates`), each to the last bit of the NumPy route it
replaces (session 43: a lone filter's step had spent more on thirty calls' set-up than on the models). The tone
detector's lower bound (:func:`peak_over_median_bound`) is the one kernel whose sums LLVM may reorder (``fastmath``'s
reassociation): only a bound, cleared by a margin, is taken from them (session 44: most frames then skip the
detector's padded FFT).

Compiled code is cached next to this file (``cache=True``): the first run on a machine compiles (about
50 seconds on the development machine, most of it the window fit's pass, which holds all three measurement models;
the filter bank's four kernels add 5), later processes load it (about 0.15 s, at the first call).

Why one module for every stage's loops. numba checks a cached kernel only against the file that defines it (a hash
of its contents since numba 0.68, its time stamp and size before): a kernel that calls a compiled function from
another file keeps its old machine code when only that other file changes (the limits of ``cache=True`` in numba's
user guide; numba issue #1833), so a split would let a kernel run a model the source no longer holds. A separate limit
of the cache: a module constant such as ``FIT_BLOCK`` or ``LANES`` is frozen into the cached code, so change it in
the source, not at run time.
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


# Cephes' arctangent (S. L. Moshier, 1984-2000): atan(t) = t + t z P(z) / Q(z), z = t^2, for |t| <= tan(pi/8).
_AP0, _AP1, _AP2 = -8.750608600031904122785e-01, -1.615753718733365076637e01, -7.500855792314704667340e01
_AP3, _AP4 = -1.228866684490136173410e02, -6.485021904942025371773e01
_AQ0, _AQ1, _AQ2 = 2.485846490142306297962e01, 1.650270098316988542046e02, 4.328810604912902668951e02
_AQ3, _AQ4 = 4.853903996359136964868e02, 1.945506571482613964425e02
_TAN_PI_8 = 0.41421356237309503


@numba.njit(inline="always", error_model="numpy")
def _atan2(y: float, x: float) -> float:
    """atan2(y, x) (rad), branch-free so that a loop calling it vectorises (the C library's is one call per
    element). The angle of the smaller over the larger of |x| and |y| is taken to |t| <= tan(pi/8) by
    atan(t) = pi/4 + atan((t - 1) / (t + 1)), then placed in its octant; signed zeros as NumPy's. Within 3 ulp of
    ``np.arctan2`` (``tests/test_kernels.py``)."""
    ax, ay = abs(x), abs(y)
    steep = ay > ax
    small, large = (ax if steep else ay), (ay if steep else ax)
    t = small / large if large > 0.0 else 0.0
    upper = t > _TAN_PI_8
    t = (t - 1.0) / (t + 1.0) if upper else t
    z = t * t
    p = (((_AP0 * z + _AP1) * z + _AP2) * z + _AP3) * z + _AP4
    q = ((((z + _AQ0) * z + _AQ1) * z + _AQ2) * z + _AQ3) * z + _AQ4
    angle = t + t * z * p / q
    angle = angle + 0.25 * math.pi if upper else angle
    angle = 0.5 * math.pi - angle if steep else angle
    angle = math.pi - angle if math.copysign(1.0, x) < 0.0 else angle
    return math.copysign(angle, y)


@_compile
def _atan2_loop(y, x, out):
    for i in range(x.shape[0]):
        out[i] = _atan2(y[i], x[i])


def arctan2(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """:func:`_atan2` over two 1-D arrays of the same length: what the tests hold to ``np.arctan2``."""
    y, x = np.ascontiguousarray(y, dtype=float), np.ascontiguousarray(x, dtype=float)
    out = np.empty_like(x)
    _atan2_loop(y, x, out)
    return out


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
    # Each range and |M|^2 divides several terms: one reciprocal each, then products (a division costs some ten
    # multiplications in the vectorised loops; session 48: a tenth of a phasor window fit).
    inverse, surface_inverse, bed_inverse, k_inverse = 1.0 / d, 1.0 / surface_range, 1.0 / bed_range, 1.0 / k
    # The path-length differences are bounded by the water column (k (r_i - d) <= 2 k D, hundreds of rad), far
    # inside SINCOS_LIMIT, so the loop calls the polynomial directly.
    surface_sin, surface_cos = _sincos(k * (surface_range - d))
    bed_sin, bed_cos = _sincos(k * (bed_range - d))
    surface_amplitude, bed_amplitude = surface_gain * d * surface_inverse, bed_gain * d * bed_inverse
    t1r, t1i = surface_amplitude * surface_cos, -surface_amplitude * surface_sin
    t2r, t2i = bed_amplitude * bed_cos, -bed_amplitude * bed_sin
    factor_real, factor_imag = 1.0 + t1r + t2r, t1i + t2i
    power_inverse = 1.0 / (factor_real * factor_real + factor_imag * factor_imag)
    # w_i = T_i / M; the phase's gradient is A u - sum_i B_i S u_i with A = sum_i (Im w_i / d + k Re w_i)
    # and B_i = Im w_i / r_i + k Re w_i (u, u_i the unit vectors to the source and its images).
    w1r, w1i = (
        (t1r * factor_real + t1i * factor_imag) * power_inverse,
        (t1i * factor_real - t1r * factor_imag) * power_inverse,
    )
    w2r, w2i = (
        (t2r * factor_real + t2i * factor_imag) * power_inverse,
        (t2i * factor_real - t2r * factor_imag) * power_inverse,
    )
    direct_scale = (w1i + w2i) * inverse + k * (w1r + w2r)
    surface_scale, bed_scale = w1i * surface_inverse + k * w1r, w2i * bed_inverse + k * w2r
    image_horizontal = surface_scale * surface_inverse + bed_scale * bed_inverse
    image_vertical = surface_scale * surface_vertical * surface_inverse + bed_scale * bed_vertical * bed_inverse
    horizontal_scale = inverse - (direct_scale * inverse - image_horizontal) * k_inverse
    direct_vertical = oz * (inverse - direct_scale * inverse * k_inverse)
    return ox, oy, d, factor_real, factor_imag, horizontal_scale, direct_vertical, -image_vertical * k_inverse


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
        if s > 0:  # outside the loop over the columns, as in _frame_mean_slope
            for i in range(count):
                slips[i] += np.rint((range_difference[s, i] - range_difference[s - 1, i]) / period)
        for i in range(count):
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
    if all(a.shape == (3,) for a in arrays):  # one point each (a filter's, the env's): one call, not twelve
        return (), np.concatenate(arrays)[:, None]
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


@_compile
def _rate_loop(paths, rows, out):
    """The apparent RD's rate for the columns of ``paths`` (:func:`_phasor_loop`'s rows) and ``rows`` (12, N: the
    source's and the mobile's positions, then their velocities): its gradients along the two velocities."""
    for i in range(rows.shape[1]):
        source = paths[5, i] * rows[6, i] + paths[6, i] * rows[7, i] + paths[7, i] * rows[8, i]
        out[i] = source + (paths[8, i] * rows[9, i] + paths[9, i] * rows[10, i] + paths[10, i] * rows[11, i])


def phasor_measurement(
    position,
    velocity,
    mobile,
    mobile_velocity,
    fixed,
    water_depth: float,
    surface_reflection: float,
    bed_reflection: float,
    wavenumber: float,
) -> np.ndarray:
    """The phasor model's [RD, RRD] (..., 2; m, m/s) for source and mobile states that broadcast together and one
    fixed hydrophone (3,): the apparent RD of :func:`phasor_paths` and its time derivative - the fixed hydrophone
    being still, the RD's gradients along the source's and the mobile's velocities - from one compiled pass. The
    same as :func:`aasl_gym.geometry.phasor_multipath` (NumPy's, which differentiates each receiver's phase in time)
    to rounding (``tests/test_kernels.py``); a geometric world's sensor and filters run it at every step (its window
    fits, the same model in the fit's pass: :func:`_phasor_at_sample`)."""
    shape, rows = _rows(position, mobile, velocity, mobile_velocity)
    paths = _paths(rows, _fixed_point(fixed), water_depth, surface_reflection, bed_reflection, wavenumber)
    return np.moveaxis(_measured(paths, rows, wavenumber).reshape((2, *shape)), 0, -1)


def _measured(paths: np.ndarray, rows: np.ndarray, wavenumber: float) -> np.ndarray:
    """[RD, RRD] (2, N) from the loops' rows ``paths`` (11, N) at the states ``rows`` (12, N)."""
    z = np.empty((2, rows.shape[1]))
    z[0] = _apparent(paths, wavenumber)
    _rate_loop(paths, rows, z[1])
    return z


# s: the time step of the central difference that gives the phasor RRD's position Jacobians: the source and the robot
# move some 10 um, where the RD's gradients vary on the ripple's scale, a fraction of a 1.5 m wavelength (next to an
# interference null, millimetres). Against central differences of the model, 1e-6 m (m/s) in each of p, v, p_m, v_m,
# on 400 random states: 1e-3 s erred by up to 3 %, 1e-5 s by 3e-6 (relative, the worst state; the median 1e-10).
RATE_JACOBIAN_STEP = 1e-5


def phasor_linearized(
    position,
    velocity,
    mobile,
    mobile_velocity,
    fixed,
    water_depth: float,
    surface_reflection: float,
    bed_reflection: float,
    wavenumber: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`phasor_measurement`'s [RD, RRD] (..., 2; the same numbers to the last bit) with its Jacobians
    d[RD, RRD]/d[p, v] and d[RD, RRD]/d[p_m, v_m] (..., 2, 6 each). The RD's rows and the RRD's velocity columns are
    the RD's gradients from the pass itself (RRD = grad_p RD . v + grad_m RD . v_m). The RRD's position columns are
    the RD's Hessian times the velocities, that is the time derivative of those gradients as the source and the robot
    move on: a central difference in time of the pass's gradients (``RATE_JACOBIAN_STEP``), two more passes in all,
    where differences of the model in each state component took twelve."""
    shape, rows = _rows(position, mobile, velocity, mobile_velocity)
    count, fixed = rows.shape[1], _fixed_point(fixed)
    step = RATE_JACOBIAN_STEP
    moved = np.concatenate([rows[0:6], rows[0:6] + step * rows[6:12], rows[0:6] - step * rows[6:12]], axis=1)
    paths = _paths(moved, fixed, water_depth, surface_reflection, bed_reflection, wavenumber)
    now = paths[:, :count]
    values = _measured(now, rows, wavenumber)
    gradients = now[5:11]  # the RD's in the source's position (3), then in the robot's (3)
    rates = (paths[5:11, count : 2 * count] - paths[5:11, 2 * count :]) / (2 * step)
    local, receiver = np.zeros((2, 6, count)), np.zeros((2, 6, count))
    for jacobian, part in ((local, slice(0, 3)), (receiver, slice(3, 6))):
        jacobian[0, 0:3] = jacobian[1, 3:6] = gradients[part]
        jacobian[1, 0:3] = rates[part]
    return (
        np.moveaxis(values.reshape((2, *shape)), 0, -1),
        np.moveaxis(local.reshape((12, *shape)), 0, -1).reshape(shape + (2, 6)),
        np.moveaxis(receiver.reshape((12, *shape)), 0, -1).reshape(shape + (2, 6)),
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
    return _columns(out, shape)


def _columns(out: np.ndarray, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows (26, N) the frame model's and the direct path's loops write as [RD, RRD] (..., 2), d[RD, RRD]/d[p, v]
    and d[RD, RRD]/d[p_m, v_m] (..., 2, 6 each) for states of leading ``shape``."""
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
    paths = _paths(points, fixed, *p.channel).reshape(11, len(offsets), -1)
    out = np.empty((26, rows.shape[1]))
    _frame_combine(_apparent(paths, p.wavenumber), paths, offsets, 2 * np.pi / p.wavenumber, out)
    return out


@_compile
def _frame_and_direct_paths(position, velocity, mobile, mobile_velocity, fixed, offsets, channel, paths, direct):
    """:func:`_frame_block`'s phasor rows ``paths`` (11, S, N) and :func:`_direct_loop`'s rows ``direct`` (26, N) for
    the N states ``position`` and ``velocity`` (N, 3 each) and one mobile receiver (3,), in one call: the two loops on
    one set of rows (12, N), :func:`_frame_block`'s frame samples (x + tau x') taken from them as it takes them."""
    count = position.shape[0]
    rows = np.empty((12, count))
    for i in range(count):
        for c in range(3):
            rows[c, i], rows[3 + c, i] = position[i, c], mobile[c]
            rows[6 + c, i], rows[9 + c, i] = velocity[i, c], mobile_velocity[c]
    points = np.empty((6, offsets.shape[0] * count))  # sample-major, as _frame_block lays them out
    for s in range(offsets.shape[0]):
        for q in range(6):
            for i in range(count):
                points[q, s * count + i] = rows[q, i] + offsets[s] * rows[6 + q, i]
    _phasor_loop(points, fixed, channel[0], channel[1], channel[2], channel[3], paths.reshape(11, -1))
    _direct_loop(rows, fixed, direct)


def frame_and_direct(
    position, velocity, mobile, mobile_velocity, fixed, offsets: np.ndarray, propagation
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`frame_phasor`'s [RD, RRD] and receiver Jacobian and :func:`direct_path`'s, for source states (..., 3
    each; at most ``CHUNK`` of them) and one mobile receiver (3,): the same numbers to the last bit, from one pass
    over the states (an unscented filter bank's sigma points take both every step)."""
    shape = np.shape(position)[:-1]
    if np.shape(velocity) != np.shape(position) or np.shape(position)[-1:] != (3,):
        raise ValueError(f"position and velocity must share one shape (..., 3), got {np.shape(position)} and "
                         f"{np.shape(velocity)}")  # fmt: skip
    position = np.ascontiguousarray(position, dtype=float).reshape(-1, 3)
    count = position.shape[0]
    if count > CHUNK:
        raise ValueError(f"at most {CHUNK} states a call, got {count}")
    offsets, p = np.asarray(offsets, dtype=float), propagation
    channel = np.array(p.channel, dtype=float)
    paths, direct = np.empty((11, len(offsets), count)), np.empty((26, count))
    _frame_and_direct_paths(
        position, np.ascontiguousarray(velocity, dtype=float).reshape(-1, 3), np.array(mobile, dtype=float).reshape(3),
        np.array(mobile_velocity, dtype=float).reshape(3), _fixed_point(fixed), offsets, channel, paths, direct,
    )  # fmt: skip
    frame = np.empty((26, count))
    _frame_combine(_apparent(paths, p.wavenumber), paths, offsets, 2 * np.pi / p.wavenumber, frame)
    frame_values, _, frame_receiver = _columns(frame, shape)
    direct_values, _, direct_receiver = _columns(direct, shape)
    return frame_values, frame_receiver, direct_values, direct_receiver


@numba.njit(inline="always", error_model="numpy")
def _pair_dot6(a, b):
    """sum_q a[q] b[q] over six numbers in NumPy's ``einsum`` order for a contraction of six: two running sums,
    the even terms' and the odd terms', added at the end - the order of NumPy's baseline x86-64 build (two-lane
    vectors, no fused multiply-add). A build with wider vectors or fused multiply-adds (ARM, x86-64-v3) sums in
    another order; ``tests/test_kernels.py`` holds the two equal, and fails there."""
    even = a[0] * b[0] + a[2] * b[2] + a[4] * b[4]
    odd = a[1] * b[1] + a[3] * b[3] + a[5] * b[5]
    return even + odd


@_compile
def _ripple_measurements(frame, direct, receiver, offsets, period, scales, values, noise):
    """See :func:`ripple_measurements`; ``scales`` (6,) are the navigation sd per receiver coordinate."""
    half = 0.5 * period
    rd_row, rrd_row = np.empty(6), np.empty(6)
    for h in range(frame.shape[0]):
        centre_rd = frame[h, 0, 0] - direct[h, 0, 0]  # the RRD's correction is not wrapped: no centre needed
        for s in range(frame.shape[1]):
            offset = (frame[h, s, 0] - direct[h, s, 0] - centre_rd + half) % period - half
            values[h, s, 0] = direct[h, s, 0] + (centre_rd + offset) + offsets[h, s, 0]
            values[h, s, 1] = direct[h, s, 1] + (frame[h, s, 1] - direct[h, s, 1]) + offsets[h, s, 1]
        for q in range(6):
            rd_row[q], rrd_row[q] = receiver[h, 0, q] * scales[q], receiver[h, 1, q] * scales[q]
        # No ripple noise here: zero plus the navigation term, as the general route adds them.
        noise[h, 0, 0] = 0.0 + _pair_dot6(rd_row, rd_row)
        noise[h, 1, 1] = 0.0 + _pair_dot6(rrd_row, rrd_row)
        noise[h, 0, 1] = noise[h, 1, 0] = 0.0 + _pair_dot6(rd_row, rrd_row)


def ripple_measurements(
    frame: np.ndarray,
    direct: np.ndarray,
    receiver: np.ndarray,
    offsets: np.ndarray,
    period: float,
    navigation_sd: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """A bank's filter measurements under the phasor model where every filter resolves the ripple: from the frame
    model's [RD, RRD] ``frame`` and the direct path's ``direct`` at the sigma points (H, S, 2), each point's multipath
    correction (frame - direct) taken within half a ``period`` (m) of the central point's, plus the state's offsets
    b_p, b_v (``offsets``, H, S, 2); and the navigation term H_r Sigma_r H_r^T (H, 2, 2) of the frame model's receiver
    Jacobian at each mean (``receiver``, H, 2, 6) for ``navigation_sd`` (m, m/s). The numbers of
    :meth:`aasl_gym.estimator.SourceTracker._sigma_model`'s NumPy route with
    :func:`aasl_gym.measurement_models.receiver_noise`, to the last bit, in one call."""
    count, samples = frame.shape[:2]
    values, noise = np.empty((count, samples, 2)), np.empty((count, 2, 2))
    position_sd, velocity_sd = navigation_sd
    scales = np.array((position_sd,) * 3 + (velocity_sd,) * 3, dtype=float)
    _ripple_measurements(
        np.ascontiguousarray(frame, dtype=float), np.ascontiguousarray(direct, dtype=float),
        np.ascontiguousarray(receiver, dtype=float), np.ascontiguousarray(offsets, dtype=float), float(period),
        scales, values, noise,
    )  # fmt: skip
    return values, noise


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
                angles[p, r, n] = (phase + angular * (times[n] - distance / sound_speed)) - mixer_phase[n]
                pressures[p, r, n] = scales[p] / distance
            for n in range(times.shape[0]):  # apart: a running maximum kept the loop above from vectorising
                largest = max(largest, abs(angles[p, r, n]))
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


@numba.njit(inline="always", error_model="numpy")
def _wrapped(value: float, period: float) -> float:
    """``value`` (m) wrapped to [-period/2, period/2) by floor, which vectorises (Python's % on floats is a call to
    fmod)."""
    return value - period * math.floor((value + 0.5 * period) / period)


@numba.njit(inline="always", error_model="numpy")
def _whitener(r00, r01, r11):
    """(w00, w10, w11): W = L^-1 for R = L L^T (lower triangular) of a 2 x 2 covariance [[r00, r01], [r01, r11]]."""
    a = math.sqrt(r00)
    b = r01 / a
    d = math.sqrt(r11 - b * b)
    return 1.0 / a, -b / (a * d), 1.0 / d


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
            w00, w10, w11 = _whitener(r00, r01, r11)
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


# Starts per block of :func:`_fit_terms`: its scratch rows (about a hundred per start) then stay in the core's caches.
FIT_BLOCK = 64
DIRECT_PATH, FRAME_PHASOR, INSTANT_PHASOR = 0, 1, 2  # the measurement models the window fit's pass knows
# Starts per pass of :func:`_fit_terms`' vectorised loops as LLVM compiles them: one AVX-512 vector, two AVX2.
LANES = 8


@numba.njit(inline="always", error_model="numpy")
def _dot6(local, first, i, sign, m0, m1, m2, m3, m4, m5):
    """sum_q local[first + q, i] m_q over q = 0..5, summed in order from zero, the fold's ``sign`` on m2 and m5."""
    total = 0.0
    total += local[first, i] * m0
    total += local[first + 1, i] * m1
    total += local[first + 2, i] * (sign * m2)
    total += local[first + 3, i] * m3
    total += local[first + 4, i] * m4
    total += local[first + 5, i] * (sign * m5)
    return total


@numba.njit(inline="always", error_model="numpy")
def _chain(local, sign, white, rows, i, j, m0, m1, m2, m3, m4, m5):
    """Column j of the sample's whitened Jacobian for block column i: W [local @ motion[:, j]], ``motion``'s column
    (m0..m5) with the fold's ``sign`` on its z and v_z rows (exact: a factor of +-1)."""
    rd = _dot6(local, 0, i, sign, m0, m1, m2, m3, m4, m5)
    rrd = _dot6(local, 6, i, sign, m0, m1, m2, m3, m4, m5)
    rows[0, j, i] = white[0, i] * rd
    rows[1, j, i] = white[1, i] * rd + white[2, i] * rrd


@numba.njit(inline="always", error_model="numpy")
def _lane_states(states, motion, points, k, start, width, fold, lanes):
    """The source's position and velocity at sample k (``lanes`` rows 0:6) and the fold's sign there (row 6) for the
    block's ``width`` starts from ``start``: from ``points`` (6, K, C) where the trajectories are given (the signs
    already in ``motion``), else the free motion ``motion[k]`` (6, m) times the block's ``states`` (n, B), folded
    into ``fold`` (z_min, slab span; a span of 0 for none) as :meth:`aasl_gym.filters.MotionModel.trajectory` folds.
    ``points`` without rows (0, 0, 0) says that no trajectories were given (a single start's given trajectory has
    one column, as one shared free motion does, so the motion's shape cannot say)."""
    if points.shape[0] > 0:
        for q in range(6):
            for i in range(width):
                lanes[q, i] = points[q, k, start + i]
        for i in range(width):
            lanes[6, i] = 1.0
        return
    for q in range(6):
        for i in range(width):
            lanes[q, i] = 0.0
    for j in range(motion.shape[2]):
        m0, m1, m2 = motion[k, 0, j, 0], motion[k, 1, j, 0], motion[k, 2, j, 0]
        m3, m4, m5 = motion[k, 3, j, 0], motion[k, 4, j, 0], motion[k, 5, j, 0]
        for i in range(width):
            x = states[j, i]
            lanes[0, i] += m0 * x
            lanes[1, i] += m1 * x
            lanes[2, i] += m2 * x
            lanes[3, i] += m3 * x
            lanes[4, i] += m4 * x
            lanes[5, i] += m5 * x
    low, span = fold[0], fold[1]
    for i in range(width):
        lanes[6, i] = 1.0
    if span > 0.0:  # outside the loop: a branch within it kept the loop from vectorising
        for i in range(width):
            phase = (lanes[2, i] - low) % (2 * span)
            mirrored = phase > span
            lanes[2, i] = low + (2 * span - phase if mirrored else phase)
            lanes[5, i] = -lanes[5, i] if mirrored else lanes[5, i]
            lanes[6, i] = -1.0 if mirrored else 1.0


@numba.njit(inline="always", error_model="numpy")
def _frame_at_sample(lanes, k, width, receivers, fixed, offsets, channel, rows):
    """The apparent RD (``rows[:, 0]``) and its gradients in the source's and the mobile's positions (``rows[:, 1:4]``,
    ``rows[:, 4:7]``) at each frame offset of sample k (``rows`` (S, 7, B)), for the source states in ``lanes``
    (:func:`_lane_states`). One array out, so that the loop vectorises (see the module's note)."""
    depth, surface_gain, bed_gain, wavenumber = channel[0], channel[1], channel[2], channel[3]
    fx, fy, fz = fixed[0], fixed[1], fixed[2]
    inverse_wavenumber = 1.0 / wavenumber
    for s in range(offsets.shape[0]):
        tau = offsets[s]
        mx, my = receivers[0, k] + tau * receivers[3, k], receivers[1, k] + tau * receivers[4, k]
        mz = receivers[2, k] + tau * receivers[5, k]
        for i in range(width):
            sx, sy = lanes[0, i] + tau * lanes[3, i], lanes[1, i] + tau * lanes[4, i]
            sz = lanes[2, i] + tau * lanes[5, i]
            row = _pair(sx, sy, sz, mx, my, mz, fx, fy, fz, depth, surface_gain, bed_gain, wavenumber)
            # phi_f - phi_m as the phase of M_f conj(M_m): one arctangent, not two. It can differ from the two phases'
            # difference by a whole turn, a wavelength of RD, which the unwrapping across the offsets and the fit's
            # residual modulo the wavelength both ignore.
            product_real = row[3] * row[1] + row[4] * row[2]
            product_imag = row[4] * row[1] - row[3] * row[2]
            rows[s, 0, i] = row[0] + _atan2(product_imag, product_real) * inverse_wavenumber
            rows[s, 1, i], rows[s, 2, i], rows[s, 3, i] = row[5], row[6], row[7]
            rows[s, 4, i], rows[s, 5, i], rows[s, 6, i] = row[8], row[9], row[10]


@numba.njit(inline="always", error_model="numpy")
def _frame_mean_slope(width, offsets, period, rows, unwrapped, slips, value, local, receiver):
    """:func:`_frame_combine` for one sample of a block (``rows`` from :func:`_frame_at_sample`): [mean, slope] into
    ``value`` (2, B), their derivatives in [p, v] into ``local`` (12, B) and in [p_m, v_m] into ``receiver``
    (12, B), each a 2 x 6 block row by row."""
    frame = offsets.shape[0]
    spread = 0.0
    for s in range(frame):
        spread += offsets[s] * offsets[s]
    for i in range(width):
        slips[i], value[0, i], value[1, i] = 0.0, 0.0, 0.0
    for r in range(12):
        for i in range(width):
            local[r, i], receiver[r, i] = 0.0, 0.0
    for s in range(frame):
        if s > 0:
            for i in range(width):
                slips[i] += np.rint((rows[s, 0, i] - rows[s - 1, 0, i]) / period)
        for i in range(width):
            unwrapped[s, i] = rows[s, 0, i] - slips[i] * period
            value[0, i] += unwrapped[s, i] / frame
    for s in range(frame):
        slope_weight = offsets[s] / spread
        for i in range(width):
            value[1, i] += (unwrapped[s, i] - value[0, i]) * slope_weight
    for first, out in ((1, local), (4, receiver)):
        for c in range(3):
            for s in range(frame):
                tau = offsets[s]
                mean_weight, slope_weight = 1.0 / frame, tau / spread
                for i in range(width):
                    g = rows[s, first + c, i]
                    out[c, i] += g * mean_weight
                    out[3 + c, i] += g * mean_weight * tau
                    out[6 + c, i] += g * slope_weight
                    out[9 + c, i] += g * slope_weight * tau


@numba.njit(inline="always", error_model="numpy")
def _direct(sx, sy, sz, vx, vy, vz, mx, my, mz, mvx, mvy, mvz, fx, fy, fz):
    """The direct path's RD, RRD and their gradients for a source at (sx, sy, sz) moving at (vx, vy, vz), the mobile
    hydrophone at (mx, my, mz) moving at (mvx, mvy, mvz) and the fixed one at (fx, fy, fz): (RD, RRD, g, q, u_m, w),
    each vector as three numbers. g = u_m - u_f is dRD/dp and dRRD/dv, and q = dRRD/dp = w - (I - u_f u_f^T) v_s / d_f
    with the mobile's share w = (I - u_m u_m^T)(v_s - v_m) / d_m (:func:`aasl_gym.geometry.direct_jacobian`); the
    receiver's Jacobian is dRD/dp_m = dRRD/dv_m = -u_m, dRRD/dp_m = -w
    (:func:`aasl_gym.measurement_models.direct_receiver_jacobian`)."""
    ax, ay, az = sx - mx, sy - my, sz - mz
    bx, by, bz = sx - fx, sy - fy, sz - fz
    mobile_range = math.sqrt(ax * ax + ay * ay + az * az)
    fixed_range = math.sqrt(bx * bx + by * by + bz * bz)
    ax, ay, az = ax / mobile_range, ay / mobile_range, az / mobile_range
    bx, by, bz = bx / fixed_range, by / fixed_range, bz / fixed_range
    rx, ry, rz = vx - mvx, vy - mvy, vz - mvz
    mobile_rate = rx * ax + ry * ay + rz * az
    fixed_rate = vx * bx + vy * by + vz * bz
    px = (rx - ax * mobile_rate) / mobile_range
    py = (ry - ay * mobile_rate) / mobile_range
    pz = (rz - az * mobile_rate) / mobile_range
    qx = px - (vx - bx * fixed_rate) / fixed_range
    qy = py - (vy - by * fixed_rate) / fixed_range
    qz = pz - (vz - bz * fixed_rate) / fixed_range
    rd, rrd = mobile_range - fixed_range, mobile_rate - fixed_rate
    return rd, rrd, ax - bx, ay - by, az - bz, qx, qy, qz, ax, ay, az, px, py, pz


@_compile
def _direct_loop(rows, fixed, out):
    """:func:`_direct` for the states in ``rows`` (12, N: the source's and the mobile's positions, then their
    velocities): [RD, RRD], d/d[p, v] and d/d[p_m, v_m] row by row into ``out`` (26, N), as :func:`_frame_combine`
    lays out the frame model's."""
    fx, fy, fz = fixed[0], fixed[1], fixed[2]
    for i in range(rows.shape[1]):
        rd, rrd, gx, gy, gz, qx, qy, qz, ax, ay, az, px, py, pz = _direct(
            rows[0, i], rows[1, i], rows[2, i], rows[6, i], rows[7, i], rows[8, i],
            rows[3, i], rows[4, i], rows[5, i], rows[9, i], rows[10, i], rows[11, i], fx, fy, fz,
        )  # fmt: skip
        out[0, i], out[1, i] = rd, rrd
        out[2, i], out[3, i], out[4, i], out[5, i], out[6, i], out[7, i] = gx, gy, gz, 0.0, 0.0, 0.0
        out[8, i], out[9, i], out[10, i], out[11, i], out[12, i], out[13, i] = qx, qy, qz, gx, gy, gz
        out[14, i], out[15, i], out[16, i], out[17, i], out[18, i], out[19, i] = -ax, -ay, -az, 0.0, 0.0, 0.0
        out[20, i], out[21, i], out[22, i], out[23, i], out[24, i], out[25, i] = -px, -py, -pz, -ax, -ay, -az


def direct_path(position, velocity, mobile, mobile_velocity, fixed) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The direct path's [RD, RRD] (..., 2; m, m/s) and its Jacobians d[RD, RRD]/d[p, v] and d[RD, RRD]/d[p_m, v_m]
    (..., 2, 6 each) in one compiled pass, for source and mobile positions (m) and velocities (m/s) that broadcast
    together and one fixed hydrophone (3,; a ValueError names any other shape): the
    same as :func:`aasl_gym.measurement_models.direct_measurement`, :func:`aasl_gym.geometry.direct_jacobian` and
    :func:`aasl_gym.measurement_models.direct_receiver_jacobian` to rounding (``tests/test_kernels.py``), at a few
    microseconds for one point or a filter's sigma points (NumPy's forms: 14 us for the values alone)."""
    shape, rows = _rows(position, mobile, velocity, mobile_velocity)
    out = np.empty((26, rows.shape[1]))
    _direct_loop(rows, _fixed_point(fixed), out)
    return _columns(out, shape)


@numba.njit(inline="always", error_model="numpy")
def _direct_at_sample(lanes, k, width, receivers, fixed, value, local, receiver):
    """The direct path's [RD, RRD] (``value`` (2, B)) and its Jacobians in [p, v] (``local`` (12, B)) and in [p_m, v_m]
    (``receiver`` (12, B)) at sample k (:func:`_direct`), laid out as :func:`_frame_mean_slope` lays out the frame
    model's."""
    mx, my, mz = receivers[0, k], receivers[1, k], receivers[2, k]
    mvx, mvy, mvz = receivers[3, k], receivers[4, k], receivers[5, k]
    fx, fy, fz = fixed[0], fixed[1], fixed[2]
    for i in range(width):
        rd, rrd, gx, gy, gz, qx, qy, qz, ax, ay, az, px, py, pz = _direct(
            lanes[0, i], lanes[1, i], lanes[2, i], lanes[3, i], lanes[4, i], lanes[5, i],
            mx, my, mz, mvx, mvy, mvz, fx, fy, fz,
        )  # fmt: skip
        value[0, i], value[1, i] = rd, rrd
        local[0, i], local[1, i], local[2, i], local[3, i], local[4, i], local[5, i] = gx, gy, gz, 0.0, 0.0, 0.0
        local[6, i], local[7, i], local[8, i], local[9, i], local[10, i], local[11, i] = qx, qy, qz, gx, gy, gz
        receiver[0, i], receiver[1, i], receiver[2, i] = -ax, -ay, -az
        receiver[3, i], receiver[4, i], receiver[5, i] = 0.0, 0.0, 0.0
        receiver[6, i], receiver[7, i], receiver[8, i] = -px, -py, -pz
        receiver[9, i], receiver[10, i], receiver[11, i] = -ax, -ay, -az


@numba.njit(inline="always", error_model="numpy")
def _phasor_at_sample(lanes, k, width, receivers, fixed, channel, value, local, receiver):
    """The geometric worlds' phasor model's [RD, RRD] (``value`` (2, B)) and its Jacobians in [p, v] (``local``
    (12, B)) and in [p_m, v_m] (``receiver`` (12, B)) at sample k, as :func:`phasor_linearized` gives them: the RD's
    gradients from the pass, the RRD's position columns a central difference in time of those gradients
    (``RATE_JACOBIAN_STEP``); laid out as :func:`_frame_mean_slope` lays out the frame model's."""
    depth, surface_gain, bed_gain, wavenumber = channel[0], channel[1], channel[2], channel[3]
    mx, my, mz = receivers[0, k], receivers[1, k], receivers[2, k]
    mvx, mvy, mvz = receivers[3, k], receivers[4, k], receivers[5, k]
    fx, fy, fz = fixed[0], fixed[1], fixed[2]
    step = RATE_JACOBIAN_STEP
    for i in range(width):
        sx, sy, sz, vx, vy, vz = lanes[0, i], lanes[1, i], lanes[2, i], lanes[3, i], lanes[4, i], lanes[5, i]
        now = _pair(sx, sy, sz, mx, my, mz, fx, fy, fz, depth, surface_gain, bed_gain, wavenumber)
        ahead = _pair(
            sx + step * vx, sy + step * vy, sz + step * vz, mx + step * mvx, my + step * mvy, mz + step * mvz,
            fx, fy, fz, depth, surface_gain, bed_gain, wavenumber,
        )  # fmt: skip
        behind = _pair(
            sx - step * vx, sy - step * vy, sz - step * vz, mx - step * mvx, my - step * mvy, mz - step * mvz,
            fx, fy, fz, depth, surface_gain, bed_gain, wavenumber,
        )  # fmt: skip
        # Two arctangents, as the filters' model (:func:`_apparent`): each receiver's phase wrapped on its own.
        value[0, i] = now[0] + (_atan2(now[4], now[3]) - _atan2(now[2], now[1])) / wavenumber
        source_rate = now[5] * vx + now[6] * vy + now[7] * vz
        value[1, i] = source_rate + (now[8] * mvx + now[9] * mvy + now[10] * mvz)
        for q in range(3):
            local[q, i], local[3 + q, i], local[9 + q, i] = now[5 + q], 0.0, now[5 + q]
            local[6 + q, i] = (ahead[5 + q] - behind[5 + q]) / (2 * step)
            receiver[q, i], receiver[3 + q, i], receiver[9 + q, i] = now[8 + q], 0.0, now[8 + q]
            receiver[6 + q, i] = (ahead[8 + q] - behind[8 + q]) / (2 * step)


@numba.njit(inline="always", error_model="numpy")
def _sample_terms(k, width, states, measured, noise, variances, period, robust, value, receiver, white, error):
    """R_eff's whitener (``white`` rows w00, w10, w11), the whitened residual and its IRLS weight (``error`` rows
    e0, e1, v0, v1) and its loss (row 4) at sample k, as :func:`_window_terms` and the soft-L1 loss give them. A pass
    over the lanes per stage, the modes' tests between them (see the module's note)."""
    position_variance, velocity_variance = variances[0], variances[1]
    dim = states.shape[0]
    n00, n01, n11 = noise[0, 0], noise[1, 0], noise[1, 1]
    z0, z1 = measured[k, 0], measured[k, 1]
    for i in range(width):
        r00, r01, r11 = n00, n01, n11
        for j in range(6):
            variance = position_variance if j < 3 else velocity_variance
            rd, rrd = receiver[j, i], receiver[6 + j, i]
            r00 += variance * rd * rd
            r01 += variance * rd * rrd
            r11 += variance * rrd * rrd
        w00, w10, w11 = _whitener(r00, r01, r11)
        rd_error = z0 - (value[0, i] + states[dim - 2, i])
        rrd_error = z1 - (value[1, i] + states[dim - 1, i])
        white[0, i], white[1, i], white[2, i] = w00, w10, w11
        error[0, i], error[1, i] = rd_error, rrd_error
    if period > 0.0:
        for i in range(width):
            error[0, i] = _wrapped(error[0, i], period)
    for i in range(width):
        rd_error, rrd_error = error[0, i], error[1, i]
        e0, e1 = white[0, i] * rd_error, white[1, i] * rd_error + white[2, i] * rrd_error
        error[0, i], error[1, i] = e0, e1
    if robust:
        for i in range(width):
            e0, e1 = error[0, i], error[1, i]
            root0, root1 = math.sqrt(1 + e0 * e0), math.sqrt(1 + e1 * e1)
            error[2, i], error[3, i] = 1 / root0, 1 / root1
            error[4, i] = 2 * (root0 - 1) + 2 * (root1 - 1)
    else:
        for i in range(width):
            e0, e1 = error[0, i], error[1, i]
            error[2, i], error[3, i] = 1.0, 1.0
            error[4, i] = e0 * e0 + e1 * e1


@_compile
def _block_terms(states, start, width, motion, points, fold, data, scratch, loss, information, gradient):
    """:func:`fit_terms`' sums for one block: the loss (B,), J^T V J (n, n, B; its upper triangle) and J^T V W r
    (n, B) of the block's ``width`` states (n, B), the starts ``start`` onwards of ``points`` and ``motion``.
    ``data`` and ``scratch`` are tuples of the pass's constants and work arrays (see :func:`_fit_terms`)."""
    receivers, fixed, offsets, channel, measured, noise, variances, period, robust, wavelength, kind = data
    lanes, rows_at_offsets, unwrapped, slips, value, local, receiver, white, error, rows = scratch
    moving = motion.shape[2]
    dim = moving + 2
    shared = points.shape[0] == 0  # one free motion for every start, not each start's own trajectory
    information[:] = 0.0
    gradient[:] = 0.0
    loss[:] = 0.0
    for k in range(measured.shape[0]):
        _lane_states(states, motion, points, k, start, width, fold, lanes)
        if kind == DIRECT_PATH:
            _direct_at_sample(lanes, k, width, receivers, fixed, value, local, receiver)
        elif kind == INSTANT_PHASOR:
            _phasor_at_sample(lanes, k, width, receivers, fixed, channel, value, local, receiver)
        else:
            _frame_at_sample(lanes, k, width, receivers, fixed, offsets, channel, rows_at_offsets)
            _frame_mean_slope(width, offsets, wavelength, rows_at_offsets, unwrapped, slips, value, local, receiver)
        _sample_terms(k, width, states, measured, noise, variances, period, robust, value, receiver, white, error)
        for j in range(moving):
            if shared:
                m0, m1, m2 = motion[k, 0, j, 0], motion[k, 1, j, 0], motion[k, 2, j, 0]
                m3, m4, m5 = motion[k, 3, j, 0], motion[k, 4, j, 0], motion[k, 5, j, 0]
                for i in range(width):
                    _chain(local, lanes[6, i], white, rows, i, j, m0, m1, m2, m3, m4, m5)
            else:
                for i in range(width):
                    c = start + i
                    _chain(
                        local, 1.0, white, rows, i, j, motion[k, 0, j, c], motion[k, 1, j, c],
                        motion[k, 2, j, c], motion[k, 3, j, c], motion[k, 4, j, c], motion[k, 5, j, c],
                    )  # fmt: skip
        for i in range(width):  # the biases' unit columns, whitened
            rows[0, dim - 2, i], rows[1, dim - 2, i] = white[0, i], white[1, i]
            rows[0, dim - 1, i], rows[1, dim - 1, i] = 0.0, white[2, i]
        for a in range(dim):
            for i in range(width):
                weighted0, weighted1 = error[2, i] * rows[0, a, i], error[3, i] * rows[1, a, i]
                gradient[a, i] += weighted0 * error[0, i] + weighted1 * error[1, i]
            for b in range(a, dim):
                for i in range(width):
                    weighted0, weighted1 = error[2, i] * rows[0, a, i], error[3, i] * rows[1, a, i]
                    information[a, b, i] += weighted0 * rows[0, b, i] + weighted1 * rows[1, b, i]
        for i in range(width):
            loss[i] += error[4, i]


@numba.njit(inline="always", error_model="numpy")
def _store_symmetric(upper, i, out, c):
    """``out[c]`` (n, n) = the symmetric matrix whose upper triangle is lane i's, ``upper[:, :, i]``."""
    dim = out.shape[1]
    for a in range(dim):
        for b in range(a, dim):
            out[c, a, b] = out[c, b, a] = upper[a, b, i]


@numba.njit(inline="always", error_model="numpy")
def _scratch(frame, dim, block):
    """The work arrays of :func:`_block_terms` for ``frame`` offsets, states of size ``dim`` and ``block`` lanes."""
    return (
        np.empty((7, block)), np.empty((frame, 7, block)), np.empty((frame, block)), np.empty(block),
        np.empty((2, block)), np.empty((12, block)), np.empty((12, block)), np.empty((3, block)),
        np.empty((5, block)), np.empty((2, dim, block)),
    )  # fmt: skip


@_compile
def _fit_terms(states, motion, points, fold, data, loss, normal, pull):
    """See :func:`fit_terms`: ``states`` (n, C), ``data`` the constants of :func:`_block_terms`. Loops over blocks of
    starts, then samples; each stage's innermost loop runs over the block's starts, so that it vectorises, and each
    start sums its samples in order, whatever the vector width."""
    dim, count = states.shape
    block = FIT_BLOCK
    scratch = _scratch(data[2].shape[0], dim, block)
    cost, information, gradient = np.empty(block), np.empty((dim, dim, block)), np.empty((dim, block))
    for start in range(0, count, block):
        width = min(block, count - start)
        lanes = np.ascontiguousarray(states[:, start : start + block])
        _block_terms(lanes, start, width, motion, points, fold, data, scratch, cost, information, gradient)
        for i in range(width):
            c = start + i
            loss[c] = cost[i]
            for a in range(dim):
                pull[c, a] = gradient[a, i]
            _store_symmetric(information, i, normal, c)


def _padded(count: int) -> np.ndarray:
    """Indices of ``count`` starts padded to a multiple of ``LANES`` with copies of the last. The loops run over the
    starts LANES at a time; a remainder runs one start at a time, several times slower a start, so the pass takes
    copies instead and drops their terms. Fewer than LANES starts run alone: one start's scalar loop costs less than
    a vector's worth of copies. (Padding changes no start's result: each start sums its own samples in order.)"""
    if count < LANES:
        return np.arange(count)
    return np.minimum(np.arange(-(-count // LANES) * LANES), count - 1)


def _fold_slab(bounds: tuple[float, float] | None) -> np.ndarray:
    """[z_min, span] (m) of a fold's slab for the compiled pass; a span of 0 for no fold."""
    return np.array([0.0, 0.0] if bounds is None else [bounds[0], bounds[1] - bounds[0]], dtype=float)


def _model_kind(offsets, propagation) -> int:
    """The pass's measurement model: the direct path (``propagation`` None), the geometric worlds' instantaneous
    phasor model (``offsets`` None) or the frame-averaged one."""
    if propagation is None:
        return DIRECT_PATH
    return INSTANT_PHASOR if offsets is None else FRAME_PHASOR


def _constants(receivers, fixed, offsets, propagation, measured, noise, navigation_sd, period, robust) -> tuple:
    """What :func:`_block_terms` reads besides the states, as its arrays and numbers; ``propagation`` None for the
    direct path, ``offsets`` None for the instantaneous phasor model (no frame: ``offsets`` are not read)."""
    kind = _model_kind(offsets, propagation)
    direct = kind == DIRECT_PATH
    channel = np.zeros(4) if direct else np.array(propagation.channel, dtype=float)
    return (
        np.ascontiguousarray(np.concatenate(receivers, axis=1).T, dtype=float),  # (6, K)
        _fixed_point(fixed),
        np.zeros(0) if kind != FRAME_PHASOR else np.asarray(offsets, dtype=float),
        channel,
        np.ascontiguousarray(measured, dtype=float),
        np.asarray(noise, dtype=float),
        np.square(np.asarray(navigation_sd, dtype=float)),
        0.0 if period is None else float(period),
        bool(robust),
        2 * np.pi / propagation.wavenumber if kind == FRAME_PHASOR else 0.0,  # the frame's unwrapping period
        kind,
    )


def fit_terms(
    states: np.ndarray,
    motion: np.ndarray,
    trajectory: np.ndarray | None,
    fold: tuple[float, float] | None,
    receivers: tuple[np.ndarray, np.ndarray],
    fixed: np.ndarray,
    offsets: np.ndarray,
    propagation,
    measured: np.ndarray,
    noise: np.ndarray,
    navigation_sd: tuple[float, float],
    period: float | None,
    robust: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A window fit's Gauss-Newton terms under the direct path or a phasor model (frame-averaged, or a geometric world's
    instantaneous one), in one compiled pass per start: the loss sum_k rho(|W_k r_k|^2) (C,), the normal matrix
    J^T V J (C, n, n) and J^T V W r (C, n), with r_k = z_k - h(x(t_k)) - b, W_k R_eff's whitener along the start's own
    trajectory, J the whitened prediction's Jacobian and V the IRLS weights of soft-L1 (``robust``) or ones. The same
    as :func:`frame_phasor` (or :func:`phasor_linearized`, or the direct path's NumPy forms), :func:`window_terms` and
    :func:`whitened_chain` followed by NumPy's sums, to rounding (``tests/test_window.py``).

    ``states`` (C, n) in the filter's layout at the window's last sample, [b_p, b_v] last. Either ``motion`` is one
    free motion for every state, d[p, v](t_k)/d x (K, 6, n - 2)
    (:meth:`aasl_gym.filters.MotionModel.free_motion_matrix`), ``trajectory`` None, and the pass runs each state
    along it, folded into ``fold`` (z_min, z_max; m) unless None; or ``motion`` is each state's own (C, K, 6, n - 2)
    and ``trajectory`` (C, K, 6+) its source positions and velocities (m, m/s). ``receivers`` the mobile's positions
    and velocities (K, 3 each), ``fixed`` (3,), the frame's ``offsets`` (s) and ``propagation`` (a
    :class:`aasl_gym.measurement_models.Propagation`; both None for the direct path, ``offsets`` None for the
    instantaneous phasor model), ``measured`` (K, 2), ``noise``
    R_ac (2, 2), ``navigation_sd`` (m, m/s), the RD residual taken modulo ``period`` (m) unless None."""
    count, dim = states.shape
    take = _padded(count)
    padded = len(take)
    if trajectory is None:
        motion, points = np.ascontiguousarray(motion[..., None]), np.empty((0, 0, 0))
    else:
        motion = np.ascontiguousarray(motion[take].transpose(1, 2, 3, 0))
        points = np.ascontiguousarray(trajectory[take, :, 0:6].transpose(2, 1, 0))  # (6, K, C): the starts innermost
    loss, normal, pull = np.empty(padded), np.empty((padded, dim, dim)), np.empty((padded, dim))
    constants = _constants(receivers, fixed, offsets, propagation, measured, noise, navigation_sd, period, robust)
    _fit_terms(
        np.ascontiguousarray(states[take].T, dtype=float),
        motion,
        points,
        _fold_slab(fold),
        constants,
        loss,
        normal,
        pull,
    )
    return loss[:count], normal[:count], pull[:count]


@numba.njit(inline="always", error_model="numpy")
def _lane_solves(matrix, right, width, pivot, work, out):
    """``out`` (n, B) = matrix^-1 right for each of ``width`` lanes' systems ``matrix`` (n, n, B) and ``right`` (n, B),
    in place: Gaussian elimination with partial pivoting, every lane at once (the row swaps as selects), so that the
    loops run over the lanes and vectorise; ``pivot`` (B,) and ``work`` (2, B) are scratch. Each lane takes the
    operations one system solved alone takes, in their order (``tests/test_kernels.py``)."""
    dim = right.shape[0]
    best, factor = work[0], work[1]
    for a in range(dim):
        for i in range(width):
            pivot[i], best[i] = a, abs(matrix[a, a, i])
        for r in range(a + 1, dim):
            for i in range(width):
                magnitude = abs(matrix[r, a, i])
                if magnitude > best[i]:
                    pivot[i], best[i] = r, magnitude
        for r in range(a + 1, dim):
            for b in range(dim):
                for i in range(width):
                    upper, lower, swap = matrix[a, b, i], matrix[r, b, i], pivot[i] == r
                    matrix[a, b, i], matrix[r, b, i] = (lower, upper) if swap else (upper, lower)
            for i in range(width):
                upper, lower, swap = right[a, i], right[r, i], pivot[i] == r
                right[a, i], right[r, i] = (lower, upper) if swap else (upper, lower)
        for r in range(a + 1, dim):
            for i in range(width):
                factor[i] = matrix[r, a, i] / matrix[a, a, i]
            for b in range(a, dim):
                for i in range(width):
                    matrix[r, b, i] -= factor[i] * matrix[a, b, i]
            for i in range(width):
                right[r, i] -= factor[i] * right[a, i]
    total = work[0]
    for a in range(dim - 1, -1, -1):
        for i in range(width):
            total[i] = right[a, i]
        for b in range(a + 1, dim):
            for i in range(width):
                total[i] -= matrix[a, b, i] * out[b, i]
        for i in range(width):
            out[a, i] = total[i] / matrix[a, a, i]


@_compile
def _damped_steps(normal, damping, gradient, steps):
    """``steps`` (C, n) = -(N + lambda diag(N))^-1 g for each start's normal matrix N (C, n, n), damping lambda (C,)
    and gradient g (C, n): every start's system a lane of :func:`_lane_solves`."""
    count, dim = gradient.shape
    matrix, right, out = np.empty((dim, dim, count)), np.empty((dim, count)), np.empty((dim, count))
    for c in range(count):
        for a in range(dim):
            for b in range(dim):
                matrix[a, b, c] = normal[c, a, b]
            matrix[a, a, c] += damping[c] * normal[c, a, a]
            right[a, c] = -gradient[c, a]
    _lane_solves(matrix, right, count, np.empty(count, dtype=np.int64), np.empty((2, count)), out)
    for c in range(count):
        for a in range(dim):
            steps[c, a] = out[a, c]


def damped_steps(normal: np.ndarray, damping: np.ndarray, gradient: np.ndarray) -> np.ndarray:
    """Levenberg-Marquardt's steps (C, n) with Marquardt's scaling: -(N + lambda diag(N))^-1 g for normal matrices
    N (C, n, n), dampings lambda (C,) and gradients g (C, n); the same as ``np.linalg.solve`` to rounding, without
    its per-call overhead on a few hundred 8 x 8 systems."""
    steps = np.empty(gradient.shape)
    _damped_steps(
        np.ascontiguousarray(normal, dtype=float),
        np.asarray(damping, float),
        np.ascontiguousarray(gradient, dtype=float),
        steps,
    )
    return steps


@_compile
def _fit(states, prior_mean, prior_sd, motion, fold, data, iterations, max_position_step, costs, information):
    """See :func:`fit`: ``states`` (n, C) are fitted in place, block by block, each block's Levenberg-Marquardt
    iterations run through in cache. The same steps as :func:`aasl_gym.window.fit_window`'s loop."""
    dim, count = states.shape
    block = FIT_BLOCK
    scratch = _scratch(data[2].shape[0], dim, block)
    no_points = np.empty((0, 0, 0))  # the pass runs the trajectories itself (see _lane_states)
    loss, normal, pull = np.empty(block), np.empty((dim, dim, block)), np.empty((dim, block))
    trial_loss, trial_normal, trial_pull = np.empty(block), np.empty((dim, dim, block)), np.empty((dim, block))
    prior, trial_prior, cost, damping = np.empty((dim, block)), np.empty((dim, block)), np.empty(block), np.empty(block)
    matrix, right, step = np.empty((dim, dim, block)), np.empty((dim, block)), np.empty((dim, block))
    pivot, work = np.empty(block, dtype=np.int64), np.empty((2, block))
    prior_information = 1 / prior_sd**2
    for start in range(0, count, block):
        width = min(block, count - start)
        x = np.ascontiguousarray(states[:, start : start + block])
        trial = np.empty_like(x)
        _block_terms(x, start, width, motion, no_points, fold, data, scratch, loss, normal, pull)
        for i in range(width):
            cost[i], damping[i] = loss[i], 1e-3
            for a in range(dim):
                prior[a, i] = (x[a, i] - prior_mean[a, start + i]) / prior_sd[a]
            for a in range(dim):
                cost[i] += prior[a, i] ** 2
        for _ in range(iterations):
            for a in range(dim):
                for b in range(a, dim):
                    for i in range(width):
                        matrix[a, b, i] = matrix[b, a, i] = normal[a, b, i]
                for i in range(width):
                    matrix[a, a, i] += prior_information[a]
                    matrix[a, a, i] += damping[i] * matrix[a, a, i]
                    # The residuals fall as the predictions rise: the gradient carries -J.
                    right[a, i] = -(prior[a, i] / prior_sd[a] - pull[a, i])
            _lane_solves(matrix, right, width, pivot, work, step)
            for i in range(width):
                length = math.sqrt(step[0, i] * step[0, i] + step[1, i] * step[1, i] + step[2, i] * step[2, i])
                shrink = min(1.0, max_position_step / max(length, 1e-12))
                for a in range(dim):
                    trial[a, i] = x[a, i] + step[a, i] * shrink
            _block_terms(
                trial, start, width, motion, no_points, fold, data, scratch, trial_loss, trial_normal, trial_pull
            )
            for i in range(width):
                trial_cost = trial_loss[i]
                for a in range(dim):
                    trial_prior[a, i] = (trial[a, i] - prior_mean[a, start + i]) / prior_sd[a]
                for a in range(dim):
                    trial_cost += trial_prior[a, i] ** 2
                if trial_cost < cost[i]:
                    cost[i], damping[i] = trial_cost, damping[i] / 3
                    for a in range(dim):
                        x[a, i], prior[a, i], pull[a, i] = trial[a, i], trial_prior[a, i], trial_pull[a, i]
                        for b in range(a, dim):
                            normal[a, b, i] = trial_normal[a, b, i]
                else:
                    damping[i] *= 4
        for i in range(width):
            c = start + i
            costs[c] = cost[i]
            _store_symmetric(normal, i, information, c)
            for a in range(dim):
                states[a, c] = x[a, i]
                information[c, a, a] += prior_information[a]


def fit(
    states: np.ndarray,
    prior_mean: np.ndarray,
    prior_sd: np.ndarray,
    motion: np.ndarray,
    fold: tuple[float, float] | None,
    burst_data: tuple,
    iterations: int,
    max_position_step: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Levenberg-Marquardt window fits under the direct path or a phasor model (:func:`fit_terms`), compiled whole, for
    a motion model whose free motion is one matrix ``motion`` (K, 6, n - 2) for every state (folded into ``fold``
    unless None): from ``states`` (C, n), with the prior ``prior_mean`` (C, n) and ``prior_sd`` (n,), the fitted
    states (C, n), their costs (C,) and information (C, n, n). ``burst_data`` are :func:`fit_terms`' arguments from
    ``receivers`` to ``robust``. See :func:`aasl_gym.window.fit_window`, whose loop over :func:`fit_terms` this is."""
    count, dim = states.shape
    take = _padded(count)
    padded = len(take)
    fitted = np.ascontiguousarray(states[take].T, dtype=float)
    costs, information = np.empty(padded), np.empty((padded, dim, dim))
    _fit(
        fitted, np.ascontiguousarray(prior_mean[take].T, dtype=float), np.asarray(prior_sd, dtype=float),
        np.ascontiguousarray(motion[..., None], dtype=float), _fold_slab(fold), _constants(*burst_data),
        int(iterations), float(max_position_step), costs, information,
    )  # fmt: skip
    return fitted.T[:count].copy(), costs[:count], information[:count]


# Candidates per block of LC-MAP's grid pass: each stage's loop runs over a block's candidates, so that it vectorises.
GRID_BLOCK = 64


@numba.njit(inline="always", error_model="numpy")
def _grid_sample(start, width, k, positions, velocity, biases, tau, motion, receivers, fixed, measured, white, period,
                 robust, scratch, out, loss):  # fmt: skip
    """LC-MAP's grid at sample k for the block's ``width`` candidates from ``start`` (their ``positions`` (C, 3) and
    ``velocity`` (3, B) at the first sample), moving as ``motion`` (4, C or 1, K: s, c, cos, sin of
    :class:`aasl_gym.initializers.CandidateMotion`) says: the whitened residual times the robust root weights
    (``out[0, 0:2]``, (3, 6, B)), those weights (``out[0, 2:4]``; ones unless ``robust``), the whitened Jacobian in
    [p, v] at the first sample (``out[1:3, 0:6]``, without the weights) and the sample's loss (soft-L1's or the
    square) into ``loss`` (B,). ``scratch`` (12, B) holds the direct path's residuals and gradients (rows 0:8) and
    the candidates' motion at the sample (8:12) between the stages."""
    moving = scratch[8:12]  # the candidates' s, c, cos and sin at sample k
    for q in range(4):
        if motion.shape[1] == 1:
            for i in range(width):
                moving[q, i] = motion[q, 0, k]
        else:
            for i in range(width):
                moving[q, i] = motion[q, start + i, k]
    for i in range(width):
        c = start + i
        s, cc, cos, sin = moving[0, i], moving[1, i], moving[2, i], moving[3, i]
        vx, vy, vz = velocity[0, i], velocity[1, i], velocity[2, i]
        rd, rrd, gx, gy, gz, qx, qy, qz, _, _, _, _, _, _ = _direct(
            positions[c, 0] + (s * vx - cc * vy), positions[c, 1] + (cc * vx + s * vy), positions[c, 2] + vz * tau[k],
            cos * vx - sin * vy, sin * vx + cos * vy, vz,
            receivers[0, k], receivers[1, k], receivers[2, k], receivers[3, k], receivers[4, k], receivers[5, k],
            fixed[0], fixed[1], fixed[2],
        )  # fmt: skip
        scratch[0, i], scratch[1, i] = measured[k, 0] - rd - biases[c], measured[k, 1] - rrd
        scratch[2, i], scratch[3, i], scratch[4, i] = gx, gy, gz
        scratch[5, i], scratch[6, i], scratch[7, i] = qx, qy, qz
    if period > 0.0:
        for i in range(width):
            scratch[0, i] = _wrapped(scratch[0, i], period)
    for i in range(width):
        rd_error, rrd_error = scratch[0, i], scratch[1, i]
        out[0, 0, i] = white[0, 0] * rd_error + white[0, 1] * rrd_error
        out[0, 1, i] = white[1, 0] * rd_error + white[1, 1] * rrd_error
    if robust:
        for i in range(width):
            e0, e1 = out[0, 0, i], out[0, 1, i]
            loss[i] = 2 * (math.sqrt(1 + e0 * e0) - 1) + 2 * (math.sqrt(1 + e1 * e1) - 1)
            root0, root1 = (1 + e0 * e0) ** -0.25, (1 + e1 * e1) ** -0.25
            out[0, 0, i], out[0, 1, i], out[0, 2, i], out[0, 3, i] = root0 * e0, root1 * e1, root0, root1
    else:
        for i in range(width):
            e0, e1 = out[0, 0, i], out[0, 1, i]
            loss[i] = e0 * e0 + e1 * e1
            out[0, 2, i], out[0, 3, i] = 1.0, 1.0
    # Each whitened row of [RD, RRD] in [p(t), v(t)] - RD's (g, 0), RRD's (q, g) - chained to [p, v] at the first
    # sample.
    for row in range(2):
        w0, w1 = white[row, 0], white[row, 1]
        for i in range(width):
            s, cc, cos, sin = moving[0, i], moving[1, i], moving[2, i], moving[3, i]
            gx, gy, gz = scratch[2, i], scratch[3, i], scratch[4, i]
            qx, qy, qz = scratch[5, i], scratch[6, i], scratch[7, i]
            p0, p1, p2 = w0 * gx + w1 * qx, w0 * gy + w1 * qy, w0 * gz + w1 * qz
            u0, u1, u2 = w1 * gx, w1 * gy, w1 * gz
            out[1 + row, 0, i], out[1 + row, 1, i], out[1 + row, 2, i] = p0, p1, p2
            out[1 + row, 3, i] = p0 * s + p1 * cc + u0 * cos + u1 * sin
            out[1 + row, 4, i] = -p0 * cc + p1 * s - u0 * sin + u1 * cos
            out[1 + row, 5, i] = p2 * tau[k] + u2


@numba.njit(inline="always", error_model="numpy")
def _grid_velocity(start, width, positions, biases, tau, motion, receivers, fixed, measured, white, period, robust,
                   precision, iterations, velocity, work, last_jacobians):  # fmt: skip
    """The block's candidates' MAP velocities from rest (``velocity`` (3, B), in place) by ``iterations``
    Gauss-Newton steps with the velocity prior's ``precision``; the last linearization's whitened Jacobians stay in
    ``last_jacobians`` (K, 2, 6, B). ``work`` holds :func:`_lcmap_grid`'s scratch arrays."""
    scratch, terms, loss, normal, right, step, pivot, solve_work = work
    velocity[:] = 0.0
    for _ in range(iterations):
        normal[:] = 0.0
        right[:] = 0.0
        for k in range(tau.shape[0]):
            _grid_sample(start, width, k, positions, velocity, biases, tau, motion, receivers, fixed, measured,
                         white, period, robust, scratch, terms, loss)  # fmt: skip
            for row in range(2):
                for a in range(3):
                    for i in range(width):
                        right[a, i] += terms[0, 2 + row, i] * terms[1 + row, 3 + a, i] * terms[0, row, i]
                    for b in range(a, 3):
                        for i in range(width):
                            root = terms[0, 2 + row, i]
                            normal[a, b, i] += (root * terms[1 + row, 3 + a, i]) * (root * terms[1 + row, 3 + b, i])
            for row in range(2):
                for a in range(6):
                    for i in range(width):
                        last_jacobians[k, row, a, i] = terms[1 + row, a, i]
        for a in range(3):
            for b in range(a):
                for i in range(width):
                    normal[a, b, i] = normal[b, a, i]
            for i in range(width):
                normal[a, a, i] += precision
                right[a, i] -= velocity[a, i] * precision
        _lane_solves(normal, right, width, pivot, solve_work, step)
        for a in range(3):
            for i in range(width):
                velocity[a, i] += step[a, i]


@numba.njit(inline="always", error_model="numpy")
def _grid_score(start, width, positions, biases, tau, motion, receivers, fixed, measured, white, period, robust,
                velocity, work, last_jacobians, cost, information):  # fmt: skip
    """The block's candidates' loss at their solved ``velocity`` (into ``cost`` (B,)) and the information of the last
    linearization (one small Gauss-Newton step away) weighed with the root weights at the solved velocity, as the
    NumPy score does, into ``information`` (6, 6, B), without its prior."""
    scratch, terms, loss = work[0], work[1], work[2]
    cost[:] = 0.0
    information[:] = 0.0
    for k in range(tau.shape[0]):
        _grid_sample(start, width, k, positions, velocity, biases, tau, motion, receivers, fixed, measured,
                     white, period, robust, scratch, terms, loss)  # fmt: skip
        for i in range(width):
            cost[i] += loss[i]
        for row in range(2):
            for a in range(6):
                for b in range(a, 6):  # the lower triangle is the same products (x y = y x exactly)
                    for i in range(width):
                        root = terms[0, 2 + row, i]
                        information[a, b, i] += (root * last_jacobians[k, row, a, i]) * (
                            root * last_jacobians[k, row, b, i]
                        )
    for a in range(6):
        for b in range(a):
            for i in range(width):
                information[a, b, i] = information[b, a, i]


@_compile
def _lcmap_grid(positions, biases, tau, motion, receivers, fixed, measured, white, period, robust, precisions,
                iterations, velocities, costs, information):  # fmt: skip
    """See :func:`lcmap_grid`: the candidates in blocks of ``GRID_BLOCK``, each stage over a block's candidates."""
    position_precision, velocity_precision = precisions[0], precisions[1]
    block = GRID_BLOCK
    work = (
        np.empty((12, block)), np.empty((3, 6, block)), np.empty(block), np.empty((3, 3, block)), np.empty((3, block)),
        np.empty((3, block)), np.empty(block, dtype=np.int64), np.empty((2, block)),
    )  # fmt: skip
    velocity, cost = np.empty((3, block)), np.empty(block)
    last_jacobians, lane_information = np.empty((tau.shape[0], 2, 6, block)), np.empty((6, 6, block))
    for start in range(0, positions.shape[0], block):
        width = min(block, positions.shape[0] - start)
        _grid_velocity(start, width, positions, biases, tau, motion, receivers, fixed, measured, white, period, robust,
                       velocity_precision, iterations, velocity, work, last_jacobians)  # fmt: skip
        _grid_score(start, width, positions, biases, tau, motion, receivers, fixed, measured, white, period, robust,
                    velocity, work, last_jacobians, cost, lane_information)  # fmt: skip
        for i in range(width):
            c = start + i
            for a in range(3):
                velocities[c, a] = velocity[a, i]
            costs[c] = cost[i] + velocity_precision * (velocity[0, i] ** 2 + velocity[1, i] ** 2 + velocity[2, i] ** 2)
            for a in range(6):
                for b in range(6):
                    information[c, a, b] = lane_information[a, b, i]
                information[c, a, a] += position_precision if a < 3 else velocity_precision


def lcmap_grid(
    positions: np.ndarray,
    biases: np.ndarray,
    tau: np.ndarray,
    motion: np.ndarray,
    receivers: tuple[np.ndarray, np.ndarray],
    fixed: np.ndarray,
    measured: np.ndarray,
    white: np.ndarray,
    period: float | None,
    robust: bool,
    position_sd: float,
    velocity_sd: float,
    iterations: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """LC-MAP's grid on the direct path, compiled: for each candidate position (C, 3; m) on the locus at a burst's
    first sample, with its whole-period RD bias (C,; m), the MAP velocity from rest by ``iterations`` Gauss-Newton
    steps (C, 3; m/s; prior sd ``velocity_sd``), the burst's loss there plus the velocity prior (C,) and the information
    of the last linearization in [p, v] (C, 6, 6; prior sd ``position_sd``, ``velocity_sd``). ``tau`` (K,; s) are the
    samples' times since the first, ``motion`` (4, C or 1, K) the candidates' s, c, cos and sin
    (:class:`aasl_gym.initializers.CandidateMotion`), ``receivers`` the mobile's positions and velocities (K, 3 each),
    ``fixed`` (3,), ``measured`` (K, 2), ``white`` (2, 2) the burst's uniform whitener, the RD residual taken modulo
    ``period`` (m) unless None, soft-L1 where ``robust``. The same as
    :meth:`aasl_gym.initializers.LCMAPInitializer._solve_velocities` and its ``_score`` to rounding
    (``tests/test_initializers.py``)."""
    count = len(positions)
    velocities, costs, information = np.empty((count, 3)), np.empty(count), np.empty((count, 6, 6))
    _lcmap_grid(
        np.ascontiguousarray(positions, dtype=float), np.ascontiguousarray(biases, dtype=float),
        np.ascontiguousarray(tau, dtype=float), np.ascontiguousarray(motion, dtype=float),
        np.ascontiguousarray(np.concatenate(receivers, axis=1).T, dtype=float), _fixed_point(fixed),
        np.ascontiguousarray(measured, dtype=float), np.ascontiguousarray(white, dtype=float),
        0.0 if period is None else float(period), bool(robust),
        np.array([1 / position_sd**2, 1 / velocity_sd**2]), int(iterations), velocities, costs, information,
    )  # fmt: skip
    return velocities, costs, information


@_compile
def _peak_counts(rows, counts):
    """How many samples (axis 1) of each row and part of ``rows`` (R, N, P) reach that row and part's largest
    magnitude, into ``counts`` (R, P)."""
    for r in range(rows.shape[0]):
        for p in range(rows.shape[2]):
            peak = 0.0
            for i in range(rows.shape[1]):
                peak = max(peak, abs(rows[r, i, p]))
            count = 0
            for i in range(rows.shape[1]):
                count += abs(rows[r, i, p]) >= peak
            counts[r, p] = count


def peak_counts(samples: np.ndarray) -> np.ndarray:
    """How many samples of each channel (..., N) reach its largest magnitude, (..., 1); of a complex channel, its real
    and its imaginary part's apart, (..., 2). A clipped channel's count (:func:`aasl_gym.frontend.saturated`), in one
    pass without NumPy's temporaries or a copy of the parts."""
    parts = 2 if np.iscomplexobj(samples) else 1
    samples = np.ascontiguousarray(samples, dtype=complex if parts == 2 else float)
    rows = samples.view(np.float64).reshape(-1, samples.shape[-1], parts)
    counts = np.empty((rows.shape[0], parts), dtype=np.int64)
    _peak_counts(rows, counts)
    return counts.reshape(samples.shape[:-1] + (parts,))


@_compile
def _tone_estimate(mobile, fixed, times, starts, stop, carrier, period, out):
    """See :func:`tone_estimate`: ``out`` (3,) = [mean delay (s), its least-squares slope in time, mean coherence]."""
    windows = starts.shape[0]
    delays, centres = np.empty(windows), np.empty(windows)
    coherence = 0.0
    for w in range(windows):
        first, last = starts[w], starts[w + 1] if w + 1 < windows else stop
        real, imag, mobile_energy, fixed_energy, time = 0.0, 0.0, 0.0, 0.0, 0.0
        for n in range(first, last):
            m, f = mobile[n], fixed[n]
            real += f.real * m.real + f.imag * m.imag  # conj(f) m
            imag += f.real * m.imag - f.imag * m.real
            mobile_energy += m.real * m.real + m.imag * m.imag
            fixed_energy += f.real * f.real + f.imag * f.imag
            time += times[n]
        delays[w] = -math.atan2(imag, real) / (2 * math.pi * carrier)
        coherence += math.hypot(real, imag) / math.sqrt(mobile_energy * fixed_energy)
        centres[w] = time / (last - first)
    slips, delay_sum, time_sum, previous = 0.0, delays[0], centres[0], delays[0]
    for w in range(1, windows):  # each step between neighbours moved by whole periods into [-period/2, period/2]
        slips += np.rint((delays[w] - previous) / period)
        previous = delays[w]
        delays[w] -= slips * period
        delay_sum += delays[w]
        time_sum += centres[w]
    mean_delay, mean_time = delay_sum / windows, time_sum / windows
    covariance, spread = 0.0, 0.0
    for w in range(windows):
        offset = centres[w] - mean_time
        covariance += offset * delays[w]
        spread += offset * offset
    out[0], out[1], out[2] = mean_delay, covariance / spread, coherence / windows


def tone_estimate(
    mobile: np.ndarray, fixed: np.ndarray, times: np.ndarray, starts: np.ndarray, carrier: float, period: float
) -> tuple[float, float, float]:
    """A tone frame's mean delay of the mobile channel behind the fixed one (s), the delay's least-squares slope in
    time and the windows' mean coherence, from the two complex envelopes (N,) about ``carrier`` (Hz) and their sample
    ``times`` (N,; s), in windows starting at ``starts`` (W,; each at least two samples, the last to the end); each
    window's delay is its correlation's phase over 2 pi ``carrier``, unwrapped across windows by whole ``period`` (s).
    :func:`aasl_gym.frontend.delay_track` and :func:`aasl_gym.frontend.tdoa_fdoa` at lag 0, in one pass (the same to
    rounding, ``tests/test_frontend.py``) without their two dozen NumPy calls on ten windows."""
    out = np.empty(3)
    _tone_estimate(mobile, fixed, times, np.asarray(starts, dtype=np.int64), len(times), carrier, period, out)
    return out[0], out[1], out[2]


@_compile
def _peak_over_median(spectra, bins, out):
    """See :func:`peak_over_median`: ``spectra`` (R, M), ``out`` (R,)."""
    power = np.empty(len(bins))
    for r in range(spectra.shape[0]):
        for j in range(len(bins)):
            power[j] = abs(spectra[r, bins[j]]) ** 2
        out[r] = power.max() / (np.median(power) / math.log(2.0))


def peak_over_median(spectra: np.ndarray, bins: np.ndarray) -> np.ndarray:
    """Each spectrum's (..., M; complex) largest power |X_b|^2 over ``bins`` divided by the median of those powers
    over ln 2 (..., ): the tone detector's CFAR statistic (:func:`aasl_gym.frontend.detection_statistic`) in one pass,
    without NumPy's temporaries and its median's checks. The same as NumPy's ``abs``, ``max`` and ``median`` to
    rounding; only its comparison with the threshold is used, so no measurement moves."""
    rows = np.ascontiguousarray(spectra, dtype=complex).reshape(-1, spectra.shape[-1])
    out = np.empty(rows.shape[0])
    _peak_over_median(rows, np.ascontiguousarray(bins, dtype=np.int64), out)
    return out.reshape(spectra.shape[:-1])


# Reassociation lets LLVM vectorise the bins' sums; their rounding only has to stay inside the bound's margin. (Not
# the flags that assume no NaN: a NaN channel must give no bound, not a wrong one.)
@numba.njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract"})
def _peak_over_median_bound(rows, table, padded, above, out):
    """See :func:`peak_over_median_bound`: ``rows`` (R, N) complex, ``table`` (2, J, N), ``out`` (R,)."""
    count = rows.shape[1]
    real, imaginary = np.empty(count), np.empty(count)
    for r in range(rows.shape[0]):
        energy = 0.0
        for n in range(count):  # the parts apart, so that the sums below read contiguous rows
            real[n], imaginary[n] = rows[r, n].real, rows[r, n].imag
            energy += real[n] * real[n] + imaginary[n] * imaginary[n]
        peak, near = 0.0, 0.0
        for j in range(table.shape[1]):
            total_real, total_imaginary = 0.0, 0.0
            for n in range(count):
                cosine, sine = table[0, j, n], table[1, j, n]
                total_real += real[n] * cosine - imaginary[n] * sine
                total_imaginary += real[n] * sine + imaginary[n] * cosine
            power = total_real * total_real + total_imaginary * total_imaginary
            peak, near = max(peak, power), near + power
        rest = padded * energy - near
        out[r] = peak * math.log(2.0) * above / rest if rest > 0.0 else 0.0


def peak_over_median_bound(samples: np.ndarray, table: np.ndarray, padded: int, above: int) -> np.ndarray:
    """A lower bound of :func:`peak_over_median`'s statistic (..., ) for channels x (..., N; complex) zero-padded to
    ``padded`` points, from their periodogram at J bins only: X_j = sum_n x_n exp(-i theta_jn), ``table`` (2, J, N)
    holding cos and -sin of theta_jn. max_j |X_j|^2 ln 2 ``above`` / (``padded`` sum_n |x_n|^2 - sum_j |X_j|^2), zero
    where the denominator is not positive (see :func:`aasl_gym.frontend.detection_lower_bound`, whose ``above`` is
    the number of band bins sure to lie above the median and outside the J). Summed in any order: a relative error
    of a few 1e-15, inside the margin the detector leaves."""
    rows = np.ascontiguousarray(samples, dtype=complex).reshape(-1, np.shape(samples)[-1])
    out = np.empty(rows.shape[0])
    _peak_over_median_bound(rows, np.ascontiguousarray(table, dtype=float), float(padded), float(above), out)
    return out.reshape(np.shape(samples)[:-1])


@_compile
def _unscented_update(sigmas, values, x, covariance, mean_weights, cov_weights, noise, measured, period, out):
    """See :func:`unscented_update`; ``out`` (n + 1 + n n + 2 + 4,) takes the state, the NIS, the covariance, the
    innovation and the innovation covariance, in that order. Returns the innovation covariance's determinant (the
    update is skipped unless it is positive)."""
    count, dim = sigmas.shape
    z0, z1 = 0.0, 0.0
    for s in range(count):
        z0 += mean_weights[s] * values[s, 0]
        z1 += mean_weights[s] * values[s, 1]
    s00, s01, s11 = noise[0, 0], noise[0, 1], noise[1, 1]
    cross = np.zeros((dim, 2))
    for s in range(count):
        d0, d1, w = values[s, 0] - z0, values[s, 1] - z1, cov_weights[s]
        s00 += w * d0 * d0
        s01 += w * d0 * d1
        s11 += w * d1 * d1
        for a in range(dim):
            deviation = w * (sigmas[s, a] - x[a])
            cross[a, 0] += deviation * d0
            cross[a, 1] += deviation * d1
    det = s00 * s11 - s01 * s01
    y0, y1 = measured[0] - z0, measured[1] - z1
    if period > 0.0:
        y0 = _wrapped(y0, period)
    out[dim + 1 + dim * dim :] = np.array([y0, y1, s00, s01, s01, s11])
    if not det > 0.0:
        return det
    i00, i01, i11 = s11 / det, -s01 / det, s00 / det
    gain = np.empty((dim, 2))
    for a in range(dim):
        gain[a, 0] = cross[a, 0] * i00 + cross[a, 1] * i01
        gain[a, 1] = cross[a, 0] * i01 + cross[a, 1] * i11
        out[a] = x[a] + gain[a, 0] * y0 + gain[a, 1] * y1
    out[dim] = y0 * (i00 * y0 + i01 * y1) + y1 * (i01 * y0 + i11 * y1)
    # P - K S K^T = P - K C^T (K S = C), symmetrised.
    first = dim + 1
    for a in range(dim):
        for b in range(a, dim):
            value = 0.5 * (
                (covariance[a, b] - (gain[a, 0] * cross[b, 0] + gain[a, 1] * cross[b, 1]))
                + (covariance[b, a] - (gain[b, 0] * cross[a, 0] + gain[b, 1] * cross[a, 1]))
            )
            out[first + a * dim + b] = out[first + b * dim + a] = value
    return det


def unscented_update(
    sigmas: np.ndarray,
    values: np.ndarray,
    x: np.ndarray,
    covariance: np.ndarray,
    mean_weights: np.ndarray,
    cov_weights: np.ndarray,
    noise: np.ndarray,
    measured: np.ndarray,
    period: float | None,
) -> tuple[float, np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]:
    """An unscented filter's update with one [RD, RRD] measurement, compiled: from its predicted ``sigmas`` (S, n), the
    measurement model's ``values`` there (S, 2), the predicted mean ``x`` and ``covariance``, the weights, R
    (``noise``, 2 x 2, symmetric: its upper off-diagonal is read) and the measurement ``measured`` (2,), the RD
    innovation taken modulo ``period`` (m) unless None, as :meth:`aasl_gym.estimator.SourceTracker.residual` takes
    it: (det S, x, P, NIS, innovation, S). Where det S is not positive the state, P and NIS are NaN (no update)."""
    dim = len(x)
    out = np.full(dim + 1 + dim * dim + 6, np.nan)
    det = _unscented_update(
        np.ascontiguousarray(sigmas, dtype=float), np.ascontiguousarray(values, dtype=float), x,
        np.ascontiguousarray(covariance, dtype=float), mean_weights, cov_weights,
        np.ascontiguousarray(noise, dtype=float), np.asarray(measured, dtype=float),
        0.0 if period is None else float(period), out,
    )  # fmt: skip
    first = dim + 1 + dim * dim
    state, nis, updated = out[:dim], float(out[dim]), out[dim + 1 : first].reshape(dim, dim)
    return float(det), state, updated, nis, out[first : first + 2], out[first + 2 :].reshape(2, 2)


@numba.njit(inline="always", error_model="numpy")
def _points_of(h, means, covariances, spread, out, ok, root):
    """Gaussian h's sigma points into ``out[h]`` and whether its P was positive definite into ``ok[h]``: the Cholesky
    factor of the spread P by the Cholesky-Banachiewicz recursion (``root`` (n, n) is scratch)."""
    dim = means.shape[1]
    ok[h] = True
    for j in range(dim):
        total = spread * covariances[h, j, j]
        for k in range(j):
            total -= root[j, k] * root[j, k]
        if not total > 0.0:
            ok[h] = False
            break
        root[j, j] = math.sqrt(total)
        for i in range(j + 1, dim):
            total = spread * covariances[h, i, j]
            for k in range(j):
                total -= root[i, k] * root[j, k]
            root[i, j] = total / root[j, j]
    for a in range(dim):
        out[h, 0, a] = means[h, a]
    for i in range(dim):  # sigma point 1 + i is x plus column i of the lower factor, 1 + n + i x minus it
        for a in range(dim):
            column = root[a, i] if a >= i and ok[h] else 0.0
            out[h, 1 + i, a] = means[h, a] + column
            out[h, 1 + dim + i, a] = means[h, a] - column


@_compile
def _unscented_updates(
    sigmas, values, means, covariances, mean_weights, cov_weights, noises, measured, period, out, det
):
    """See :func:`unscented_updates`: :func:`_unscented_update` for each filter h into ``out[h]`` and ``det[h]``."""
    for h in range(sigmas.shape[0]):
        det[h] = _unscented_update(
            sigmas[h], values[h], means[h], covariances[h], mean_weights, cov_weights, noises[h], measured, period,
            out[h],
        )  # fmt: skip


def unscented_updates(
    sigmas: np.ndarray,
    values: np.ndarray,
    means: np.ndarray,
    covariances: np.ndarray,
    mean_weights: np.ndarray,
    cov_weights: np.ndarray,
    noises: np.ndarray,
    measured: np.ndarray,
    period: float | None,
) -> tuple[np.ndarray, ...]:
    """:func:`unscented_update` for a bank of H filters with one measurement in one call: their sigma points (H, S, n),
    the model's values there (H, S, 2), means (H, n), covariances (H, n, n) and R (H, 2, 2). Returns the H filters'
    det S, x, P, NIS, innovations and S, stacked, each filter's numbers as :func:`unscented_update` gives them."""
    count, dim = np.shape(means)
    out = np.full((count, dim + 1 + dim * dim + 6), np.nan)
    det = np.empty(count)
    _unscented_updates(
        np.ascontiguousarray(sigmas, dtype=float), np.ascontiguousarray(values, dtype=float),
        np.ascontiguousarray(means, dtype=float), np.ascontiguousarray(covariances, dtype=float), mean_weights,
        cov_weights, np.ascontiguousarray(noises, dtype=float), np.asarray(measured, dtype=float),
        0.0 if period is None else float(period), out, det,
    )  # fmt: skip
    first = dim + 1 + dim * dim
    return (
        det, out[:, :dim], out[:, dim + 1 : first].reshape(count, dim, dim), out[:, dim],
        out[:, first : first + 2], out[:, first + 2 :].reshape(count, 2, 2),
    )  # fmt: skip


@_compile
def _sigma_points(means, covariances, spread, out, ok):
    """See :func:`sigma_points`."""
    root = np.zeros((means.shape[1], means.shape[1]))
    for h in range(means.shape[0]):
        _points_of(h, means, covariances, spread, out, ok, root)


def sigma_points(means: np.ndarray, covariances: np.ndarray, spread: float) -> tuple[np.ndarray, np.ndarray]:
    """Merwe's sigma points of H Gaussians at once, compiled: x, x + sqrt((n + lambda) P)_i, x - sqrt((n + lambda) P)_i
    as rows (H, 2n+1, n) for means (H, n) and covariances (H, n, n) - the columns of the lower Cholesky factor, the
    rows of filterpy's upper one - and whether each covariance was positive definite (H,; where not, its points are
    meaningless). The same as :func:`aasl_gym.filters.merwe_sigma_points` to rounding."""
    count, dim = means.shape
    out, ok = np.empty((count, 2 * dim + 1, dim)), np.empty(count, dtype=np.bool_)
    _sigma_points(
        np.ascontiguousarray(means, dtype=float), np.ascontiguousarray(covariances, dtype=float), float(spread), out, ok
    )
    return out, ok


@numba.njit(inline="always", error_model="numpy")
def _moments_of(h, points, mean_weights, cov_weights, noise, means, covariances):
    """Set h's unscented mean and covariance plus ``noise`` into ``means[h]`` and ``covariances[h]``."""
    size, dim = points.shape[1], points.shape[2]
    for a in range(dim):
        total = 0.0
        for s in range(size):
            total += mean_weights[s] * points[h, s, a]
        means[h, a] = total
    for a in range(dim):
        for b in range(a, dim):
            total = 0.0
            for s in range(size):
                total += cov_weights[s] * (points[h, s, a] - means[h, a]) * (points[h, s, b] - means[h, b])
            covariances[h, a, b] = total + noise[a, b]
            covariances[h, b, a] = total + noise[b, a]


@_compile
def _sigma_moments(points, mean_weights, cov_weights, noise, means, covariances):
    """See :func:`sigma_moments`."""
    for h in range(points.shape[0]):
        _moments_of(h, points, mean_weights, cov_weights, noise, means, covariances)


@_compile
def _constant_velocity_prediction(means, covariances, spread, dt, mean_weights, cov_weights, noise, out):
    """See :func:`constant_velocity_prediction`; ``out`` holds the means, covariances, new points and their flags."""
    predicted_means, predicted_covariances, points, ok = out
    count, size, dim = points.shape
    root = np.zeros((dim, dim))
    moved, moved_ok = np.empty((1, size, dim)), np.empty(count, dtype=np.bool_)
    for h in range(count):
        _points_of(h, means, covariances, spread, points, ok, root)
        for s in range(size):
            for a in range(dim):
                moved[0, s, a] = points[h, s, a]
            for a in range(3):  # x + dt v, as ConstantVelocity moves its states
                moved[0, s, a] += dt * points[h, s, 3 + a]
        _moments_of(
            0, moved, mean_weights, cov_weights, noise, predicted_means[h : h + 1], predicted_covariances[h : h + 1]
        )
        _points_of(h, predicted_means, predicted_covariances, spread, points, moved_ok, root)
        ok[h] = ok[h] and moved_ok[h]


def constant_velocity_prediction(
    means: np.ndarray, covariances: np.ndarray, spread: float, dt: float, mean_weights, cov_weights, noise: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """H unscented predictions of a constant-velocity state (position, velocity first) ``dt`` seconds on in one call:
    :func:`sigma_points`, the motion x + dt v, :func:`sigma_moments` with the process noise ``noise`` and the predicted
    Gaussians' :func:`sigma_points`, to the last bit. Returns the predicted means (H, n), covariances (H, n, n),
    sigma points (H, 2n+1, n) and whether both covariances were positive definite (H,)."""
    count, dim = np.shape(means)
    out = (
        np.empty((count, dim)), np.empty((count, dim, dim)), np.empty((count, 2 * dim + 1, dim)),
        np.empty(count, dtype=np.bool_),
    )  # fmt: skip
    _constant_velocity_prediction(
        np.ascontiguousarray(means, dtype=float), np.ascontiguousarray(covariances, dtype=float), float(spread),
        float(dt), mean_weights, cov_weights, np.ascontiguousarray(noise, dtype=float), out,
    )  # fmt: skip
    return out


def sigma_moments(
    points: np.ndarray, mean_weights: np.ndarray, cov_weights: np.ndarray, noise: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The unscented mean (H, n) and covariance plus ``noise`` (H, n, n) of H sets of propagated sigma points
    (H, 2n+1, n), compiled: sum_s Wm_s X_s and sum_s Wc_s (X_s - x)(X_s - x)^T + Q."""
    count, _, dim = points.shape
    means, covariances = np.empty((count, dim)), np.empty((count, dim, dim))
    _sigma_moments(
        np.ascontiguousarray(points, dtype=float), mean_weights, cov_weights,
        np.ascontiguousarray(noise, dtype=float), means, covariances,
    )  # fmt: skip
    return means, covariances


@numba.njit(inline="always", error_model="numpy")
def _information_update(covariance, dt, process_noise, jacobian, noise, measured, moved, gain):
    """One step of the Fisher information's recursion in place on ``covariance`` (8, 8): F P F^T + Q under constant
    velocity, then, if ``measured``, P - P H^T (H P H^T + R)^-1 H P; ``moved`` (8, 8) and ``gain`` (8, 2) scratch."""
    dim = covariance.shape[0]
    for i in range(dim):  # F P: the positions take dt times the velocities' rows
        for j in range(dim):
            moved[i, j] = covariance[i, j] + dt * covariance[i + 3, j] if i < 3 else covariance[i, j]
    for i in range(dim):  # (F P) F^T + Q
        for j in range(dim):
            value = moved[i, j] + dt * moved[i, j + 3] if j < 3 else moved[i, j]
            covariance[i, j] = value + process_noise[i, j]
    if not measured:
        return
    for i in range(dim):  # P H^T
        for r in range(2):
            total = 0.0
            for j in range(dim):
                total += covariance[i, j] * jacobian[r, j]
            gain[i, r] = total
    s00, s01, s10, s11 = noise[0, 0], noise[0, 1], noise[1, 0], noise[1, 1]
    for j in range(dim):
        s00 += jacobian[0, j] * gain[j, 0]
        s01 += jacobian[0, j] * gain[j, 1]
        s10 += jacobian[1, j] * gain[j, 0]
        s11 += jacobian[1, j] * gain[j, 1]
    determinant = s00 * s11 - s01 * s10
    i00, i01, i10, i11 = s11 / determinant, -s01 / determinant, -s10 / determinant, s00 / determinant
    for i in range(dim):
        a = gain[i, 0] * i00 + gain[i, 1] * i10  # (P H^T S^-1)[i]
        b = gain[i, 0] * i01 + gain[i, 1] * i11
        for j in range(dim):
            covariance[i, j] -= a * gain[j, 0] + b * gain[j, 1]


@numba.njit(inline="always", error_model="numpy")
def _position_logdet(p):
    """-log det of the position block p[:3, :3] (inf where it is not positive)."""
    determinant = (
        p[0, 0] * (p[1, 1] * p[2, 2] - p[1, 2] * p[2, 1])
        - p[0, 1] * (p[1, 0] * p[2, 2] - p[1, 2] * p[2, 0])
        + p[0, 2] * (p[1, 0] * p[2, 1] - p[1, 1] * p[2, 0])
    )
    return -math.log(determinant) if determinant > 0 else math.inf


@_compile
def _information_step(covariance, dt, process_noise, jacobian, noise, measured):
    """:func:`information_step` in place on ``covariance`` (8, 8); returns -log det of its position block."""
    dim = covariance.shape[0]
    _information_update(
        covariance, dt, process_noise, jacobian, noise, measured, np.empty((dim, dim)), np.empty((dim, 2))
    )
    for i in range(dim):
        for j in range(i + 1, dim):
            covariance[i, j] = covariance[j, i] = 0.5 * (covariance[i, j] + covariance[j, i])
    return _position_logdet(covariance)


def information_step(
    covariance: np.ndarray, dt: float, process_noise: np.ndarray, jacobian: np.ndarray | None, noise: np.ndarray
) -> tuple[np.ndarray, float]:
    """One step of the Fisher information's EKF-form recursion on [p, v, b_p, b_v] (:mod:`aasl_gym.fisher`):
    ``covariance`` (8, 8) predicted ``dt`` seconds under constant velocity with ``process_noise`` Q, updated with a
    measurement's ``jacobian`` H (2, 8) and ``noise`` R (2, 2) unless H is None (a lost frame), made symmetric;
    returns the new covariance and -log det of its position block (inf where that is not positive definite). The
    same as :func:`aasl_gym.fisher.updated_covariance` and :func:`aasl_gym.fisher.position_information_logdet`
    after F P F^T + Q, to rounding (``tests/test_fisher.py``), at a twentieth of their NumPy calls' cost a step."""
    updated = np.array(covariance, dtype=float)
    measured = jacobian is not None
    rows = np.zeros((2, 8)) if jacobian is None else np.ascontiguousarray(jacobian, dtype=float)
    logdet = _information_step(
        updated, float(dt), np.ascontiguousarray(process_noise, dtype=float), rows,
        np.ascontiguousarray(noise, dtype=float), measured,
    )  # fmt: skip
    return updated, logdet


@_compile
def _horizon_information(covariance, dt, process_noise, jacobians, noises, out):
    """:func:`horizon_information` into ``out`` (C,)."""
    dim = covariance.shape[0]
    current, moved, gain = np.empty((dim, dim)), np.empty((dim, dim)), np.empty((dim, 2))
    for c in range(jacobians.shape[0]):
        current[:, :] = covariance
        for k in range(jacobians.shape[1]):
            _information_update(current, dt, process_noise, jacobians[c, k], noises[c, k], True, moved, gain)
        out[c] = _position_logdet(current)


def horizon_information(
    covariance: np.ndarray, dt: float, process_noise: np.ndarray, jacobians: np.ndarray, noises: np.ndarray
) -> np.ndarray:
    """-log det of the position information (nats) after each of C paths of S steps from ``covariance`` (8, 8): at
    every step the prediction of :func:`information_step` and the update with that path's ``jacobians`` (C, S, 2, 8)
    and ``noises`` (C, S, 2, 2), not symmetrized between steps (the greedy planner's recursion,
    :meth:`aasl_gym.planning.GreedyPlanner.scores`); the same as its NumPy form to rounding, a tenth of its cost."""
    out = np.empty(len(jacobians))
    _horizon_information(
        np.ascontiguousarray(covariance, dtype=float), float(dt), np.ascontiguousarray(process_noise, dtype=float),
        np.ascontiguousarray(jacobians, dtype=float), np.ascontiguousarray(noises, dtype=float), out,
    )  # fmt: skip
    return out
