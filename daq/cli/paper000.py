"""Paper 000's analyses on the command line: ``daq analyse belt-law`` and ``daq analyse poincare``.

Why commands: the paper identifies its friction model from belt-ndof trajectories (the
kinetic branches f(w, sgn w'), the static limit f_s(t_s, delta), periodicity from a
Poincaré section); each is one command with JSON and figures (docs/analyses-000.md).
The analyses live in daq/analysis/paper000/.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from daq.errors import InputError
from daq.io.files import atomic_path
from daq.io.jsonout import print_json

from .output import say


def _runs(paths: list[str], rig_config: str | None, damping: float | None):
    # lazy: numpy, scipy, pydantic and h5py load only when the command runs (start-up time of daq --help)
    from daq.analysis.paper000.preparation import prepare
    from daq.io.interchange import read_recording

    runs = []
    for p in paths:
        if not Path(p).is_file():
            raise InputError(str(p), "(file)", "no such file")
        runs.append(prepare(read_recording(p), str(p), rig=rig_config, damping=damping))
    return runs


def _mass(args: argparse.Namespace, runs) -> int | None:
    if args.mass is None:
        return None
    n = max(r.n for r in runs)
    if not 1 <= args.mass <= n:
        raise InputError("--mass", "mass", f"{args.mass} is not a mass of the recording(s) (1..{n})")
    return args.mass - 1


def _write_json(path: Path, obj) -> None:
    """The result model as pydantic writes it (NaN and inf as null), atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(obj.model_dump_json(indent=2))


def _report(report: str, res, json_name: str, figures: dict) -> None:
    """The --report directory: each figure (name -> draw(path)), then the result's JSON; one line saying so."""
    rep = Path(report)
    rep.mkdir(parents=True, exist_ok=True)
    for name, draw in figures.items():
        draw(rep / name)
    _write_json(rep / json_name, res)
    say("wrote " + ", ".join(str(rep / name) for name in [*figures, json_name]))


def cmd_belt_law(args: argparse.Namespace) -> int:
    # lazy: the analysis (numpy, scipy, the compiled physics) loads only when the command runs
    from daq.analysis.paper000.belt_law import belt_law
    from daq.analysis.paper000.equation_error import LAW

    if args.damping is not None and not args.damping >= 0:  # also refuses nan
        raise InputError("--damping", "d", "must be >= 0")
    if args.windows < 2:
        raise InputError("--windows", "windows", "must be >= 2")
    runs = _runs(args.data, args.rig_config, args.damping)
    m = _mass(args, runs)
    print(f"analyse belt-law: {len(runs)} recording(s), d = {runs[0].mech.d:g} ({runs[0].mech.config_source})",
          file=sys.stderr)
    a = belt_law(runs, masses=None if m is None else [m], windows_per_mass=args.windows, progress=say)
    res = a.result
    if args.report:
        # lazy: matplotlib only when figures are asked for
        from daq.analysis.paper000.figures import belt_law_figure, belt_static_figure

        _report(args.report, res, "belt-law.json", {"belt-law.png": lambda p: belt_law_figure(res, p),
                                                     "belt-static.png": lambda p: belt_static_figure(res, p)})
    if args.json:
        print_json(json.loads(res.model_dump_json()))
        return 0
    print(f"{len(res.recordings)} recording(s): " + ", ".join(
        f"{Path(r.path).name} (s = {r.belt_speed_s:.3f}, {r.windows} windows)" for r in res.recordings))
    print(f"kinetic law (output error, rms {res.law_rms_noise_units:.3g} noise units over "
          f"{res.windows_in_law_fit} windows):")
    for k in LAW:
        e, q = res.law[k], res.equation_error[k]
        print(f"  {k:11s} {e.value:9.4f} +- {e.std:.2g}    (equation error, the paper's least squares: "
              f"{q.value:.4f})")
    if res.static:
        print(f"static limit ({len(res.episodes)} break-aways, rms {res.static_rms:.3g}; "
              f"q0 = {res.force_rate_q0_N_per_s:g} N/s fixed):")
        for k, e in res.static.items():
            print(f"  {k:17s} {e.value:9.4f} +- {e.std:.2g}")
    for wmsg in res.warnings:
        print(f"  warning: {wmsg}")
    return 0


