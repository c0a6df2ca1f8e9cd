"""The ``daq`` command line. Bad input of any kind: one line on stderr naming file and field, exit 2."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from daq.errors import InputError


def _print_json(obj: object) -> None:
    sys.stdout.write(json.dumps(obj, indent=2, default=float) + "\n")


def _progress(label: str):
    """A rich progress bar on stderr when it is a terminal; silent otherwise."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    prog = Progress(TextColumn(label), BarColumn(), TextColumn("{task.completed:.1f}/{task.total:.1f} s"),
                    TimeRemainingColumn(), transient=True, disable=not sys.stderr.isatty())
    return prog


# ----------------------------------------------------------------------------- rig


def cmd_rig_list(args: argparse.Namespace) -> int:
    from daq.config import load_rig, rig_ids

    for rid in rig_ids():
        cfg = load_rig(rid)
        print(f"{rid:15s} paper {cfg.paper}  {cfg.title}")
    return 0


def rig_summary(rig: str) -> dict:
    """Parameters, channels, effects and linearised eigenfrequencies of a rig (its seed configuration)."""
    from daq.config import load_rig
    from daq.physics.effects import CATALOG
    from daq.sim.effectset import effect_vector
    from daq.sim.rigs import make_sim

    cfg = load_rig(rig)
    e, active = effect_vector(cfg)
    sim = make_sim(cfg, e)
    return {
        "rig": cfg.rig,
        "title": cfg.title,
        "paper": cfg.paper,
        "mechanics": cfg.mechanics.model_dump(),
        "friction": cfg.friction.model_dump(),
        "drive": cfg.drive.model_dump(exclude_none=True),
        "channels": {k: {"unit": c.unit, "instrument": c.instrument, "description": c.description}
                     for k, c in cfg.channels.items()},
        "seed_effects": active,
        "applicable_effects": [n for n, s in CATALOG.items() if cfg.rig in s.rigs],
        "effect_defaults": cfg.effects,
        "linear_modes_hz": sim.modes_hz(),
        "chosen": cfg.chosen,
    }


def cmd_rig_show(args: argparse.Namespace) -> int:
    info = rig_summary(args.rig)
    if args.json:
        _print_json(info)
        return 0
    print(f"{info['rig']}: {info['title']} (paper {info['paper']})")
    for section in ("mechanics", "friction", "drive"):
        print(f"  [{section}]")
        for k, v in info[section].items():
            print(f"    {k:22s} {v}")
    print("  channels:")
    for k, c in info["channels"].items():
        print(f"    {k:12s} [{c['unit']}]  {c['instrument']}: {c['description']}")
    print("  seed effects: " + ", ".join(f"{k} {v}" for k, v in info["seed_effects"].items()))
    print("  applicable effects: " + ", ".join(info["applicable_effects"]))
    print("  linearised eigenfrequencies [Hz]:")
    for k, v in info["linear_modes_hz"].items():
        print(f"    {k:22s} " + ", ".join(f"{f:.3f}" for f in v))
    if info["rig"] == "brake-2dof":
        print("    (paper 001 prints 9.87/14.20 Hz; its printed equations give these values, see README)")
    return 0


# ----------------------------------------------------------------------------- sim


def cmd_sim(args: argparse.Namespace) -> int:
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
    with _progress(f"sim {cfg.rig}") as prog:
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


# ----------------------------------------------------------------------------- import / export


def cmd_import(args: argparse.Namespace) -> int:
    from daq.io.importer import import_file

    import_file(args.file, args.rig, args.output)
    print(f"imported {args.file} -> {args.output}", file=sys.stderr)
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from daq.io.importer import export_csv

    export_csv(args.file, args.output)
    print(f"exported {args.file} -> {args.output}", file=sys.stderr)
    return 0


# ----------------------------------------------------------------------------- bench


def cmd_bench(args: argparse.Namespace) -> int:
    from daq.bench import BENCHES, run_bench

    if args.name not in BENCHES:
        raise InputError("bench", args.name, f"unknown benchmark (have: {', '.join(BENCHES)})")
    result, report = run_bench(args.name)
    if args.json:
        _print_json(result)
    else:
        print(report)
    return 0


# ----------------------------------------------------------------------------- demo


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job: record a ramp through the daemon on a simulated rig, then compare, diagnose, add, compare."""
    from .demo import run_demo

    r = run_demo(args.out, hidden=args.hidden, ramp_s=args.ramp_seconds)
    added = ", ".join(r["added"]) or "nothing"
    line = (f"demo: report in {args.out}/ (summary.json, history.png, one folder per round); added {added}; "
            f"error {r['error_seed']:.3g} -> {r['error_final']:.3g} m (noise floor {r['noise_floor']:.3g} m)")
    print(line + f" in {r['seconds']:.0f} s")
    return 0


# ----------------------------------------------------------------------------- main


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="daq", description="Dry-friction rig acquisition, simulation and analysis")
    sub = ap.add_subparsers(dest="command", required=True)

    rig = sub.add_parser("rig", help="rig configurations")
    rsub = rig.add_subparsers(dest="rig_command", required=True)
    rsub.add_parser("list", help="list rigs").set_defaults(func=cmd_rig_list)
    show = rsub.add_parser("show", help="parameters, channels, eigenfrequencies")
    show.add_argument("rig")
    show.add_argument("--json", action="store_true")
    show.set_defaults(func=cmd_rig_show)

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

    imp = sub.add_parser("import", help="bring a CSV or LabVIEW TDMS file into the recording format")
    imp.add_argument("file")
    imp.add_argument("--rig", required=True)
    imp.add_argument("-o", "--output", required=True, help="OUT.h5")
    imp.set_defaults(func=cmd_import)

    exp = sub.add_parser("export", help="write a recording as interchange CSV")
    exp.add_argument("file")
    exp.add_argument("-o", "--output", required=True, help="OUT.csv")
    exp.set_defaults(func=cmd_export)

    bench = sub.add_parser("bench", help="run a benchmark against its same-run baseline")
    bench.add_argument("name")
    bench.add_argument("--json", action="store_true")
    bench.set_defaults(func=cmd_bench)

    from .analyses import register as register_analyses
    from .daemon import register as register_daemon
    from .models import register as register_models

    register_daemon(sub)
    register_models(sub)
    register_analyses(sub)

    demo = sub.add_parser("demo", help="the main job on simulated hardware")
    demo.add_argument("--out", default="out/demo", help="report folder")
    demo.add_argument("--hidden", default="accel-sign", help="hidden effect of the simulated rig")
    demo.add_argument("--ramp-seconds", type=float, default=20.0, help="the 45 s seed ramp time-scaled to this")
    demo.set_defaults(func=cmd_demo)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"daq: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("daq: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
