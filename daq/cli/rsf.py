"""``daq analyse rsf RUN.h5 [RUN2.h5 ...]``: rate-and-state reduction of velocity steps and slide-hold-slide.

One command for one recording or a lab's batch: every event of every file, a table (CSV and JSON, one row per
event, each law's a, b, a - b, Dc, k' with standard errors), figures (friction against load-point displacement
with the fits, residuals; healing against log hold time), progress per file. The reduction lives in
daq/analysis/rsf/ (docs/rate-and-state.md).
"""

from __future__ import annotations

import argparse
import csv
import math
import os
from pathlib import Path

from daq.errors import InputError
from daq.io.files import atomic_path
from daq.io.jsonout import print_json

from .output import say


def _write_csv(path: Path, rows: list[dict]) -> None:
    cols: list[str] = []
    for r in rows:
        cols += [c for c in r if c not in cols]
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=cols)
            w.writeheader()
            for r in rows:
                w.writerow(r)


def _fmt(e) -> str:
    return f"{e.value:.4g} +- {e.se:.2g}" if math.isfinite(e.se) else f"{e.value:.4g} (se undetermined)"


def cmd_rsf(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba load when the command runs (start-up time of daq --help)
    from daq.analysis.rsf.analysis import analyse_rsf, table_rows

    if args.workers is not None and args.workers < 1:
        raise InputError("--workers", "workers", f"{args.workers}: at least 1")
    laws = tuple(args.law) if args.law else ("aging", "slip")
    from daq.analysis.rsf.figures import MAX_FILES_DRAWN

    res, curves = analyse_rsf(args.data, rig=args.rig, laws=laws, fixed_stiffness=args.fixed_stiffness,
                              workers=args.workers or os.cpu_count() or 1,
                              keep_curves=MAX_FILES_DRAWN if args.report else 0,
                              on_file=lambda k, n, what: say(f"file {k}/{n}: {what}"))
    if args.report:
        from daq.analysis.rsf.figures import figures

        rep = Path(args.report)
        rep.mkdir(parents=True, exist_ok=True)
        res.figures = [str(p) for p in figures(res.files, curves, rep)]
        rows = table_rows(res)
        _write_csv(rep / "rsf.csv", rows)
        with atomic_path(rep / "rsf.json") as tmp:
            tmp.write_text(res.model_dump_json(indent=2))
        say(f"wrote {rep / 'rsf.json'}, {rep / 'rsf.csv'} ({len(rows)} events), {len(res.figures)} figures")
    if args.json:
        print_json(res.model_dump(mode="json"))
        return 0
    for f in res.files:
        print(f"{f.data}: {len(f.events)} events, {f.rate_Hz:.4g} Hz, rig k/N = {f.k_rig_per_m:.4g} /m")
        for ev in f.events:
            what = (f"step {1e6 * ev.v1_m_per_s:.4g} -> {1e6 * ev.v2_m_per_s:.4g} um/s" if ev.kind == "step"
                    else f"hold {ev.hold_s:.4g} s at {1e6 * ev.v1_m_per_s:.4g} um/s")
            print(f"  #{ev.index} {what} at {1e6 * ev.load_point_m:.1f} um: peak {ev.peak_change:+.4g}, "
                  f"steady {ev.steady_change:+.4g}; law: {ev.law} (margin {ev.law_margin:.3g})")
            for law, fit in ev.fits.items():
                print(f"     {law:5s} a = {_fmt(fit.a)}  b = {_fmt(fit.b)}  a-b = {_fmt(fit.a_minus_b)}  "
                      f"Dc = {_fmt(fit.Dc_m)} m  k' = {_fmt(fit.k_per_m)} /m  sigma {fit.sigma:.3g}"
                      + ("" if fit.ok else "  (fit failed)"))
        if f.healing is not None:
            print(f"  healing over {f.healing.n} holds: beta = {_fmt(f.healing.beta)} per decade of hold time")
    print(f"{sum(len(f.events) for f in res.files)} events in {res.seconds:.2f} s "
          f"({1e3 * res.seconds_per_event:.1f} ms per event)")
    return 0


def register(analyse: argparse._SubParsersAction) -> None:
    p = analyse.add_parser("rsf", help="rate-and-state: a, b, Dc, stiffness per velocity step / slide-hold-slide")
    p.add_argument("data", nargs="+", help="recordings (.h5, or CSV with t, x1, vb[, vb_set]) of a one-mass "
                                           "belt-ndof rig: a spring-slider or a press imported with --map")
    p.add_argument("--rig", help="rig id or config TOML (default: the config stored in the recording)")
    p.add_argument("--law", action="append", choices=("aging", "slip"),
                   help="state law to fit (repeat for both; default both, and which one each event favours)")
    p.add_argument("--fixed-stiffness", action="store_true",
                   help="take the machine stiffness from the rig file (k / N) instead of fitting it")
    p.add_argument("--workers", type=int, help="processes sharing the files (default: this machine's cores)")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.add_argument("--report", help="folder for rsf.json, rsf.csv and the figures (the first 12 files drawn)")
    p.set_defaults(func=cmd_rsf)
