"""``episodes.jsonl``, the log a study resumes from: the config on the first line, then one line per
finished episode, appended and flushed as each one arrives."""

from __future__ import annotations

import json
import platform
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numba
import numpy as np
import scipy
from threadpoolctl import threadpool_info

from aasl_gym.io import atomic_write_json, atomic_write_text

Row = dict[str, Any]  # one episode's results (``agents.rollout``'s keys), as the log keeps them


def platform_record() -> dict[str, str]:
    """Where a report was written: Python, NumPy, SciPy and numba versions, the processor and the BLAS kernels. A
    seed's episode is the same to the last bit on one machine and build; on another (CPU, or builds of NumPy and
    its BLAS) the vectorized math can round differently in the last bit, and the tracker's decisions amplify that
    (rows resumed from an earlier run may come from another machine). OpenBLAS picks its kernels by processor:
    on an AVX-512 machine (SkylakeX kernels) committed rows made with the Haswell kernels differ from the 12th
    digit on, and ``OPENBLAS_CORETYPE=Haswell`` brings them back to the bit (README)."""
    return {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,  # the compiled phasor model and sine (aasl_gym.kernels)
        "machine": platform.machine(),
        "processor": _processor_name(),
        "blas": _blas_kernels(),
    }


def write_results_json(path: str | Path, results: dict[str, Any]) -> None:
    """A study's ``results.json``, atomically, with the :func:`platform_record` of where it was written."""
    atomic_write_json(path, results | {"platform": platform_record()})


def _blas_kernels() -> str:
    """The BLAS libraries loaded (NumPy's and SciPy's), each with its version and the kernels it chose, e.g.
    ``openblas 0.3.30 Haswell``; threadpoolctl reads them from the libraries themselves."""
    libraries = [info for info in threadpool_info() if info.get("user_api") == "blas"]
    return "; ".join(
        " ".join(str(info.get(key) or "?") for key in ("internal_api", "version", "architecture")) for info in libraries
    )


def _processor_name() -> str:
    """The CPU's model name (Linux's /proc/cpuinfo), else what :func:`platform.processor` says."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


class LogMismatch(ValueError):
    """An existing log cannot be resumed: it has no config line, or another config's."""


class EpisodeLog:
    """The log at ``path`` of the episodes run with ``config`` (the env config as plain values, the same
    for every episode: each line names its episode by the key of :func:`~aasl_gym.study.jobs.episode_key`)."""

    def __init__(self, path: str | Path, config: dict[str, Any]):
        self.path = Path(path)
        self.header = {"config": json.loads(json.dumps(config))}  # as it reads back: tuples are lists

    def open(self, resume: bool) -> dict[tuple, Row]:
        """The rows to reuse: with ``resume`` those of :meth:`read`; without (or with none), a new log."""
        done = self.read() if resume else {}
        if done:
            self._mend_tail()
        else:
            self.start()
        return done

    def _mend_tail(self) -> None:
        """Ready a kept log for appending: a torn last line (:meth:`read` skipped it) is cut off, and a whole last
        line without its newline gets one; else the next row would be written onto it and both lost."""
        data = self.path.read_bytes()
        if data.endswith(b"\n"):
            return
        start = data.rfind(b"\n") + 1
        try:
            json.loads(data[start:])
        except ValueError:
            with open(self.path, "r+b") as handle:
                handle.truncate(start)
            return
        with open(self.path, "ab") as handle:
            handle.write(b"\n")

    def start(self) -> None:
        """A new log holding only the config line (replacing any earlier one)."""
        atomic_write_text(self.path, json.dumps(self.header) + "\n")

    def read(self) -> dict[tuple, Row]:
        """The rows of an earlier run by episode key (none if there is no log). A torn last line (the run
        killed mid-write) is skipped: that episode runs again. Raises :class:`LogMismatch` for a log
        without a config line or with another config than this one. A log written before fields were
        added to the config still matches: each new field's default keeps the behaviour it had without it
        (the project's rule for a new field), so only a changed or removed value is another config. So
        does a study's log from before it gained variants (appended): their rows are new."""
        if not self.path.is_file():
            return {}
        try:
            lines = self.path.read_text().splitlines()
        except UnicodeDecodeError as exc:
            raise LogMismatch(f"{self.path} is not a text log ({exc})") from None
        try:
            written = json.loads(lines[0])["config"]
        except (IndexError, KeyError, TypeError, json.JSONDecodeError):
            raise LogMismatch(f"{self.path} does not start with a config line") from None
        expected = self.header["config"]
        if not _extends(expected, written):
            keys = set(written) | set(expected)
            sections = sorted(k for k in keys if k not in expected or not _extends(expected[k], written.get(k), k))
            raise LogMismatch(f"{self.path} was written with another config (sections {sections} differ)")
        done = {}
        for line in lines[1:]:
            try:
                entry = json.loads(line)
            except json.JSONDecodeError:
                continue
            done[tuple(entry["key"])] = entry["row"]
        return done

    @contextmanager
    def appending(self) -> Iterator[Callable[[tuple, Row], None]]:
        """A function that appends one episode's line (its key and row) and flushes it at once."""
        with open(self.path, "a") as handle:

            def append(key: tuple, row: Row) -> None:
                handle.write(json.dumps({"key": key, "row": row}) + "\n")
                handle.flush()

            yield append


def _extends(new: Any, old: Any, name: str = "") -> bool:
    """Whether ``new`` is ``old`` with keys added to its mappings, at any depth, and variants appended to a
    study's ``variants`` (its rows name their variant), and nothing else changed."""
    if isinstance(new, dict) and isinstance(old, dict):
        return set(old) <= set(new) and all(_extends(new[key], value, key) for key, value in old.items())
    if name == "variants" and isinstance(new, list) and isinstance(old, list):
        return new[: len(old)] == old  # a variant's changes are the values it runs with: each one as it was
    return new == old
