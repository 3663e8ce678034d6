"""Fixed-array baselines (issue 15): where a source is, from one snapshot of range differences
measured by an array of M fixed receivers - what the reference paper compares its two-receiver tracker with.

``receivers`` is an (M, 3) array (m) whose row 0 is the reference; ``range_differences[i - 1] =
|p - r_i| - |p - r_0|`` (m), i = 1 .. M - 1.

* :func:`osls`, the one-step least squares of Huang et al. (2000): with R0 = |p - r_0| and the reference
  at the origin, squaring |p - r_i| = d_i + R0 gives the linear equations 2 r_i . p + 2 d_i R0 =
  |r_i|^2 - d_i^2 in (p, R0), solved in one least-squares step (R0's tie to p is not enforced).
* :func:`sdp`, the semidefinite relaxation of Lui, So and Chan (2009): the ranges d_j = |p - r_j| join p
  in one vector y; y y^T is relaxed to a positive semidefinite matrix whose entries keep the ranges'
  squares exact and their products bounded, and the squared misfit of the measured range differences is
  minimized. It needs cvxpy (``pip install -e '.[arrays]'``, with the open-source Clarabel solver).
* :func:`crb`, the Cramer-Rao bound of an array for independent RD noise, to judge both against.

An array whose receivers lie in one plane cannot tell a source from its mirror image in that plane:
both functions raise :class:`DegenerateArray` for it.
"""

from __future__ import annotations

import numpy as np

# An array a fraction of the range across turns an RD error into a position error (range / aperture)^2 times
# larger: the solver must solve far below its default tolerances.
TIGHT = {"CLARABEL": {"tol_gap_abs": 1e-12, "tol_gap_rel": 1e-12, "tol_feas": 1e-12, "max_iter": 400}}
COPLANAR_TOLERANCE = 1e-9  # smallest / largest singular value of the receivers' offsets from the reference


class DegenerateArray(ValueError):
    """The receivers cannot localize in 3-D: too few, or all in one plane."""


def _offsets(receivers, minimum: int) -> tuple[np.ndarray, np.ndarray]:
    """The reference (3,) and the other receivers' offsets from it (M - 1, 3), validated."""
    receivers = np.asarray(receivers, dtype=float)
    if receivers.ndim != 2 or receivers.shape[1] != 3:
        raise ValueError(f"receivers must be an (M, 3) array, got shape {receivers.shape}")
    if not np.all(np.isfinite(receivers)):
        raise ValueError("receivers must be finite")
    if len(receivers) < minimum:
        raise DegenerateArray(f"needs at least {minimum} receivers, got {len(receivers)}")
    offsets = receivers[1:] - receivers[0]
    singular = np.linalg.svd(offsets, compute_uv=False)
    if singular[-1] <= COPLANAR_TOLERANCE * singular[0]:
        raise DegenerateArray(
            "the receivers lie in one plane (or on a line): a source and its mirror image in that plane give the "
            f"same range differences (singular values of the offsets {np.round(singular, 12).tolist()})"
        )
    return receivers[0], offsets


def _differences(range_differences, count: int) -> np.ndarray:
    """The M - 1 = ``count`` range differences (m), validated."""
    range_differences = np.asarray(range_differences, dtype=float)
    if range_differences.shape != (count,):
        raise ValueError(f"range_differences must have M - 1 = {count} entries, got shape {range_differences.shape}")
    if not np.all(np.isfinite(range_differences)):
        raise ValueError("range_differences must be finite")
    return range_differences


def osls(receivers, range_differences) -> np.ndarray:
    """Position (3,) (m) by the one-step least squares of Huang et al. (2000); needs M >= 5 receivers."""
    reference, offsets = _offsets(receivers, minimum=5)
    rd = _differences(range_differences, len(offsets))
    matrix = np.column_stack([2.0 * offsets, 2.0 * rd])
    target = np.einsum("ij,ij->i", offsets, offsets) - rd**2
    solution = np.linalg.lstsq(matrix, target, rcond=None)[0]
    return reference + solution[:3]


def sdp(receivers, range_differences, solver: str = "CLARABEL") -> np.ndarray:
    """Position (3,) (m) by the semidefinite relaxation of Lui, So and Chan (2009); needs M >= 4 receivers
    and cvxpy. ``solver`` is any conic solver cvxpy has that takes semidefinite cones. To solve many
    snapshots of one array, build an :class:`SdpLocator` once: the program is compiled once."""
    return SdpLocator(receivers, solver)(range_differences)


