"""The physics shared by the simulator and the models: rig equations, friction laws, effects.

Numba caches compiled functions per source file and does not notice when a
function's callee changes in another file, so the cache lives in a directory
keyed by a hash of all compiled sources: any edit gets a fresh cache.

Decision record: docs/decisions/0001-physics-in-one-place.md.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path


def _cache_dir() -> Path:
    here = Path(__file__).resolve().parent
    files = sorted(here.glob("*.py")) + sorted((here.parent / "sim").glob("*.py"))
    digest = hashlib.sha1(b"".join(f.read_bytes() for f in files)).hexdigest()[:16]
    base = Path(os.environ.get("DAQ_NUMBA_CACHE", Path.home() / ".cache" / "friction-daq"))
    return base / f"numba-{digest}"


if "NUMBA_CACHE_DIR" not in os.environ:
    import numba

    numba.config.CACHE_DIR = str(_cache_dir())
