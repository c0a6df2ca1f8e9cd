"""``daq soak``: run the daemon with its page, two viewers (one stalled), rotated recordings and ramps, and say
whether memory stays flat, every stream keeps its rate and nothing is lost (daq/daemon/soak.py).

Heavy modules are imported inside the command (``# heavy``): `daq --help` imports every cli module.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from daq.errors import InputError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("soak", help="run daq daemon --sim --web for N minutes with viewers and recordings; "
                                    "memory slope per process, stream rates, lost blocks")
    p.add_argument("--minutes", type=float, required=True, help="how long the daemon runs once ready")
    p.add_argument("--record-every", type=float, default=60.0, metavar="MIN",
                   help="start a new recording this often (default 60: hourly)")
    p.add_argument("--sample-s", type=float, help="read every process's RSS this often (default: 1-5 s by length)")
    p.add_argument("--warmup", type=float, metavar="MIN",
                   help="each process's first minutes left out of its slope (default: a fifth of the run, at most 3)")
    p.add_argument("--rig", default="brake-2dof", help="the simulated rig (default brake-2dof)")
    p.add_argument("--no-ramps", action="store_true", help="leave the belt at rest (default: ramps one after the other)")
    p.add_argument("--out", default="out/soak", help="data, daemon.log, soak.json and soak.png (default out/soak)")
    p.add_argument("--json", action="store_true", help="the result as one JSON object on stdout")
    p.set_defaults(func=cmd_soak)


def cmd_soak(args: argparse.Namespace) -> int:
    # heavy: pydantic, psutil, websockets, h5py, matplotlib only when the command runs
    from pydantic import ValidationError

    from daq.daemon.soak import SoakCfg, report, run_soak, write_result
    from daq.io.jsonout import print_json

    try:
        cfg = SoakCfg(minutes=args.minutes, out_dir=Path(args.out), rig=args.rig, record_every_min=args.record_every,
                      sample_s=args.sample_s, warmup_min=args.warmup, ramps=not args.no_ramps)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        flag = {"minutes": "--minutes", "record_every_min": "--record-every", "sample_s": "--sample-s",
                "warmup_min": "--warmup"}.get(str(err["loc"][0]), f"--{err['loc'][0]}")
        raise InputError("soak", flag, err["msg"]) from None
    interrupt = threading.Event()  # SIGTERM/SIGINT: stop early, stop the daemon, report what ran
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: interrupt.set())
    result = run_soak(cfg, log=lambda line: print(line, file=sys.stderr, flush=True), interrupt=interrupt)
    path = write_result(result, cfg.out_dir / "soak.json")
    if args.json:
        print_json(result.model_dump(mode="json"))
    else:
        print(report(result))
        print(f"json: {path}")
    return 0 if result.daemon_exit is None else 1
