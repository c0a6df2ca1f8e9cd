"""``daq model``, ``daq fit``, ``daq compare``, ``daq diagnose``, ``daq history``: models against measurements.

Heavy modules are imported inside the command functions (marked ``# heavy``): `daq --help`
imports every cli module and must stay fast.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import sys
import time
from pathlib import Path

from daq.errors import InputError
from daq.io.jsonout import dumps_json, print_json

from .docs import EffectsHelp
from .output import say

HISTORY = "daq-history.jsonl"


def _out_path(p: str, suffix: str, flag: str = "-o") -> Path:
    out = Path(p)
    if out.suffix.lower() != suffix:
        raise InputError(str(out), flag, f"must end in {suffix}")
    return out


# ----------------------------------------------------------------------------- model files


def cmd_model_init(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.models.spec import like_model, load_model, save_model, seed_model

    out = _out_path(args.output, ".toml")
    said: list[str] = []
    if args.like:
        m, said = like_model(load_model(args.like), args.rig, f"{args.like}: --like")
    else:
        m = seed_model(args.rig)
    save_model(m, out)
    print(f"wrote {out}: {m.title}; effects: {', '.join(m.effects)}; free: {', '.join(m.free_names())}",
          file=sys.stderr)
    for line in said:  # a mechanics correction carried from the model's own rig
        print(f"  {line}", file=sys.stderr)
    return 0


def cmd_model_add(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.models.candidates import MECHANICS, free_mechanics
    from daq.models.spec import add_effect, load_model, save_model

    m = load_model(args.model)
    if args.effect.startswith("mechanics."):  # a rig that is not its config: set one of its parameters free
        key = args.effect.split(".", 1)[1]
        if key not in MECHANICS.get(m.rig, ()):
            raise InputError(f"model add {args.effect}", args.effect,
                             f"not a mechanics parameter a fit may free on {m.rig} (has: "
                             f"{', '.join('mechanics.' + k for k in MECHANICS.get(m.rig, ())) or 'none'})")
        new = free_mechanics(m, key, f"model add {args.effect}")
        out = Path(args.output or args.model)
        save_model(new, out)
        print(f"wrote {out}: {args.effect} free", file=sys.stderr)
        return 0
    path = args.effect if args.effect.endswith(".py") else None
    name = Path(path).stem if path else args.effect
    if path and not Path(path).is_file():
        raise InputError(path, "path", "user effect file not found")
    new = add_effect(m, name, f"model add {args.effect}", path=str(Path(path).resolve()) if path else None,
                     form=args.form)
    out = Path(args.output or args.model)
    save_model(new, out)
    added = [k for k in new.free_names() if k not in m.params()]
    print(f"wrote {out}: + {name} (free: {', '.join(added) or 'none'})", file=sys.stderr)
    return 0


def cmd_model_remove(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.models.spec import load_model, remove_effect, save_model

    m = load_model(args.model)
    new = remove_effect(m, args.effect)
    out = Path(args.output or args.model)
    save_model(new, out)
    print(f"wrote {out}: - {args.effect}", file=sys.stderr)
    return 0


# ----------------------------------------------------------------------------- analyses


def _session(args: argparse.Namespace):
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.models.fit.session import Session
    from daq.models.spec import load_model

    model = load_model(args.model)
    data = args.data
    if isinstance(data, list) and len(data) > 1:  # several recordings of one rig, judged together (issue 26)
        from daq.models.fit.multi_session import MultiSession

        s = MultiSession.open(data, model, args.rig, loss=args.loss)  # every file loaded before the first line
        print(f"{args.command}: {' + '.join(data)} against {model.describe()}", file=sys.stderr)
        for p in s.parts:
            say(f"{p.source}: {p.m.n} samples at {p.m.rate:g} Hz; {p.win.starts.size} windows "
                f"({int(p.win.held_out.sum())} held out); noise " + ", ".join(f"{k} {v:.3g}" for k, v in p.m.sigma.items()))
        say(f"{s.win.starts.size} windows of {(s.win.length - 1) / s.m.rate:.3f} s in all, one model for every record")
        return model, s
    if isinstance(data, list):
        data = args.data = data[0]
    s = Session.open(data, model, args.rig, loss=args.loss)  # before the first progress line: a bad file is one line
    print(f"{args.command}: {args.data} against {model.describe()}", file=sys.stderr)
    filled = s.rec.meta.get("filled")
    if filled:
        by_count: dict[int, list[str]] = {}
        for name, n in filled.items():
            by_count.setdefault(n, []).append(name)
        say("filled in by interpolation where the recording has no data: "
            + "; ".join(f"{n} samples of {', '.join(names)}" for n, names in by_count.items()))
    if s.m.outliers:
        say("spikes repaired (single samples and bursts of up to 3; the cubic through the samples beside them): "
            + ", ".join(f"{k} {v.size}" for k, v in s.m.outliers.items()))
    if s.m.averaged > 1:
        say(f"the file's {s.m.rate * s.m.averaged:g} Hz samples compared as block means of {s.m.averaged} (one per "
            f"model step of {1e3 / s.m.rate:.3g} ms: finer samples add nothing the model resolves)")
    say(f"{s.m.n} samples at {s.m.rate:g} Hz; {s.win.starts.size} windows of {(s.win.length - 1) / s.m.rate:.3f} s "
         f"({int(s.win.held_out.sum())} held out); drive: {s.m.command_source}")
    return model, s


def cmd_fit(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.models.spec import FitInfo, save_model

    out = _out_path(args.output, ".toml")
    model, s = _session(args)
    t0 = time.perf_counter()
    say(f"fitting {len(model.free_names())} free parameters")
    f = s.fit(model)
    err = f.rms(s.primary)
    fitted = f.model.model_copy(update={"fit": FitInfo(data=str(args.data), error=err, error_unit=s.m.units[s.primary],
                                                      cost=f.fit.cost)})
    save_model(fitted, out)
    res = {"model": str(out), "error": err, "error_unit": s.m.units[s.primary], "error_all_windows": f.rms(s.primary, "all"),
           "parameters": {k: {"value": f.values[k], "std": f.fit.std.get(k)} for k in model.free_names()},
           "seconds": time.perf_counter() - t0, "converged": f.fit.success, "message": f.fit.message}
    if args.json:
        print_json(res)
    else:
        for k, d in res["parameters"].items():
            print(f"  {k:42s} {d['value']:.6g} +- {d['std'] if d['std'] is not None else float('nan'):.2g}")
        print(f"error {err:.4g} {res['error_unit']} on held-out windows (all windows {res['error_all_windows']:.4g}); "
              f"wrote {out}")
    return 0


def _append_history(path: Path, res: dict) -> None:
    entry = {k: res[k] for k in ("data", "model", "model_digest", "error", "error_unit", "noise_floor",
                                 "error_all_windows")}
    entry["time"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    entry["data"] = str(Path(res["data"]).resolve())
    with open(path, "a") as fh:
        fh.write(dumps_json(entry, indent=None) + "\n")


def cmd_compare(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.api.loop import compared

    model, s = _session(args)
    c = compared(s, model, report=args.report, predict=args.predict, progress=say)  # daq.compare's own path
    if not args.no_history:
        _append_history(Path(args.history), c.json)
    if args.json:
        print_json(c.json)
    else:
        print(c.text)
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.api.loop import diagnosed

    if args.workers is not None and args.workers < 1:  # checked before any work (issue 16: 0 and -3 were taken)
        raise InputError("--workers", "--workers", f"must be a whole number >= 1, got {args.workers}")
    model, s = _session(args)
    d = diagnosed(s, model, workers=args.workers, report=args.report, progress=say)  # daq.diagnose's own path
    if args.json:
        print_json(d.json)
    else:
        print(d.text)
    return 0


def cmd_history(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.models.figures import history_figure

    path = Path(args.history)
    if not path.is_file():
        raise InputError(str(path), "(file)", "no history yet (run daq compare first)")
    entries = []
    for n, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            entries.append(json.loads(line))
        except json.JSONDecodeError as exc:
            raise InputError(str(path), f"line {n}", f"not JSON: {exc.msg}") from None
    if args.data:
        want = str(Path(args.data).resolve())
        entries = [e for e in entries if e.get("data") == want]
    out = _out_path(args.output, ".png")
    history_figure(entries, out)
    for e in entries:
        print(f"{e['time']}  {Path(e['data']).name:24s} {e['error']:.4g} {e['error_unit']} "
              f"(floor {e['noise_floor']:.3g})  {e['model']}")
    print(f"wrote {out}", file=sys.stderr)
    return 0


# ----------------------------------------------------------------------------- parser


def register(sub: argparse._SubParsersAction) -> None:
    model = sub.add_parser("model", help="model files: init, add, remove")
    msub = model.add_subparsers(dest="model_command", required=True)
    p = msub.add_parser("init", help="write the baseline model of a rig: its paper's equations, the law partly free")
    p.add_argument("rig", help="a rig id or a user's rig file")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--like", metavar="MODEL.toml",
                   help="keep this model's effects, forms and fitted friction and effect values and take the mechanics "
                        "RIG's file states (a mechanics value the model holds off its own rig file carries as a ratio)")
    p.set_defaults(func=cmd_model_init)
    for name, fn, hlp in (("add", cmd_model_add, "add a catalog effect (in one of its forms), a user effect "
                                                 "file.py, or free a mechanics parameter (mechanics.NAME)"),
                          ("remove", cmd_model_remove, "remove an effect")):
        # add's help ends with the catalog, built only when asked for (the catalog loads numpy: `daq --help` must not)
        p = msub.add_parser(name, help=hlp, add_help=name != "add")
        if name == "add":
            p.add_argument("-h", "--help", action=EffectsHelp, help="show this help and the catalog's effects, and exit")
        p.add_argument("model")
        p.add_argument("effect", help="EFFECT (listed below), a user effect FILE.py, or mechanics.NAME"
                       if name == "add" else "an effect the model has")
        p.add_argument("-o", "--output", help="write here instead of changing MODEL in place")
        if name == "add":
            p.add_argument("--form", help="one of the effect's forms (as diagnose names it; default: its first)")
        p.set_defaults(func=fn)

    def common(p: argparse.ArgumentParser, several: bool = False) -> None:
        if several:
            p.add_argument("data", nargs="+", help="recordings (.h5) or interchange CSV/TDMS of one rig: one model, "
                                                   "shared parameters, each record its own windows and noise")
        else:
            p.add_argument("data", help="recording (.h5) or interchange CSV/TDMS")
        p.add_argument("--model", required=True, help="model TOML")
        p.add_argument("--rig", help="rig of a CSV/TDMS file (default: the model's)")
        p.add_argument("--json", action="store_true")
        p.add_argument("--loss", choices=("huber", "squares"), default="huber",
                       help="of every fit: Huber's on the noise-scaled residual (default; a few bad samples cannot "
                            "pull the fit) or plain least squares")

    p = sub.add_parser("fit", help="fit a model's free parameters (multiple shooting)")
    common(p)
    p.add_argument("-o", "--output", required=True, help="FITTED.toml")
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser("compare", help="model vs measurement: error, noise floor, where it fails")
    common(p)
    p.add_argument("--report", help="folder for figures and JSON")
    p.add_argument("--history", default=HISTORY, help=f"history file to append to (default ./{HISTORY})")
    p.add_argument("--no-history", action="store_true")
    p.add_argument("--predict", action="store_true",
                   help="score the model as its file states it: nothing fitted but each window's start state (does a "
                        "model found on one record, or carried by `model init --like`, predict this one?)")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("diagnose", help="which catalog effect is the model missing?")
    common(p, several=True)
    p.add_argument("--report", help="folder for figures and JSON")
    p.add_argument("--workers", type=int, help="processes for the candidate fits (default: all cores)")
    p.set_defaults(func=cmd_diagnose)

    p = sub.add_parser("history", help="plot the error across model revisions")
    p.add_argument("--history", default=HISTORY)
    p.add_argument("--data", help="only this data file")
    p.add_argument("-o", "--output", default="history.png")
    p.set_defaults(func=cmd_history)
