"""``daq bench NAME``: run a benchmark and print its figures beside the baseline measured in the same run.

The registry (daq/bench/__init__.py) imports a benchmark's module only when it runs.
"""

from __future__ import annotations

import argparse
import sys

from daq.bench import BENCHES, run_bench
from daq.errors import InputError
from daq.io.jsonout import print_json


COUNTS = {"steps": ("rsf", "steps"), "records": ("archive", "records")}  # option -> (its benchmark, what it counts)


def cmd_bench(args: argparse.Namespace) -> int:
    if args.name not in BENCHES:
        raise InputError("bench", args.name, f"unknown benchmark (have: {', '.join(BENCHES)})")
    options = {}
    if args.rig is not None:
        if args.name != "diagnose":
            raise InputError("bench", "--rig", f"only `daq bench diagnose` takes a rig (not {args.name!r})")
        options = {"rig": args.rig, "progress": lambda msg: print(msg, file=sys.stderr, flush=True)}
    for option, (owner, what) in COUNTS.items():  # counts one benchmark takes: checked before any work
        n = getattr(args, option)
        if n is None:
            continue
        if args.name != owner:
            raise InputError("bench", f"--{option}", f"only `daq bench {owner}` takes a number of {what} "
                                                     f"(not {args.name!r})")
        if n < 1:
            raise InputError("bench", f"--{option}", f"{n}: at least 1")
        options[option] = n
    if args.name in ("rsf", "propose"):
        options["progress"] = lambda msg: print(f"  {msg}", file=sys.stderr, flush=True)
    result, report = run_bench(args.name, **options)
    if args.json:
        print_json(result)
    else:
        print(report)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    bench = sub.add_parser("bench", help="run a benchmark against its same-run baseline")
    bench.add_argument("name")
    bench.add_argument("--json", action="store_true")
    bench.add_argument("--rig", help="diagnose: brake-2dof (default) or belt-ndof (issue 14's long record)")
    bench.add_argument("--steps", type=int, help="rsf: velocity steps in the batch (default 10 000)")
    bench.add_argument("--records", type=int, help="archive: recordings in the job (default 10); a job's fixed cost "
                                                   "(the cluster, its workers' imports) spreads over them")
    bench.set_defaults(func=cmd_bench)
