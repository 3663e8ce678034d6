"""Committed study rows reproduce to the last bit with the code as it is (the project's rule for a refactoring),
where the platform is the one that wrote them: the same CPU vendor, library builds and OpenBLAS kernels."""

import functools
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# One study of each world - the free field with geometric measurements, the default world through the front end - and
# the greedy planner's (its scores compiled apart from the env's information).
STUDIES = (
    ("reports/tracker/heldout_free_760000", "episodes.jsonl", "helix"),
    ("reports/tracker/heldout_default_720000", "episodes.jsonl", "helix"),
    ("reports/patrol/default_world", "results.json", "greedy"),
)


def _environment() -> dict[str, str]:
    threads = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    return {**os.environ, **threads, "OPENBLAS_CORETYPE": "Haswell"}


@functools.cache
def _platform() -> dict:
    """This platform's record as a study writes it (one subprocess for every study checked)."""
    script = "import json; from aasl_gym.study.log import platform_record; print(json.dumps(platform_record()))"
    done = subprocess.run([sys.executable, "-c", script], env=_environment(), capture_output=True, text=True, cwd=ROOT)
    return json.loads(done.stdout)


def _comparable(platform: dict, keys: dict | None = None) -> dict:
    """``platform``'s ``keys`` (all if None; an older record lacks the BLAS kernels), its BLAS libraries in one order
    (they are listed in the order they were loaded)."""
    kept = {key: value for key, value in platform.items() if keys is None or key in keys}
    if "blas" in kept:
        kept["blas"] = sorted(kept["blas"].split("; "))
    return kept


@pytest.mark.parametrize("folder, source, policy", STUDIES)
def test_committed_rows_reproduce_on_the_platform_that_wrote_them(folder, source, policy):
    """The study's first row of ``policy`` re-run: every field the same, or the checker exits 1."""
    committed = _comparable(json.loads((ROOT / folder / "results.json").read_text())["platform"])
    here = _comparable(_platform(), committed)
    if committed != here:
        pytest.skip(f"rows written on {committed}, this platform is {here}")
    command = [sys.executable, "benchmarks/reproduce_rows.py", f"{folder}/{source}", "--policies", policy]
    done = subprocess.run(
        [*command, "--rows", "1", "--workers", "1"], env=_environment(), capture_output=True, text=True, cwd=ROOT
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "1 of 1 rows reproduce" in done.stdout
