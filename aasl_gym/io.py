"""File input and output: atomic writes (write to a temporary file in the same folder, then rename over the
target) and YAML reading with the exponent floats researchers write (``1e-7``)."""

from __future__ import annotations

import json
import os
import re
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml


def _new_file_mode() -> int:
    """The mode ``open()`` gives a new file: 0o666 less the process's umask (read back by setting it twice)."""
    umask = os.umask(0o022)
    os.umask(umask)
    return 0o666 & ~umask


def atomic_write(path: str | Path, write: Callable[[str], object]) -> Path:
    """Call ``write(tmp_path)`` and rename the result onto ``path``; a crash never leaves half a file. The file gets
    the mode a new file gets (0o666 less the umask; ``mkstemp``'s own, 0o600, would hide reports from the rest of a
    group), also where it replaces one: unlike a write in place, the replaced file's own mode is not kept."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, _new_file_mode())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    return atomic_write(path, lambda tmp: Path(tmp).write_text(text))


def atomic_write_json(path: str | Path, data: Any) -> Path:
    return atomic_write_text(path, json.dumps(data, indent=2, allow_nan=False) + "\n")


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader, which follows YAML 1.1 and so reads ``1e-7`` or ``3e-4`` (no dot, or no sign in the
    exponent) as strings; YAML 1.2 takes them for numbers, and so does this loader."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$"),
    list("-+.0123456789"),
)


def read_yaml(text: str) -> Any:
    """The plain values of a YAML document (safe loading: no Python objects), ``1e-7`` a float; raises
    ``yaml.YAMLError`` where it is not valid YAML."""
    return yaml.load(text, Loader=_Loader)  # a SafeLoader: plain values only
