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
    from daq.models.spec import save_model, seed_model

    out = _out_path(args.output, ".toml")
    m = seed_model(args.rig)
    save_model(m, out)
    print(f"wrote {out}: {m.title}; effects: {', '.join(m.effects)}; free: {', '.join(m.free_names())}",
          file=sys.stderr)
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
    from daq.models.session import Session
    from daq.models.spec import load_model

    model = load_model(args.model)
    data = args.data
    if isinstance(data, list) and len(data) > 1:  # several recordings of one rig, judged together (issue 26)
        from daq.models.multi_session import MultiSession

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
    from daq.models.compare import OUTLIER_SIGMAS, compare
    from daq.models.figures import compare_figure, cycles_figure, spectrogram_figure
    from daq.models.spec import save_model

    model, s = _session(args)
    say(f"fitting {len(model.free_names())} free parameters")
    f = s.fit(model)
    say("noise floor: the fitted model scored on its own simulated output with the measured noise")
    floor = s.noise_floor(f)
    say("forward simulation and breakdowns")
    res, drawn = compare(s, f, floor)
    if args.report:
        rep = Path(args.report)
        rep.mkdir(parents=True, exist_ok=True)
        compare_figure(s, f, res, rep / "compare.png")
        spectrogram_figure(s, drawn, rep / "spectrogram.png")
        cycles_figure(s, res, drawn, rep / "cycles.png")
        (rep / "compare.json").write_text(dumps_json(res))
        save_model(f.model, rep / "fitted.toml")
        res["report"] = str(rep)
    if not args.no_history:
        _append_history(Path(args.history), res)
    if args.json:
        print_json(res)
    else:
        u = res["error_unit"]
        print(f"error {res['error']:.4g} {u} on held-out windows (noise floor {res['noise_floor']:.4g}; all windows "
              f"{res['error_all_windows']:.4g})"
              f"  model: {res['model']}")
        print("  by regime: " + "; ".join(f"{k} {v['error']:.3g}" for k, v in res["by_regime"].items()))
        print("  by signal: " + "; ".join(f"{k} {v['error']:.3g} {v['unit']} (floor {v['noise_floor']:.3g})"
                                          for k, v in res["by_signal"].items()))
        if res["clock_jitter_s"] > 0:
            print(f"  clock jitter {res['clock_jitter_s'] * 1e3:.3g} ms (samples taken early or late, read from the "
                  "residual's sample-to-sample part growing with speed): counted in the noise floor")
        far = {k: n for k, n in res["residual_outliers"].items() if n}
        if far:
            print(f"  beyond {OUTLIER_SIGMAS:g} noise levels of the model (spikes left, or where it fails): "
                  + ", ".join(f"{k} {n} samples" for k, n in far.items()))
        capped = {k: n for k, n in res["loss_capped"].items() if n}
        if capped:
            print(f"  {res['loss']} loss: counted linearly, not squared (beyond 3 x the window's residual scale): "
                  + ", ".join(f"{k} {n} samples" for k, n in capped.items()))
        print("  invariants (measured / model): " + "; ".join(
            f"{k} {v['measured']:.4g} / {v['model']:.4g}" for k, v in res["invariants"].items()))
        c = res["cycles"]
        print(f"  cycles (record / model free run, medians; {c['record']['cycles']} / {c['model']['cycles']} cycles): "
              f"stick {c['record']['stick_s_median']:.3g} / {c['model']['stick_s_median']:.3g} s "
              f"(at the peak load {c['record']['creep_s_median']:.3g} / {c['model']['creep_s_median']:.3g} s), "
              f"drop {c['record']['drop_median']:.3g} / {c['model']['drop_median']:.3g} {c['unit']}, "
              f"slip {c['record']['slip_s_median']:.3g} / {c['model']['slip_s_median']:.3g} s, "
              f"mean period {c['record']['period_s_mean']:.3g} / {c['model']['period_s_mean']:.3g} s")
        ld = c["loading"]
        print(f"  loading in the stick, early / late, over the drive's speed: record {ld['early_record']:.2f} / "
              f"{ld['late_record']:.2f}, model {ld['early_model']:.2f} / {ld['late_model']:.2f} (1: loaded as a "
              f"stuck slider is; lower late: it creeps before it slips)")
        if res["by_cycle_phase"]:
            print("  error by cycle phase (share of samples): " + ", ".join(
                f"{k} {v['error']:.3g} {res['error_unit']} ({v['fraction']:.0%})" for k, v in res["by_cycle_phase"].items()))
        mo = res["motion"]
        print(f"  ringing (strongest line within 2x of the rig's lowest natural frequency {mo['natural_Hz']:.3g} Hz, "
              f"mains masked): record {mo['line_Hz_record']:.3g} Hz, model {mo['line_Hz_model']:.3g} Hz with "
              f"{mo['band_power_model_over_record']:.2g} of the record's power there")
        print(f"  worst regime: {res['worst_regime']}" + (f"; report in {args.report}/" if args.report else ""))
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.models.diagnose import diagnose
    from daq.models.figures import diagnose_figure

    if args.workers is not None and args.workers < 1:  # checked before any work (issue 16: 0 and -3 were taken)
        raise InputError("--workers", "--workers", f"must be a whole number >= 1, got {args.workers}")
    model, s = _session(args)
    t0 = time.perf_counter()
    d = diagnose(s, model, progress=say, workers=args.workers)
    res = d.as_json(s)
    res["seconds"] = time.perf_counter() - t0
    if args.report:
        rep = Path(args.report)
        rep.mkdir(parents=True, exist_ok=True)
        if len(getattr(s, "parts", ())) > 1:
            say("several recordings: diagnose.json only (the figure is drawn for one recording)")
        else:
            diagnose_figure(s, d, rep / "diagnose.png")
        (rep / "diagnose.json").write_text(dumps_json(res))
        res["report"] = str(rep)
    if args.json:
        print_json(res)
    else:
        print(d.summary)
        print(f"  {'candidate':36s} {'reduction':>9s} {'z':>6s}  params")
        for c in res["candidates"]:
            if c["reduction"] is None:
                print(f"  {c['label']:36s} {'-':>9s} {'':6s}  (screened, predicted gain {c['predicted_gain']:.3g}; "
                      "not fitted)")
                continue
            print(f"  {c['label']:36s} {c['reduction']:9.2f} {c['consistency_z']:6.1f}  "
                  + ", ".join(f"{k.rsplit('.', 1)[-1]}={v:.4g}" for k, v in c["values"].items()))
        for step in res["sequence"]:
            print(f"  added: {step['label']} (removes {step['step_reduction']:.0%} of the excess left, "
                  f"z {step['consistency_z']:.1f})")
        for v in res["margins"]:
            print(f"  margin: {v['label']} " + ("named" if v["decided"] else "undecided") + "; " + ", ".join(
                f"over {m['rival']} {m['margin']:+.2f} of the excess (5 % bound {m['margin_lower']:+.2f})"
                for m in v["rivals"]))
        if res["missing_effect_found"]:
            print(f"  promised: {res['final_reduction']:.0%} of the excess, as `model add` + `compare` fit it "
                  f"(the diagnosis's own fit: {res['search_reduction']:.0%})")
        if not d.found and d.correlations:
            print("  residual correlates with: " + ", ".join(
                f"{c['quantity']} ({c['spearman_rho']:+.2f})" for c in d.correlations[:5]))
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
    p = msub.add_parser("init", help="write the seed model of a rig")
    p.add_argument("rig")
    p.add_argument("-o", "--output", required=True)
    p.set_defaults(func=cmd_model_init)
    for name, fn, hlp in (("add", cmd_model_add, "add a catalog effect (in one of its forms), a user effect "
                                                 "file.py, or free a mechanics parameter (mechanics.NAME)"),
                          ("remove", cmd_model_remove, "remove an effect")):
        p = msub.add_parser(name, help=hlp)
        p.add_argument("model")
        p.add_argument("effect")
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
