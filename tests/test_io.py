"""Atomic writes: a file is replaced whole or not at all."""

import json
import os
import stat
import tempfile
from pathlib import Path

import pytest

from aasl_gym.io import atomic_write, atomic_write_json, atomic_write_text


def test_a_write_replaces_the_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "sub" / "report.md"
    atomic_write_text(target, "first")
    atomic_write_text(target, "second")
    assert target.read_text() == "second"
    assert [p.name for p in target.parent.iterdir()] == ["report.md"]


def test_a_failed_write_keeps_the_old_file_and_cleans_up(tmp_path):
    target = tmp_path / "model.zip"
    target.write_text("old")

    def crash(tmp: str) -> None:
        Path(tmp).write_text("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):
        atomic_write(target, crash)
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["model.zip"]


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_a_written_file_has_the_mode_a_plain_write_gives(tmp_path, umask):
    """Not the temporary file's private 0o600: a report shared with a group reads as any file the user writes."""
    previous = os.umask(umask)
    try:
        (tmp_path / "plain.md").write_text("x")
        atomic_write_text(tmp_path / "atomic.md", "x")
    finally:
        os.umask(previous)
    mode = stat.S_IMODE((tmp_path / "plain.md").stat().st_mode)
    assert stat.S_IMODE((tmp_path / "atomic.md").stat().st_mode) == mode == 0o666 & ~umask


def test_a_writer_that_replaces_the_temporary_file_still_gives_a_new_files_mode(tmp_path):
    """A library may write elsewhere and move its file onto the path it was given (mkstemp's private 0o600)."""

    def replace_it(tmp: str) -> None:
        fd, own = tempfile.mkstemp(dir=tmp_path)
        os.close(fd)
        os.replace(own, tmp)

    atomic_write(tmp_path / "model.zip", replace_it)
    (tmp_path / "plain.md").write_text("x")
    assert stat.S_IMODE((tmp_path / "model.zip").stat().st_mode) == stat.S_IMODE((tmp_path / "plain.md").stat().st_mode)


def test_a_write_leaves_the_umask_alone(tmp_path, monkeypatch):
    """The umask is the process's: setting it, even for a moment, would change what other threads create."""

    def refuse(mask: int) -> int:
        raise AssertionError(f"os.umask({mask:#o}) called")

    monkeypatch.setattr(os, "umask", refuse)
    atomic_write_text(tmp_path / "report.md", "x")
    assert (tmp_path / "report.md").read_text() == "x"


def test_json_is_strict(tmp_path):
    """NaN is not JSON: it is refused rather than written as a token other readers reject."""
    atomic_write_json(tmp_path / "ok.json", {"a": 1.5})
    assert json.loads((tmp_path / "ok.json").read_text()) == {"a": 1.5}
    with pytest.raises(ValueError):
        atomic_write_json(tmp_path / "bad.json", {"a": float("nan")})
    assert not (tmp_path / "bad.json").exists()
