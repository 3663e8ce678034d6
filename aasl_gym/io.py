"""File input and output: atomic writes (write to a temporary file in the same folder, then rename over the
target) and YAML reading with the exponent floats researchers write (``1e-7``)."""

from __future__ import annotations

import json
import os
import re
import secrets
import stat
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

import yaml


def _new_temporary(folder: Path, name: str, suffix: str) -> tuple[str, int]:
    """An empty new file ``.{name}.{12 random hex digits}{suffix}`` in ``folder``, created as ``open()`` creates a
    file (mode 0o666, which the kernel narrows by the umask; ``mkstemp``'s is a private 0o600), and that mode."""
    for _ in range(100):
        tmp = folder / f".{name}.{secrets.token_hex(6)}{suffix}"
        try:
            descriptor = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        try:
            return str(tmp), stat.S_IMODE(os.fstat(descriptor).st_mode)
        finally:
            os.close(descriptor)
    raise FileExistsError(f"no free temporary name for {name!r} in {folder}")


def atomic_write(path: str | Path, write: Callable[[str], object]) -> Path:
    """Call ``write(tmp_path)`` and rename the result onto ``path``; a crash never leaves half a file. The file gets
    the mode a new file gets (0o666 less the umask; a private temporary file's 0o600 would hide reports from the
    rest of a group), also where it replaces one (unlike a write in place, the replaced file's own mode is not kept)
    and where ``write`` put a file of another mode at ``tmp_path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp, mode = _new_temporary(path.parent, path.name, path.suffix)
    try:
        write(tmp)
        if stat.S_IMODE(os.stat(tmp).st_mode) != mode:
            os.chmod(tmp, mode)
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
    exponent) as strings; YAML 1.2 takes them for numbers, and so does this loader. A key given twice in one mapping
    is an error (PyYAML keeps the last and drops the first's values without a word)."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue  # '<<' merges, which an own key may override
                key = self.construct_object(key_node, deep=deep)
                if isinstance(key, Hashable) and key in seen:
                    raise yaml.constructor.ConstructorError(
                        "while constructing a mapping", node.start_mark, f"found key {key!r} twice", key_node.start_mark
                    )
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$"),
    list("-+.0123456789"),
)


def read_yaml(text: str) -> Any:
    """The plain values of a YAML document (safe loading: no Python objects), ``1e-7`` a float; raises
    ``yaml.YAMLError`` where it is not valid YAML."""
    return yaml.load(text, Loader=_Loader)  # a SafeLoader: plain values only
