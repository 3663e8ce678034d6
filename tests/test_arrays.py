"""The fixed-array baselines (issue 15): exact on noise-free snapshots, spread against the Cramer-Rao
bound of the same array, clear errors for arrays that cannot localize; the pods' arrays and the
comparison study (``paper.py arrays``)."""

import importlib.util
import json
import warnings

import numpy as np
import pytest

import paper
from aasl_gym import arrays
from aasl_gym.study.array_comparison import (
    APERTURE_WAVELENGTHS,
    cube,
    octahedron,
    pod_array,
    snapshot_range_differences,
)

needs_cvxpy = pytest.mark.skipif(importlib.util.find_spec("cvxpy") is None, reason="sdp needs the arrays extra")


def range_differences(receivers: np.ndarray, source: np.ndarray) -> np.ndarray:
    ranges = np.linalg.norm(source - receivers, axis=1)
    return ranges[1:] - ranges[0]


def random_scene(rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
    """A random (non-coplanar, almost surely) array of ``count`` receivers in a 10 m cube and a source
    within 12 m of its centre."""
    return rng.uniform(-5.0, 5.0, (count, 3)), rng.uniform(-12.0, 12.0, 3)


@pytest.mark.parametrize("seed", range(5))
def test_osls_recovers_the_source_from_noise_free_differences(seed):
    receivers, source = random_scene(np.random.default_rng(seed), 6)
    estimate = arrays.osls(receivers, range_differences(receivers, source))
    assert np.linalg.norm(estimate - source) < 1e-8


@needs_cvxpy
@pytest.mark.parametrize("seed", range(3))
def test_sdp_recovers_the_source_from_noise_free_differences(seed):
    receivers, source = random_scene(np.random.default_rng(100 + seed), 8)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # cvxpy's "may be inaccurate" at tolerances this tight
        estimate = arrays.sdp(receivers, range_differences(receivers, source))
    assert np.linalg.norm(estimate - source) < 1e-3


def test_crb_matches_the_finite_difference_fisher_information():
    receivers, source = random_scene(np.random.default_rng(7), 6)
    step, sd = 1e-6, 0.01
    jacobian = np.column_stack(
        [
            (range_differences(receivers, source + step * e) - range_differences(receivers, source - step * e))
            / (2 * step)
            for e in np.eye(3)
        ]
    )
    expected = np.linalg.inv(jacobian.T @ jacobian / sd**2)
    np.testing.assert_allclose(arrays.crb(receivers, source, sd), expected, rtol=1e-6)


@needs_cvxpy
def test_error_spread_lies_near_the_cramer_rao_bound_at_small_noise():
    """Neither can beat the bound; the SDP (a relaxed maximum likelihood) comes close to it, the
    unweighted one-step least squares within a few times it."""
    rng = np.random.default_rng(11)
    receivers, source = random_scene(rng, 8)
    sd = 1e-3
    exact = range_differences(receivers, source)
    locator = arrays.SdpLocator(receivers)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        sdp_errors = np.array([locator(exact + rng.normal(0.0, sd, 7)) - source for _ in range(150)])
    osls_errors = np.array(
        [arrays.osls(receivers[:6], exact[:5] + rng.normal(0.0, sd, 5)) - source for _ in range(400)]
    )
    sdp_ratio = np.trace(np.cov(sdp_errors.T)) / np.trace(arrays.crb(receivers, source, sd))
    osls_ratio = np.trace(np.cov(osls_errors.T)) / np.trace(arrays.crb(receivers[:6], source, sd))
    assert 0.75 < sdp_ratio < 1.6
    assert 0.8 < osls_ratio < 6.0
    assert np.linalg.norm(sdp_errors.mean(axis=0)) < 0.3 * np.sqrt(np.trace(arrays.crb(receivers, source, sd)))


@pytest.mark.parametrize("estimator", [arrays.osls, pytest.param(arrays.sdp, marks=needs_cvxpy)])
def test_coplanar_arrays_are_refused(estimator):
    rng = np.random.default_rng(3)
    receivers = np.column_stack([rng.uniform(-5, 5, (8, 2)), np.full(8, -10.0)])  # all at one depth
    with pytest.raises(arrays.DegenerateArray, match="one plane"):
        estimator(receivers, range_differences(receivers, np.array([1.0, 2.0, -3.0])))


def test_bad_shapes_and_too_few_receivers_are_named():
    receivers, source = random_scene(np.random.default_rng(5), 6)
    rd = range_differences(receivers, source)
    with pytest.raises(ValueError, match="range_differences must have M - 1 = 5"):
        arrays.osls(receivers, rd[:4])
    with pytest.raises(ValueError, match=r"receivers must be an \(M, 3\) array"):
        arrays.osls(receivers[:, :2], rd)
    with pytest.raises(arrays.DegenerateArray, match="at least 5 receivers"):
        arrays.osls(receivers[:4], rd[:3])
    with pytest.raises(ValueError, match="range_differences must be finite"):
        arrays.osls(receivers, np.where(np.arange(5) == 2, np.nan, rd))


def test_the_pod_arrays_fit_within_their_aperture_about_the_pod():
    centre, aperture = np.array([1.0, -2.0, -30.0]), 0.75
    for receivers, count in ((octahedron(centre, aperture), 6), (cube(centre, aperture), 8)):
        spans = np.linalg.norm(receivers[:, None] - receivers[None], axis=2)
        assert receivers.shape == (count, 3)
        assert spans.max() == pytest.approx(aperture)  # opposite vertices / the space diagonal
        np.testing.assert_allclose(receivers.mean(axis=0), centre, atol=1e-12)
    wavelength = 1500.0 / 1000.0
    assert pod_array("osls", centre, wavelength).shape == (6, 3)
    span = np.linalg.norm(pod_array("sdp", centre, wavelength)[0] - pod_array("sdp", centre, wavelength)[-1])
    assert span == pytest.approx(APERTURE_WAVELENGTHS * wavelength)


def test_snapshots_are_the_range_differences_of_each_source():
    rng = np.random.default_rng(0)
    receivers, sources = rng.uniform(-1, 1, (6, 3)), rng.uniform(-20, 20, (4, 3))
    exact = snapshot_range_differences(receivers, sources, 0.0, rng)
    for source, rd in zip(sources, exact):
        np.testing.assert_allclose(rd, range_differences(receivers, source), atol=1e-12)
    noisy = snapshot_range_differences(receivers, np.repeat(sources[:1], 4000, axis=0), 0.05, rng)
    assert np.std(noisy - exact[0], axis=0) == pytest.approx(np.full(5, 0.05), rel=0.1)


@needs_cvxpy
def test_a_tiny_array_comparison_writes_its_table(tmp_path):
    short = tmp_path / "short.yaml"
    short.write_text("episode:\n  duration: 6.0\n")  # 30 steps: the tracker's estimate from 2 s on
    assert paper.main(["arrays", "--trials", "2", "--config", str(short), "--no-plots", "--out", str(tmp_path)]) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    trial = results["trials"][0]
    assert {"rmse", "median_error", "ms_mean", "ms_median", "bound_rmse", "sweep_rmse"} <= set(trial["sdp"])
    assert {"rmse", "rmse_second_half", "ms_mean", "ms_median"} <= set(trial["tracker"])
    assert [entry["method"] for entry in results["summary"]] == ["osls", "sdp", "ours"]
    assert [entry["receivers_total"] for entry in results["summary"]] == [48, 64, 9]
    report = (tmp_path / "report.md").read_text()
    assert "| SDP, 8 receivers | 8 | 64 | position, per snapshot |" in report
    assert "| arrays' RD noise sd (m) | OSLS RMSE (m): mean (median) | its bound (m) |" in report


def test_the_array_study_without_cvxpy_says_what_to_install(monkeypatch, capsys):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "cvxpy" else real(name, *a))
    assert paper.main(["arrays", "--trials", "1"]) == 2
    assert "needs cvxpy for the SDP baseline: pip install -e '.[arrays]'" in capsys.readouterr().err