class SdpLocator:
    """The semidefinite relaxation of Lui, So and Chan (2009) for one fixed array ``receivers`` (M, 3; m,
    M >= 4), compiled once; call it with a snapshot's M - 1 range differences (m) for a position (3,). A
    solve that fails or finds nothing raises RuntimeError."""

    def __init__(self, receivers, solver: str = "CLARABEL"):
        try:
            import cvxpy as cp
        except ImportError:
            raise ImportError("sdp needs cvxpy: pip install -e '.[arrays]'") from None
        self.reference, offsets = _offsets(receivers, minimum=4)
        self.solver, self._solver_error = solver, cp.error.SolverError
        self.scale = float(np.max(np.linalg.norm(offsets, axis=1)))  # in apertures the lifted entries stay moderate
        self.range_differences = cp.Parameter(len(offsets))
        anchors = np.vstack([np.zeros(3), offsets]) / self.scale  # the reference at the origin
        self.position, self.problem = _relaxation(cp, anchors, self.range_differences)

    def __call__(self, range_differences) -> np.ndarray:
        rd = _differences(range_differences, self.range_differences.shape[0])
        self.range_differences.value = rd / self.scale
        try:
            self.problem.solve(solver=self.solver, **TIGHT.get(self.solver, {}))
        except self._solver_error as exc:  # e.g. Clarabel stalling at these tolerances
            raise RuntimeError(f"the semidefinite program failed (solver {self.solver}): {exc}") from exc
        if self.position.value is None:
            raise RuntimeError(f"the semidefinite program found no solution (solver {self.solver})")
        return self.reference + self.scale * np.asarray(self.position.value).ravel()


def _relaxation(cp, anchors: np.ndarray, rd):
    """The relaxed program for receivers at ``anchors`` (M, 3; the reference at the origin) and the range
    differences ``rd`` (a cvxpy Parameter): the position's variable and the problem."""
    count = len(anchors)
    # y = [p, d_0, delta_1 .. delta_{M-1}] with d_0 = |p - r_0| and delta_i = d_i - d_0: the misfit lives in the
    # small deltas, not in differences of the large ranges' squares, which would drown in the solver's tolerance.
    size = 4 + count - 1
    lifted = cp.Variable((size + 1, size + 1), PSD=True)  # [[Y, y], [y^T, 1]], Y relaxing y y^T
    y, gram = lifted[:size, size], lifted[:size, :size]
    position, position_gram = y[:3], gram[:3, :3]

    def range_product(i: int, j: int):
        """d_i d_j in the lifted variables (index 0: the reference; delta_0 = 0)."""
        terms = gram[3, 3]
        for k in {i, j} - {0}:
            terms = terms + gram[3, 3 + k] * (1 + (i == j))
        return terms + (gram[3 + i, 3 + j] if i and j else 0)

    def inner(i: int, j: int):
        """(p - r_i) . (p - r_j), linear in the lifted variables."""
        return cp.trace(position_gram) - (anchors[i] + anchors[j]) @ position + anchors[i] @ anchors[j]

    def delta_square(k: int, m: int):
        return gram[3 + k, 3 + m] if k and m else 0

    constraints = [lifted[size, size] == 1, y[3] >= 0, y[3] + y[4:] >= 0]
    deltas = cp.hstack([0, y[4:]])
    for i in range(count):
        constraints.append(range_product(i, i) == inner(i, i))  # d_i^2 = |p - r_i|^2, exactly
        for j in range(i + 1, count):
            constraints.append(range_product(i, j) >= cp.abs(inner(i, j)))  # d_i d_j >= |(p - r_i) . (p - r_j)|
            # |delta_i - delta_j| <= |r_i - r_j| (the triangle inequality), and so is its lifted square
            baseline = float(np.linalg.norm(anchors[i] - anchors[j]))
            gap_square = delta_square(i, i) - 2 * delta_square(i, j) + delta_square(j, j)
            constraints += [cp.abs(deltas[i] - deltas[j]) <= baseline, gap_square <= baseline**2]
    # sum (delta_i - rd_i)^2 in the lifted variables, its constant sum rd_i^2 left out
    misfit = sum(gram[3 + i, 3 + i] - 2 * rd[i - 1] * y[3 + i] for i in range(1, count))
    return position, cp.Problem(cp.Minimize(misfit), constraints)


def crb(receivers, source, sd: float) -> np.ndarray:
    """The Cramer-Rao bound (3, 3) (m^2) on an unbiased position estimate from one snapshot of the M - 1
    range differences, each with independent Gaussian noise of ``sd`` (m), for a source at ``source`` (3,)."""
    receivers = np.asarray(receivers, dtype=float)
    units = (source - receivers) / np.linalg.norm(source - receivers, axis=1)[:, None]
    jacobian = units[1:] - units[0]  # d RD_i / d p
    return np.linalg.inv(jacobian.T @ jacobian) * sd**2
