"""``daq sim RIG``: simulate a rig into an interchange file (CSV or HDF5) and its figure.

Heavy modules are imported inside the command functions (marked ``# heavy``): `daq --help`
imports every cli module and must stay fast.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from daq.errors import InputError

from .output import progress


def cmd_sim(args: argparse.Namespace) -> int:
    # heavy: the compiled physics, h5py and matplotlib only when the command runs
    from daq.config import load_rig
    from daq.io.interchange import write_recording
    from daq.ramps import load_ramp
    from daq.sim.effectset import parse_effect
    from daq.sim.figures import sim_figure
    from daq.sim.run import simulate

    out = Path(args.output)
    if out.suffix.lower() not in (".h5", ".hdf5", ".csv"):
        raise InputError(str(out), "-o", "output must end in .h5, .hdf5 or .csv")
    cfg = load_rig(args.rig)
    effects = [parse_effect(x) for x in args.effect]
    ramp = None
    if args.ramp:
        _, rt, rv = load_ramp(args.ramp)
        ramp = (rt, rv)
    duration = args.duration
    if duration is None and ramp is not None:
        duration = float(ramp[0][-1])
    with progress(f"sim {cfg.rig}") as prog:
        task = prog.add_task("sim", total=float(duration or cfg.drive.default_duration_s))
        rec = simulate(cfg, effects=effects, ramp=ramp, ramp_source=args.ramp or "ramp", duration=duration,
                       rate=args.rate, seed=args.seed, progress=lambda d, T: prog.update(task, completed=d))
    write_recording(rec, out, truth_in_csv=args.truth)
    fig = None
    if not args.no_figure:
        fig = out.with_suffix(".png")
        labels = ", ".join(f"{k}" for k in rec.meta["effects"]) or "none"
        sim_figure(rec, fig, title=f"{cfg.rig}: {rec.meta['ramp']}; effects: {labels}; seed {args.seed}")
    print(f"wrote {out} ({len(rec.t)} samples at {rec.meta['rate_Hz']:g} Hz, channels "
          f"{', '.join(rec.channels)})" + (f" and {fig}" if fig else ""), file=sys.stderr)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    sim = sub.add_parser("sim", help="simulate a rig into an interchange file")
    sim.add_argument("rig", help="rig id or path to a rig TOML")
    sim.add_argument("--ramp", help="ramp file (.toml segments or .csv t,vb)")
    sim.add_argument("--duration", type=float, help="simulated seconds (default: the rig's)")
    sim.add_argument("--effect", action="append", default=[], metavar="NAME[:key=val,...]",
                     help="add a catalog effect (repeatable)")
    sim.add_argument("--seed", type=int, default=0, help="noise seed")
    sim.add_argument("--rate", type=float, help="output sample rate [Hz] (default: the rig's)")
    sim.add_argument("--truth", action="store_true", help="also write ground-truth columns to CSV")
    sim.add_argument("--no-figure", action="store_true", help="do not write OUT.png")
    sim.add_argument("-o", "--output", required=True, help="OUT.h5 or OUT.csv")
    sim.set_defaults(func=cmd_sim)
