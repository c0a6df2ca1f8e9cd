"""``daq propose``: the drive programme that would decide between rival explanations of a record (issue 26).

Heavy modules are imported inside the command function: `daq --help` imports every cli module and must stay fast.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from daq.api import MAX_RUN_S, MIN_RUN_S
from daq.io.jsonout import print_json

from .output import say


def cmd_propose(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.api.loop import check_proposal, proposed, rivals_given
    from daq.models.fit.multi_session import MultiSession
    from daq.models.fit.session import Session
    from daq.models.spec import load_model

    out = Path(args.output)
    check_proposal(out, args.budget, "-o", "--budget")
    model = load_model(args.model)
    given = rivals_given(model, args.rival or (), "--rival")
    data = list(args.data)
    # before the first progress line: a bad file is one line
    s = MultiSession.open(data, model, args.rig) if len(data) > 1 else Session.open(data[0], model, args.rig)
    print(f"propose: {' + '.join(data)} against {model.describe()}", file=sys.stderr)
    p = proposed(s, model, given, out, budget_s=args.budget, max_run_s=args.max_run_s, progress=say)  # daq.propose's
    if args.json:
        print_json(p.json)
    else:
        print(p.text)
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
