"""Episode metrics: convergence time, success at error thresholds, RMSE (SPEC section 6).

Errors are position errors in metres, NaN while no estimate exists (before initialization).
"""

from __future__ import annotations

import numpy as np

SUCCESS_THRESHOLDS = (0.1, 0.2, 0.5, 1.0, 2.0, 3.0)  # m


def convergence_time(times: np.ndarray, errors: np.ndarray, threshold: float = 1.0) -> float:
    """First time (s) after which the error stays below ``threshold`` to the end; NaN if never."""
    below = np.asarray(errors) < threshold  # NaN compares False: no estimate is not converged
    if below.size == 0 or not below[-1]:
        return float("nan")
    above = np.flatnonzero(~below)
    return float(times[0] if above.size == 0 else times[above[-1] + 1])


def success(times: np.ndarray, errors: np.ndarray, thresholds=SUCCESS_THRESHOLDS) -> dict[str, bool]:
    """Map threshold (as a string, "1.0") to whether the error converged below it within the episode."""
    return {str(float(t)): bool(np.isfinite(convergence_time(times, errors, t))) for t in thresholds}


def rmse(errors: np.ndarray) -> float:
    """Root-mean-square position error (m) over the steps that have an estimate; NaN if none."""
    finite = np.asarray(errors)[np.isfinite(errors)]
    return float(np.sqrt(np.mean(finite**2))) if finite.size else float("nan")


def time_to_first_estimate(times: np.ndarray, errors: np.ndarray) -> float:
    finite = np.flatnonzero(np.isfinite(errors))
    return float(times[finite[0]]) if finite.size else float("nan")
