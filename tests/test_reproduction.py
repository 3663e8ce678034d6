"""Committed study rows reproduce to the last bit with the code as it is (the project's rule for a refactoring),
where the platform is the one that wrote them: the same CPU vendor, library builds and OpenBLAS kernels."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# One log of each world: the free field with geometric measurements, the default world through the front end.
LOGS = ("reports/tracker/heldout_free_760000", "reports/tracker/heldout_default_720000")


def _environment() -> dict[str, str]:
    threads = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    return {**os.environ, **threads, "OPENBLAS_CORETYPE": "Haswell"}


def _platform() -> dict:
    script = "import json; from aasl_gym.study.log import platform_record; print(json.dumps(platform_record()))"
    done = subprocess.run([sys.executable, "-c", script], env=_environment(), capture_output=True, text=True, cwd=ROOT)
    return _comparable(json.loads(done.stdout))


def _comparable(platform: dict) -> dict:
    """``platform`` with its BLAS libraries in one order (they are listed in the order they were loaded)."""
    return {**platform, "blas": sorted(platform.get("blas", "").split("; "))}


def test_committed_rows_reproduce_on_the_platform_that_wrote_them():
    """The first row of each log (spread over one row) re-run: every field the same, or the checker exits 1."""
    written = [_comparable(json.loads((ROOT / log / "results.json").read_text())["platform"]) for log in LOGS]
    here, committed = _platform(), written[0]
    if any(platform != here for platform in written):
        pytest.skip(f"rows written on {committed}, this platform is {here}")
    command = [sys.executable, "benchmarks/reproduce_rows.py", *(f"{log}/episodes.jsonl" for log in LOGS)]
    done = subprocess.run(
        [*command, "--rows", "1", "--workers", "1"], env=_environment(), capture_output=True, text=True, cwd=ROOT
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "2 of 2 rows reproduce" in done.stdout
