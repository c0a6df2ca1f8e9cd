"""``daq demo``: the main job on simulated hardware (the story itself is daq/demo.py).

Heavy modules are imported inside the command functions (marked ``# heavy``): `daq --help`
imports every cli module and must stay fast.
"""

from __future__ import annotations

import argparse
from pathlib import Path

DEFAULT_OUT = "out/demo"


def free_folder(base: str) -> str:
    """``base``, or ``base-2``, ``base-3``, ... the first that holds no earlier demo's recording: a second
    `make demo` runs again and keeps the first one's report (a given --out is never renamed)."""
    n, out = 1, base
    while (Path(out) / "recording.h5").exists():
        n += 1
        out = f"{base}-{n}"
    return out


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job: record a ramp through the daemon on a simulated rig, then compare, diagnose, add, compare."""
    # heavy: the daemon, the simulators and the models
    from daq.demo import run_demo

    if args.out is None:
        args.out = free_folder(DEFAULT_OUT)
    r = run_demo(args.out, hidden=args.hidden, ramp_s=args.ramp_seconds, seed=args.seed)
    added = ", ".join(r["added"]) or "nothing"
    line = (f"demo: report in {args.out}/ (summary.json, history.png, one folder per round); added {added}; "
            f"error on held-out windows {r['error_seed']:.3g} -> {r['error_final']:.3g} m (noise floor "
            f"{r['noise_floor']:.3g} m; {r['excess_removed']:.0%} of the excess removed)")
    print(line + f" in {r['seconds']:.0f} s")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    demo = sub.add_parser("demo", help="the main job on simulated hardware")
    demo.add_argument("--out", help=f"report folder (default: {DEFAULT_OUT}, or {DEFAULT_OUT}-2, -3, ... when an "
                                    "earlier demo is there)")
    demo.add_argument("--hidden", default="accel-sign", help="hidden effect of the simulated rig")
    demo.add_argument("--ramp-seconds", type=float, default=20.0, help="the 45 s seed ramp time-scaled to this")
    demo.add_argument("--seed", type=int, default=1, help="noise seed of the simulated instruments")
    demo.set_defaults(func=cmd_demo)
