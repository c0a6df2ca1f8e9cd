"""``daq propose``: the drive programme that would decide between rival explanations of a record (issue 26).

Heavy modules are imported inside the command function: `daq --help` imports every cli module and must stay fast.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from daq.errors import InputError
from daq.io.jsonout import print_json

from .output import say


def cmd_propose(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.models import design
    from daq.models.candidates import candidates_for, parse_candidate
    from daq.models.figures import proposal_figure
    from daq.models.programmes import Programme, write_programme
    from daq.models.session import Session
    from daq.models.spec import load_model

    out = Path(args.output)
    if out.suffix.lower() != ".toml":
        raise InputError(str(out), "-o", "must end in .toml (a ramp file the daemon runs)")
    if not args.budget > 0:
        raise InputError("--budget", "--budget", f"{args.budget:g} s: must be > 0")
    model = load_model(args.model)
    known = {c.label: c for c in candidates_for(model)}
    rivals = []
    for text in args.rival:
        c = parse_candidate(text)
        if c.label not in known:
            raise InputError("--rival", "--rival", f"{text!r} is not a candidate of this model (one of: "
                                                   f"{', '.join(sorted(known))})")
        rivals.append(c)
    s = Session.open(args.data, model, args.rig)  # before the first progress line: a bad file is one line
    print(f"propose: {args.data} against {model.describe()}; rivals: {design.NOTHING}, "
          f"{', '.join(c.label for c in rivals)}", file=sys.stderr)
    v0 = design.drive_speed(s)
    max_run = args.max_run_s or min(60.0, float(s.m.t[-1] - s.m.t[0]))
    rs = design.rivals_for(s, model, rivals, say)
    for r in rs:
        say(f"{r.label}: {r.error(s):.4g} {s.m.units[s.primary]} on the record"
            + (f" ({r.fixed} held at a generic strength: the record cannot tell it from nothing)" if r.fixed else ""))
    prop = design.propose(s, rs, args.budget, max_run, v0, say)
    best: Programme = prop.best.programme
    write_programme(best, out)
    result = design.as_json(s, prop)
    result["output"] = str(out)
    figure = out.with_suffix(".png")
    proposal_figure(s, prop, figure)
    result["figure"] = str(figure)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1, default=float))
    if args.json:
        print_json(result)
    else:
        verdict = ("decides" if prop.best.decides else
                   f"does not decide (z {prop.best.z:.2f} < 2.33): the best of {len(prop.scored)} scored")
        print(f"next run: {best.name} ({best.duration_s:.1f} s, varies {', '.join(best.varies)}) -> {out}\n"
              f"  {verdict}; separation {prop.best.separation:.1f} noise units, worst pair "
              f"{min(prop.best.pairs, key=lambda p: p.z).truth} vs {min(prop.best.pairs, key=lambda p: p.z).rival}\n"
              f"  {len(prop.scored)} of {prop.family_size} programmes scored in {prop.seconds:.1f} s; figure {figure}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("propose", help="the next run: the drive programme under which rival explanations of a "
                                       "record differ most (a ramp file the daemon runs)")
    p.add_argument("data", help="recording (.h5) or interchange CSV/TDMS")
    p.add_argument("--model", required=True, help="model TOML ('nothing more' is this model, fitted)")
    p.add_argument("--rival", action="append", required=True,
                   help="a candidate the record leaves standing, as diagnose names it for `daq model add` "
                        "(EFFECT, EFFECT:FORM or mechanics.NAME); repeat for several")
    p.add_argument("--rig", help="rig of a CSV/TDMS file (default: the model's)")
    p.add_argument("--budget", type=float, default=120.0, help="seconds for scoring programmes (default 120)")
    p.add_argument("--max-run-s", type=float, help="longest programme [s] (default: the record's length, <= 60 s)")
    p.add_argument("-o", "--output", required=True, help="NEXT.toml: the proposed ramp (with NEXT.png, NEXT.json)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_propose)
