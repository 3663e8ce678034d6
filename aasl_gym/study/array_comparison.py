"""The reference paper's comparison with fixed arrays (issue 15): per pod, a 6-receiver array located by
one-step least squares (:func:`aasl_gym.arrays.osls`) and an 8-receiver one by the semidefinite
relaxation (:func:`aasl_gym.arrays.sdp`), against the two-receiver tracker, on the same sources.

A trial is one episode of the tracker (the helix patrol, LC-MAP, the filter matched to the motion; the
study's scenario). The arrays, centred on the pod's hydrophone with every receiver within half a
wavelength of every other (the paper's apertures), take one snapshot of range differences per step of
the same source track, each with the tracker's RD noise sd, independently: each snapshot gives one
position, with no memory. RMSE is over the steps from the tracker's first estimate (the initializer's
burst) to the end, for all three. Update time: the wall time of one snapshot's solve (the SDP's program
compiled once per array beforehand) and of one ``tracker.step`` (every start and re-seed included).
A sweep over the arrays' RD noise (every :data:`SWEEP_STRIDE`-th snapshot) says what noise they need.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from aasl_gym import arrays, metrics
from aasl_gym.study.log import Row
from aasl_gym.study.stats import mean_sd

ARRAY_RECEIVERS = {"osls": 6, "sdp": 8}  # the paper's receivers per pod for each baseline
NOISE_LEVELS = (0.05, 0.01, 0.005, 0.001, 0.0005, 0.0002, 0.0001, 0.00005)  # m, the arrays' RD noise sd in the sweep
SWEEP_STRIDE = 10  # the sweep uses every this-many-th snapshot
APERTURE_WAVELENGTHS = 0.5  # the largest distance between two receivers of an array, in wavelengths


def octahedron(centre: np.ndarray, aperture: float) -> np.ndarray:
    """The 6 vertices (m) of a regular octahedron about ``centre`` (3,) whose opposite vertices lie
    ``aperture`` (m) apart; row 0 (the reference) on +x."""
    axes = np.vstack([np.eye(3), -np.eye(3)])[[0, 3, 1, 4, 2, 5]]
    return np.asarray(centre, dtype=float) + 0.5 * aperture * axes


def cube(centre: np.ndarray, aperture: float) -> np.ndarray:
    """The 8 vertices (m) of a cube about ``centre`` (3,) whose space diagonal is ``aperture`` (m)."""
    corners = np.array([[x, y, z] for x in (1, -1) for y in (1, -1) for z in (1, -1)], dtype=float)
    return np.asarray(centre, dtype=float) + 0.5 * aperture / np.sqrt(3.0) * corners


def pod_array(name: str, centre: np.ndarray, wavelength: float) -> np.ndarray:
    """The receivers (M, 3; m) of baseline ``name`` (osls: octahedron, sdp: cube) about the pod's hydrophone."""
    shape = {"osls": octahedron, "sdp": cube}[name]
    return shape(centre, APERTURE_WAVELENGTHS * wavelength)


def snapshot_range_differences(
    receivers: np.ndarray, sources: np.ndarray, sd: float, rng: np.random.Generator
) -> np.ndarray:
    """(K, M - 1) range differences |p - r_i| - |p - r_0| (m) of the sources ``sources`` (K, 3) at the
    receivers (M, 3), each with independent Gaussian noise of ``sd`` (m)."""
    ranges = np.linalg.norm(sources[:, None, :] - receivers[None, :, :], axis=2)
    exact = ranges[:, 1:] - ranges[:, :1]
    return exact + rng.normal(0.0, sd, exact.shape)