def cmd_poincare(args: argparse.Namespace) -> int:
    # lazy: the analysis (numpy, scipy) loads only when the command runs
    from daq.analysis.paper000.poincare import poincare

    if args.skip is not None and not args.skip >= 0:
        raise InputError("--skip", "skip", "must be >= 0 s")
    if not 1 <= args.kmax <= 64:
        raise InputError("--kmax", "kmax", "must be in 1..64")
    run = _runs([args.data], args.rig_config, None)[0]
    m = _mass(args, [run])
    if args.skip is not None and args.skip >= 0.9 * (run.t[-1] - run.t[0]):
        raise InputError("--skip", "skip", f"{args.skip:g} s leaves (almost) nothing of the "
                                           f"{run.t[-1] - run.t[0]:.3g} s record")
    a = poincare(run, 0 if m is None else m, skip_s=args.skip, kmax=args.kmax)
    res = a.result
    if args.report:
        # lazy: matplotlib only when figures are asked for
        from daq.analysis.paper000.figures import poincare_figure

        _report(args.report, res, "poincare.json", {"poincare.png": lambda p: poincare_figure(a, p)})
    if args.json:
        print_json(json.loads(res.model_dump_json()))
        return 0
    per = f", period {res.period_s:.4f} s" if res.period_s else ""
    print(f"{res.path}: {res.n_masses} mass(es), s = {res.belt_speed_s:.3f}; section on mass {res.mass}: "
          f"{res.classification}{per}")
    print(f"  {res.points_steady} steady section points ({res.points_total} in all, first {res.skip_s:.3g} s "
          f"skipped), {res.distinct_points} distinct at tolerance {res.tolerance:.3g}")
    print("  d_k (90 % of |P[n+k] - P[n]|, scaled): " + ", ".join(
        f"{k}: {v:.3g}" for k, v in res.distance_by_k.items()))
    return 0


def register(sub: argparse._SubParsersAction, analyse: argparse._SubParsersAction) -> None:
    """Add this paper's commands: under ``daq analyse`` (analyse) or at the top level (sub)."""
    p = analyse.add_parser("belt-law", help="paper 000: identify the friction law (kinetic branches, break-away "
                                            "drop, static limit vs stick time and force rate) from belt-ndof runs")
    p.add_argument("data", nargs="+", help="recordings (.h5 or .csv with t, x1[, x2, x3], vb[, vb_set]), ideally "
                                           "at several constant belt speeds")
    p.add_argument("--mass", type=int, help="identify from this mass only (1-based; default: every mass)")
    p.add_argument("--rig-config", metavar="TOML", help="rig config (default: stored in the recording, else "
                                                        "rig_configs/belt-ndof.toml)")
    p.add_argument("--damping", type=float, metavar="D", help="dimensionless damping d (default: the rig "
                                                               "config's viscous-damping d)")
    p.add_argument("--windows", type=int, default=6, metavar="N",
                   help="slip windows per recording and mass in the law fit (default 6)")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.add_argument("--report", metavar="DIR", help="write belt-law.png (Figs. 9-10), belt-static.png (Fig. 11) "
                                                   "and belt-law.json here")
    p.set_defaults(func=cmd_belt_law)

    p = analyse.add_parser("poincare", help="paper 000: Poincaré section, period-k / irregular, limit cycle of "
                                            "a belt-ndof run")
    p.add_argument("data", help="recording (.h5 or .csv with t, x1[, x2, x3], vb)")
    p.add_argument("--mass", type=int, help="mass whose velocity defines the section (1-based, default 1)")
    p.add_argument("--skip", type=float, metavar="S", help="transient left out [s] (default: the first 40 %% of the record)")
    p.add_argument("--kmax", type=int, default=8, help="largest period tested (default 8)")
    p.add_argument("--rig-config", metavar="TOML", help="rig config (default: stored in the recording, else "
                                                        "rig_configs/belt-ndof.toml)")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.add_argument("--report", metavar="DIR", help="write poincare.png and poincare.json here")
    p.set_defaults(func=cmd_poincare)
