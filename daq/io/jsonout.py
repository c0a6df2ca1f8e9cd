"""JSON output of every command and report: one encoder (numpy values as plain numbers), written atomically.

Light on purpose (no numpy import): the command line prints ``--json`` through it and
`daq --help` must not pay for numpy. numpy arrays and scalars are recognised by ``tolist``.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

from daq.io.files import atomic_path


def json_default(o: Any) -> Any:
    """numpy arrays and scalars as plain JSON (their ``tolist``); anything else by its text."""
    if hasattr(o, "tolist"):
        return o.tolist()
    return str(o)


def finite_json(obj: Any) -> Any:
    """``obj`` with every non-finite float as None: JSON has no NaN or Infinity (Python writes them, and
    strict readers - browsers, jq, other languages - refuse the file; issue 16 found ``"error": Infinity``
    in daq-history.jsonl). numpy values become plain ones on the way."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if hasattr(obj, "tolist"):
        return finite_json(obj.tolist())
    return obj


def dumps_json(obj: Any, indent: int | None = 2) -> str:
    """Standard JSON (non-finite numbers as null), numpy values as plain numbers."""
    return json.dumps(finite_json(obj), indent=indent, default=json_default, allow_nan=False)


def print_json(obj: Any) -> None:
    """``--json``: one object on stdout."""
    sys.stdout.write(dumps_json(obj) + "\n")


def write_json(path: str | Path, obj: Any) -> Path:
    """``obj`` as indented JSON at ``path``, atomically."""
    with atomic_path(path) as tmp:
        Path(tmp).write_text(dumps_json(obj))
    return Path(path)

