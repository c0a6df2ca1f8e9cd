"""``daq propose``: the drive programme that would decide between rival explanations of a record (issue 26).

Heavy modules are imported inside the command function: `daq --help` imports every cli module and must stay fast.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from daq.errors import InputError
from daq.io.jsonout import print_json

from .output import say

# the longest programme by default: twice the first record, within these (a short record's run may need longer to
# show a slow effect: aging on the brake at one speed was decided by no 10 s run of its family, by 20 s ones)
MIN_RUN_S, MAX_RUN_S = 20.0, 60.0


def cmd_propose(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.models.candidates import candidates_for, parse_candidate
    from daq.models.design import proposal
    from daq.models.design.programmes import Programme, write_programme
    from daq.models.diagnosis.diagnose import diagnose
    from daq.models.figures import proposal_figure
    from daq.models.fit.multi_session import MultiSession
    from daq.models.fit.session import Session
    from daq.models.spec import load_model

    out = Path(args.output)
    if out.suffix.lower() != ".toml":
        raise InputError(str(out), "-o", "must end in .toml (a ramp file the daemon runs)")
    if args.budget is not None and not args.budget > 0:
        raise InputError("--budget", "--budget", f"{args.budget:g} s: must be > 0")
    model = load_model(args.model)
    known = {c.label: c for c in candidates_for(model)}
    given = []
    for text in args.rival or ():
        c = parse_candidate(text)
        if c.label not in known:
            raise InputError("--rival", "--rival", f"{text!r} is not a candidate of this model (one of: "
                                                   f"{', '.join(sorted(known))})")
        given.append(c)
    data = list(args.data)
    # before the first progress line: a bad file is one line
    s = MultiSession.open(data, model, args.rig) if len(data) > 1 else Session.open(data[0], model, args.rig)
    print(f"propose: {' + '.join(data)} against {model.describe()}", file=sys.stderr)
    if given:
        rs = proposal.rivals_for(s, model, given, say)
        why = f"rivals given: {', '.join(c.label for c in given)}"
    else:
        say("diagnosing first: the rivals are what the diagnosis leaves standing")
        rs, why = proposal.rivals_from(s, model, diagnose(s, model, progress=say, deliver=False), say)
    say(why)
    if not rs:
        result = {"data": data, "programme": None, "reason": why, "decides": None}
        out.with_suffix(".json").write_text(json.dumps(result, indent=1))
        if args.json:
            print_json(result)
        else:
            print(f"no run to propose: {why}")
        return 0
    v0 = proposal.drive_speed(s)
    max_run = args.max_run_s or min(MAX_RUN_S, max(MIN_RUN_S, 2.0 * float(s.m.t[-1] - s.m.t[0])))
    for r in rs:
        say(f"{r.label}: {r.error(s):.4g} {s.m.units[s.primary]} on the record"
            + (f" ({r.fixed} held at a generic strength: the record cannot tell it from nothing)" if r.fixed else ""))
    prop = proposal.propose(s, rs, math.inf if args.budget is None else args.budget, max_run, v0, say)
    best: Programme = prop.best.programme
    write_programme(best, out)
    result = proposal.as_json(s, prop)
    result["output"] = str(out)
    result["reason"] = why
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
    p.add_argument("data", nargs="+", help="recording(s) (.h5) or interchange CSV/TDMS of one rig (several: judged "
                                           "together, one model; the family is built around the first)")
    p.add_argument("--model", required=True, help="model TOML ('nothing more' is this model, fitted)")
    p.add_argument("--rival", action="append",
                   help="a candidate to test against 'nothing more', as diagnose names it for `daq model add` "
                        "(EFFECT or EFFECT:FORM); repeat for several. Default: diagnose first and take what it leaves "
                        "standing (a tie, or the effects the record cannot see)")
    p.add_argument("--rig", help="rig of a CSV/TDMS file (default: the model's)")
    p.add_argument("--budget", type=float,
                   help="seconds for scoring programmes; past them the best of those scored (which then depends on "
                        "the machine's speed). Default: the rig's whole family, whatever it takes")
    p.add_argument("--max-run-s", type=float, help=f"longest programme [s] (default: twice the first record, within "
                                                   f"[{MIN_RUN_S:g}, {MAX_RUN_S:g}] s)")
    p.add_argument("-o", "--output", required=True, help="NEXT.toml: the proposed ramp (with NEXT.png, NEXT.json)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_propose)
