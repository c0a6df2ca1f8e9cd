"""JSON output of every command and report: one encoder (numpy values as plain numbers), written atomically.

Light on purpose (no numpy import): the command line prints ``--json`` through it and
`daq --help` must not pay for numpy. numpy arrays and scalars are recognised by ``tolist``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from daq.io.files import atomic_path


def json_default(o: Any) -> Any:
    """numpy arrays and scalars as plain JSON (their ``tolist``); anything else by its text."""
    if hasattr(o, "tolist"):
        return o.tolist()
    return str(o)


def dumps_json(obj: Any, indent: int | None = 2) -> str:
    return json.dumps(obj, indent=indent, default=json_default)


def print_json(obj: Any) -> None:
    """``--json``: one object on stdout."""
    sys.stdout.write(dumps_json(obj) + "\n")


def write_json(path: str | Path, obj: Any) -> Path:
    """``obj`` as indented JSON at ``path``, atomically."""
    with atomic_path(path) as tmp:
        Path(tmp).write_text(dumps_json(obj))
    return Path(path)