def _locator(name: str, receivers: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    if name == "osls":
        return lambda rd: arrays.osls(receivers, rd)
    return arrays.SdpLocator(receivers)


def locate_snapshots(
    name: str, receivers: np.ndarray, sources: np.ndarray, sd: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Baseline ``name``'s position error (m) and solve time (s) for one noisy snapshot of each source
    (K, 3); a snapshot the solver finds no solution for has error NaN."""
    locate = _locator(name, receivers)
    differences = snapshot_range_differences(receivers, sources, sd, rng)
    errors, seconds = np.empty(len(sources)), np.empty(len(sources))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # cvxpy: "solution may be inaccurate" (the error says how much)
        for k, (source, rd) in enumerate(zip(sources, differences)):
            start = time.perf_counter()
            try:
                errors[k] = np.linalg.norm(locate(rd) - source)
            except RuntimeError:
                errors[k] = np.nan
            seconds[k] = time.perf_counter() - start
    return errors, seconds


def _rmse(errors: np.ndarray) -> float | None:
    """:func:`aasl_gym.metrics.rmse` over the solved snapshots; None if none was."""
    value = metrics.rmse(errors)
    return None if np.isnan(value) else value


def _bound_rmse(receivers: np.ndarray, sources: np.ndarray, sd: float) -> float | None:
    if not len(sources):
        return None
    traces = [np.trace(arrays.crb(receivers, source, sd)) for source in sources]
    return float(np.sqrt(np.mean(traces)))


def array_row(sources: np.ndarray, centre: np.ndarray, wavelength: float, sd: float, seed: int) -> Row:
    """Both baselines on one trial's source track ``sources`` (K, 3; the steps the RMSE counts): for each,
    its RMSE, median error, failed solves and solve times (ms), the Cramer-Rao bound on its RMSE (the root
    of the bound's mean trace over the snapshots) and the RMSE at each sweep noise level."""
    row: Row = {}
    for index, name in enumerate(ARRAY_RECEIVERS):
        receivers = pod_array(name, centre, wavelength)
        rng = np.random.default_rng([seed, 15, index])  # the arrays' own noise, the same for every tracker
        errors, seconds = locate_snapshots(name, receivers, sources, sd, rng)
        sweep = {
            f"{level:g}": _rmse(locate_snapshots(name, receivers, sources[::SWEEP_STRIDE], level, rng)[0])
            for level in NOISE_LEVELS
        }
        row[name] = {
            "rmse": _rmse(errors),
            "median_error": float(np.nanmedian(errors)) if np.isfinite(errors).any() else None,
            "failed": int(np.sum(~np.isfinite(errors))),
            "ms_mean": 1e3 * float(np.mean(seconds)) if len(seconds) else None,  # no snapshot: no estimate to
            "ms_median": 1e3 * float(np.median(seconds)) if len(seconds) else None,  # compare it with
            "bound_rmse": _bound_rmse(receivers, sources, sd),
            "sweep_rmse": sweep,
        }
    return row


def time_calls(owner: Any, method: str) -> list[float]:
    """Wrap ``owner``'s bound ``method`` so that each call's wall time (s) is appended to the list returned."""
    seconds: list[float] = []
    call = getattr(owner, method)

    def timed(*args, **kwargs):
        start = time.perf_counter()
        out = call(*args, **kwargs)
        seconds.append(time.perf_counter() - start)
        return out

    setattr(owner, method, timed)  # an instance attribute: this object only, the class untouched
    return seconds


def _mean(values: list[float | None]) -> float | None:
    known = [value for value in values if value is not None]
    return float(np.mean(known)) if known else None


def _median(values: list[float | None]) -> float | None:
    known = [value for value in values if value is not None]
    return float(np.median(known)) if known else None


def summarize(rows: list[Row], pods: int = 8) -> list[Row]:
    """One row per method (osls, sdp, ours): receivers per pod and for ``pods`` pods, what it estimates,
    RMSE over the trials (mean and sd of each trial's, and the median), the median error, the bound's
    RMSE (median over the trials; arrays only), failed solves and the update time (mean of the trials'
    means, median of their medians; ms)."""
    table = []
    for name, per_pod in (*ARRAY_RECEIVERS.items(), ("ours", None)):
        entries = [row[name] for row in rows] if name != "ours" else [row["tracker"] for row in rows]
        rmse = [entry["rmse"] for entry in entries if entry["rmse"] is not None]
        mean, sd = mean_sd(rmse)
        table.append(
            {
                "method": name,
                "receivers_per_pod": per_pod if per_pod else "1 + 1 shared",
                "receivers_total": per_pod * pods if per_pod else pods + 1,
                "rmse_mean": mean,
                "rmse_sd": sd,
                "rmse_median": _median(rmse),
                "median_error": _median([entry["median_error"] for entry in entries]),
                "bound_rmse": _median([entry.get("bound_rmse") for entry in entries]),
                "failed": int(sum(entry.get("failed", 0) for entry in entries)),
                "ms_mean": _mean([entry["ms_mean"] for entry in entries]),
                "ms_median": _median([entry["ms_median"] for entry in entries]),
                "trials": len(entries),
            }
        )
    return table


def summarize_sweep(rows: list[Row], sd: float) -> list[Row]:
    """Per RD noise level (m), each baseline's RMSE over the sweep's snapshots (mean and median over the
    trials) and the Cramer-Rao bound on it (the trials' median; ``sd`` (m) is the noise the rows' bound
    was computed for: the bound scales with the noise)."""
    table = []
    for level in NOISE_LEVELS:
        entry: Row = {"sd": level}
        for name in ARRAY_RECEIVERS:
            values = [row[name]["sweep_rmse"][f"{level:g}"] for row in rows]
            bound = _median([row[name]["bound_rmse"] for row in rows])
            entry[name] = {
                "rmse_mean": _mean(values),
                "rmse_median": _median(values),
                "bound_rmse": None if bound is None else bound * level / sd,
            }
        table.append(entry)
    return table
