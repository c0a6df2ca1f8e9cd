"""Paper 001's analyses on the command line: ``daq analyse brake-run DATA``.

Why a command: the paper's spectrograms, phase/configuration planes, effective friction (eq. 10)
with a fit of law (7), and the regime transitions of its section 5 are what a researcher looks at
after a brake-2dof deceleration run; one command gives them as JSON and figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from daq.errors import InputError, parse_toml
from daq.io.jsonout import print_json

from .output import say


def _planes(text: str | None) -> list[tuple[float, float]] | None:
    """``A:B,C:D`` as [(A, B), (C, D)]; an InputError names the bad item."""
    if text is None:
        return None
    out = []
    for item in text.split(","):
        a, sep, b = item.strip().partition(":")
        try:
            lo, hi = float(a), float(b)
        except ValueError:
            raise InputError("--planes", item.strip() or "(empty)", "expected START:END in seconds") from None
        if not sep or not hi > lo:
            raise InputError("--planes", item.strip(), "expected START:END with END > START")
        out.append((lo, hi))
    return out


def _config(args: argparse.Namespace, rec) -> tuple[object, str]:
    """The rig config: --rig-config, else the one stored with the recording, else rig_configs/brake-2dof."""
    # lazy: pydantic and the config models load only when the command runs (start-up time of daq --help)
    from daq.config import load_rig, parse_rig

    if args.rig_config:
        return load_rig(args.rig_config), str(args.rig_config)
    text = rec.meta.get("rig_config") if isinstance(rec.meta, dict) else None
    if isinstance(text, str) and text.strip():
        src = f"{args.data} (stored rig_config)"
        return parse_rig(parse_toml(text, src), src), src
    return load_rig("brake-2dof"), "rig_configs/brake-2dof.toml"


def cmd_brake_run(args: argparse.Namespace) -> int:
    # lazy: numpy, scipy, matplotlib and h5py load only when the command runs (start-up time of daq --help)
    from daq.analysis.paper001.analysis import analyse_run
    from daq.analysis.paper001.figures import FIGURES
    from daq.analysis.paper001.transitions import TransitionCfg
    from daq.io.files import atomic_path
    from daq.io.interchange import read_recording
    from daq.io.plausible import check_recording

    if not Path(args.data).is_file():
        raise InputError(str(args.data), "(file)", "no such file")
    if not args.window > 0:
        raise InputError("--window", "window", "must be > 0")
    planes = _planes(args.planes)
    rec = read_recording(args.data)
    if rec.rig not in (None, "", "brake-2dof"):
        raise InputError(str(args.data), "rig", f"is {rec.rig!r}; brake-run analyses brake-2dof recordings")
    cfg, cfg_src = _config(args, rec)
    check_recording(str(args.data), rec, cfg)
    print(f"analyse brake-run: {args.data} ({rec.t.size} samples, config {cfg_src})", file=sys.stderr)
    res, ctx = analyse_run(rec.t, rec.channels, cfg, str(args.data), config_source=cfg_src,
                           plane_window_s=args.window, planes=planes, diff_window_s=args.diff_window,
                           tcfg=TransitionCfg(), paper_marks=args.paper_marks, say=say)
    if args.report:
        rep = Path(args.report)
        rep.mkdir(parents=True, exist_ok=True)
        for name, fn in FIGURES.items():
            say(f"figure {rep / name}")
            fn(res, ctx, rep / name)
            res.figures.append(str(rep / name))
        with atomic_path(rep / "brake-run.json") as tmp:
            tmp.write_text(res.model_dump_json(indent=2))
    if args.json:
        print_json(json.loads(res.model_dump_json()))
        return 0
    f = res.friction
    print(f"{res.data}: {res.duration_s:.1f} s at {res.rate_hz:g} Hz; belt V0 = {res.belt_V0_m_per_s:.4f} m/s, "
          f"Tmax = {res.belt_Tmax_s:.1f} s")
    print(f"  law (7) on mu = F/N: mu0 = {f.fit.params['mu0'].value:.4f} +- {f.fit.params['mu0'].std:.4f}, "
          f"gamma = {f.fit.params['gamma'].value:.3f} +- {f.fit.params['gamma'].std:.3f} s/m "
          f"(alpha = {f.fit.held['alpha']:g}, beta = {f.fit.held['beta']:g} held; {f.fit.n_points} samples, "
          f"rms {f.fit.rms:.4f})")
    print(f"  transition bias: slip samples within {f.exclusion_s * 1e3:.1f} ms of the {f.n_transitions} "
          f"transitions left out ({f.differentiator})")
    e = f.fit_eq10.params
    print(f"  through eq. (10) on F/(m g): mu0 = {e['mu0'].value:.4f}, gamma = {e['gamma'].value:.3f} "
          f"(kappa1 = {f.kappa1:.3f}, kappa2 = {f.kappa2:.4f})")
    lines = res.spectrogram.line_hz
    print(f"  spectral line of x1: {lines[0]:.2f} Hz at the start, {lines[len(lines) // 2]:.2f} Hz mid-run; "
          f"linearised modes {', '.join(f'{m:.2f}' for m in res.spectrogram.modes_hz)} Hz")
    print(f"  segments ({res.transitions.n_cycles} cycles):")
    for s in res.transitions.segments:
        extra = f", period {s.period_s * 1e3:.0f} ms" if s.period_s else ""
        extra += f", bandwidth x{s.bandwidth_ratio:.1f}" if s.bandwidth_ratio is not None else ""
        print(f"    {s.start_s:8.2f} - {s.end_s:8.2f} s  {s.track:8s} {s.kind}{extra}")
    if res.paper_160:
        print("  against the paper's 160 s run:")
        for m in res.paper_160:
            print(f"    {m.start_s:5.0f} - {m.end_s:5.0f} s  paper: {m.paper}; here: {', '.join(m.found)}")
    if args.report:
        print(f"  report in {args.report}/")
    return 0


def register(sub: argparse._SubParsersAction, analyse: argparse._SubParsersAction) -> None:
    """Add this paper's commands: under ``daq analyse`` (analyse) or at the top level (sub)."""
    p = analyse.add_parser("brake-run", help="paper 001: spectrograms, phase planes, eq. (10) friction and "
                                             "law (7) fit, regime transitions of a brake-2dof run")
    p.add_argument("data", help="recording (.h5 from the recorder or daq sim, or .csv with t, x1, phi, vb)")
    p.add_argument("--window", type=float, default=2.0, metavar="S",
                   help="length of the phase/configuration-plane windows [s] (default 2, as the paper's Fig. 11)")
    p.add_argument("--planes", metavar="A:B,...", help="explicit plane windows in seconds (default: 6 spread "
                                                        "over the run; with --paper-marks the paper's Fig. 11)")
    p.add_argument("--diff-window", type=float, default=0.02, metavar="S",
                   help="differentiator window for x1', x1'' [s] (default 0.02; below 11 samples: spline)")
    p.add_argument("--rig-config", metavar="TOML", help="rig config (default: stored in the recording, "
                                                         "else rig_configs/brake-2dof.toml)")
    p.add_argument("--paper-marks", action="store_true",
                   help="compare with the paper's V0 = 0.25 m/s, Tmax = 160 s segments (Fig. 8) and use its "
                        "Fig. 11 plane windows")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.add_argument("--report", metavar="DIR", help="write spectrogram/planes/friction/transitions PNGs and "
                                                   "brake-run.json here")
    p.set_defaults(func=cmd_brake_run)
