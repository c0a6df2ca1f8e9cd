"""The physics shared by the simulator and the models: rig equations, friction laws, effects.

Numba caches compiled functions per source file and does not notice when a
function's callee changes in another file, so the cache lives in a directory
keyed by a hash of all compiled sources: any edit gets a fresh cache.

Decision record: docs/decisions/0001-physics-in-one-place.md.

Exports (``__all__``) the rigs' modules, ``friction`` and the effect catalogue, each imported when first used.
Importing the package imports no numba (see below).
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

from daq import lazy_exports


def _cache_dir() -> Path:
    here = Path(__file__).resolve().parent
    files = sorted(here.glob("*.py")) + sorted((here.parent / "sim").glob("*.py"))
    digest = hashlib.sha1(b"".join(f.read_bytes() for f in files)).hexdigest()[:16]
    base = Path(os.environ.get("DAQ_NUMBA_CACHE", Path.home() / ".cache" / "friction-daq"))
    return base / f"numba-{digest}"


if "NUMBA_CACHE_DIR" not in os.environ:
    # numba reads NUMBA_CACHE_DIR when it is first imported: set here, numba is imported only by a process that
    # compiles (a config's reader needs the catalog alone, daq.physics.catalog); one that imported numba already
    # is told directly. Either way the cache is this source tree's.
    if "numba" in sys.modules:
        sys.modules["numba"].config.CACHE_DIR = str(_cache_dir())
    else:
        os.environ["NUMBA_CACHE_DIR"] = str(_cache_dir())

__getattr__, __dir__, __all__ = lazy_exports(
    __name__, {"catalog": ["CATALOG", "E"]}, modules=["beltndof", "brake2dof", "drum", "friction"]
)
