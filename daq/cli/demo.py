"""``daq demo``: the main job on simulated hardware (the story itself is daq/demo.py).

Heavy modules are imported inside the command functions (marked ``# heavy``): `daq --help`
imports every cli module and must stay fast.
"""

from __future__ import annotations

import argparse
from pathlib import Path

DEFAULT_OUT = "out/demo"


def free_folder(base: str, first: str = "recording.h5") -> str:
    """``base``, or ``base-2``, ``base-3``, ... the first that holds no earlier demo's recording (``first``): a second
    `make demo` runs again and keeps the first one's report (a given --out is never renamed)."""
    n, out = 1, base
    while (Path(out) / first).exists():
        n += 1
        out = f"{base}-{n}"
    return out


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job: record a ramp through the daemon on a simulated rig, then compare, diagnose, add, compare."""
    # heavy: the daemon, the simulators and the models
    from daq.demo import HIDDEN, LOOP_HIDDEN, run_closed_loop, run_demo

    if args.closed_loop:
        return _closed_loop(args, run_closed_loop, LOOP_HIDDEN)
    if args.out is None:
        args.out = free_folder(DEFAULT_OUT)
    r = run_demo(args.out, hidden=args.hidden or HIDDEN, ramp_s=args.ramp_seconds, seed=args.seed)
    added = ", ".join(r["added"]) or "nothing"
    line = (f"demo: report in {args.out}/ (summary.json, history.png, one folder per round); added {added}; "
            f"error on held-out windows {r['error_baseline']:.3g} -> {r['error_final']:.3g} m (noise floor "
            f"{r['noise_floor']:.3g} m; {r['excess_removed']:.0%} of the excess removed)")
    print(line + f" in {r['seconds']:.0f} s")
    return 0


def _closed_loop(args: argparse.Namespace, run_closed_loop, default_hidden: str) -> int:
    """`daq demo --closed-loop`: record, diagnose, propose the run that decides, run it, diagnose both."""
    if args.out is None:
        args.out = free_folder(DEFAULT_OUT + "-loop", first="run-1.h5")
    r = run_closed_loop(args.out, hidden=args.hidden or default_hidden, seed=args.seed)
    fell = [s["fell"] for s in r["steps"] if "fell" in s]
    print(f"demo --closed-loop: report in {args.out}/ (summary.json, proposal-N/next.png); hidden {r['hidden_effect']}; "
          f"{r['proposed_runs']} proposed run(s); named {', '.join(r['named']) or 'nothing'}; error on held-out windows "
          f"{r['error_baseline']:.3g} -> {r['error_final']:.3g} m (noise floor {r['noise_floor']:.3g} m) in {r['seconds']:.0f} s"
          + "".join(f"\n  {f}" for f in fell))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    demo = sub.add_parser("demo", help="the main job on simulated hardware")
    demo.add_argument("--out", help=f"report folder (default: {DEFAULT_OUT}, or {DEFAULT_OUT}-2, -3, ... when an "
                                    "earlier demo is there)")
    demo.add_argument("--hidden", help="hidden effect of the simulated rig (default: accel-sign; with --closed-loop "
                                       "a belt lagging its command by 0.15 s, which one constant speed cannot show)")
    demo.add_argument("--closed-loop", action="store_true",
                      help="record at one constant speed, diagnose, propose the run that decides what the record "
                           "leaves open, run it through the daemon, diagnose both together (issue 26)")
    demo.add_argument("--ramp-seconds", type=float, default=20.0, help="paper 001's 45 s deceleration ramp, time-scaled to this")
    demo.add_argument("--seed", type=int, default=1, help="noise seed of the simulated instruments")
    demo.set_defaults(func=cmd_demo)
