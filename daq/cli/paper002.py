"""Paper 002 (drum-pendulum) on the command line: ``daq analyse drum-mu``, and it registers ``daq campaign drum``.

Why together: the identification of paper 002 (mu(t) by eq. (2), law (3) fitted) and the campaign that
runs it over a grid of thrusts and drum speeds through the daemon are one story; both print one
JSON object with --json and write figures with the same JSON to --report / --out. The campaign's
options and command live in daq/cli/campaign.py; this module adds it next to drum-mu.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from daq.io.files import atomic_path
from daq.io.jsonout import print_json

from .campaign import register as register_campaign


def cmd_drum_mu(args: argparse.Namespace) -> int:
    # heavy: imported when the command runs (start-up time of daq --help)
    from daq.analysis.paper002.analysis import analyse_drum_mu
    from daq.analysis.paper002.figures import figures
    from daq.analysis.paper002.kinematics import GUARD_S, V_MIN

    res, series = analyse_drum_mu(args.data, rig=args.rig, v_min=V_MIN if args.v_min is None else args.v_min,
                                  guard_s=GUARD_S if args.guard is None else args.guard, mu1=args.mu1,
                                  t_from=args.t_from, t_to=args.t_to)
    if args.report:
        rep = Path(args.report)
        paths = figures(res, series, rep)
        res.figures = [str(p) for p in paths]
        with atomic_path(rep / "drum-mu.json") as tmp:
            tmp.write_text(res.model_dump_json(indent=2))
    out = res.model_dump(mode="json")
    if args.json:
        print_json(out)
    else:
        f = res.fit
        lo, hi = f.v_range_m_per_s
        print(f"law (3) on {f.n} samples (|v_wz| {lo * 1e3:.1f}-{hi * 1e3:.1f} mm/s), "
              f"P = {res.thrust_N['mean']:.2f} N:")
        for k, c in f.coefficients.items():
            flag = "" if c.identified else "   (not identified: se > 25 %)"
            print(f"  {k} = {c.value:.5g} +- {c.se if c.se is not None else float('nan'):.2g} {c.unit}{flag}")
        print(f"  R^2 = {f.R2:.4f} (R = {f.R:.4f}), rms {f.rms:.2g}, effective samples {f.n_eff:.0f}"
              + (f"; report in {args.report}/" if args.report else ""))
    return 0


def register(sub: argparse._SubParsersAction, analyse: argparse._SubParsersAction) -> None:
    """Add this paper's commands: under ``daq analyse`` (analyse) or at the top level (sub)."""
    p = analyse.add_parser("drum-mu", help="paper 002: mu(t) by eq. (2), law (3) A-E fitted (drum-pendulum)")
    p.add_argument("data", help="recording (.h5) or interchange CSV/TDMS of the drum-pendulum rig")
    p.add_argument("--rig", help="rig id or config TOML (default: the config stored in the recording)")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.add_argument("--report", help="folder for mu_t.png, mu_v.png, residuals.png and drum-mu.json")
    p.add_argument("--v-min", type=float, help="slowest sliding speed fitted [m/s] (default 0.003; docs/campaign.md)")
    p.add_argument("--guard", type=float, help="samples this close [s] to a slower one are left out (default 0.015)")
    p.add_argument("--mu1", type=float, default=0.0,
                   help="bearing friction coefficient mu1 of eq. (2) (default 0: the seed model has none)")
    p.add_argument("--from", dest="t_from", type=float, help="analyse from this time [s]")
    p.add_argument("--to", dest="t_to", type=float, help="... to this time [s]")
    p.set_defaults(func=cmd_drum_mu)
    register_campaign(sub)
