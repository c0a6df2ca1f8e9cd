"""``daq warm``: compile the numerical kernels into the on-disk cache (daq/models/fit/warm.py says why).

Heavy modules are imported inside the command (``# heavy``): `daq --help` imports every cli module.
"""

from __future__ import annotations

import argparse
import sys
import time


def cmd_warm(args: argparse.Namespace) -> int:
    from daq.models.fit.warm import warm_kernels  # heavy: numba, scipy, the models

    t0 = time.perf_counter()
    warm_kernels(lambda msg: print(f"  {msg}", file=sys.stderr, flush=True))
    print(f"daq warm: kernels compiled or loaded in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("warm", help="compile the numerical kernels into the on-disk cache once (the first simulation, "
                                    "fit or daemon run otherwise compiles them, each process for itself)")
    p.set_defaults(func=cmd_warm)
