"""The online friction estimator as its own process (``python -m daq.daemon.estimator_process``).

The daemon starts it (daq/daemon/service.py, EstimatorProcess) so that the estimator's numerics
never share a GIL with acquisition; the algorithm itself is in daq/estimation/ (online.py on the
bus, core.py block by block).

Decision record: docs/decisions/0005-daemon-process-layout.md.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time

from daq.config import load_rig
from daq.estimation.online import OnlineCfg, OnlineEstimator

# ----------------------------------------------------------------------------- as a process

def _parent_gone(pid: int) -> bool:
    """True once the process that started us has died (we were re-parented)."""

    return bool(pid) and os.getppid() != pid


def main(argv: list[str] | None = None) -> int:
    """``python -m daq.daemon.estimator_process``: the online estimator in its own process (the daemon starts it).

    stdout: ``{"ready": true, "endpoint": ...}`` once subscribed and warmed up, then one
    ``stats {...}`` line per ``--stats-s`` (OnlineStats plus blocks_per_s). Exits on
    SIGTERM/SIGINT, or when ``--parent-pid`` is no longer its parent (the daemon died).
    """


    ap = argparse.ArgumentParser(prog="python -m daq.daemon.estimator_process", description="the online friction estimator")
    ap.add_argument("--rig", required=True)
    ap.add_argument("--sub", required=True, help="the sample bus to subscribe to")
    ap.add_argument("--pub", default="tcp://127.0.0.1:0", help="where to publish estimates")
    ap.add_argument("--fit", default="thread", choices=["process", "thread", "inline", "off"])
    ap.add_argument("--parent-pid", type=int, default=0)
    ap.add_argument("--stats-s", type=float, default=1.0)
    args = ap.parse_args(argv)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    est = OnlineEstimator(load_rig(args.rig), OnlineCfg(sub_endpoint=args.sub, pub_endpoint=args.pub, fit=args.fit))
    est.warm_up()
    est.start()
    print(json.dumps({"ready": True, "pid": os.getpid(), "endpoint": est.endpoint}), flush=True)
    last_t, last_blocks = time.monotonic(), 0
    try:
        while not stop.wait(args.stats_s):
            if _parent_gone(args.parent_pid):
                print("estimator: parent gone, exiting", file=sys.stderr, flush=True)
                break
            now, st = time.monotonic(), est.stats.model_dump()
            st["blocks_per_s"] = (st["blocks_in"] - last_blocks) / (now - last_t)
            last_t, last_blocks = now, st["blocks_in"]
            try:
                print("stats " + json.dumps(st), flush=True)
            except BrokenPipeError:
                break
    finally:
        est.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
