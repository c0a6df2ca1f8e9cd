"""The simulated bench as its own process, so that it outlives the daemon that drives it.

Why a process: the lab's instruments do not die with the daemon. A kill -9 of the
daemon must leave the simulated motor regulator running, so its watchdog (not the
daemon) brings the belt to rest, exactly as on the real rig. Running the physics
in its own interpreter also keeps it off the daemon's interpreter lock.

Transport across processes: every instrument is on a pty (serial). python-can's
``virtual`` bus only exists inside one process, and its ``udp_multicast`` interface
needs ``msgpack`` (not a dependency of this project) and is lossy under bursts
(measured here: 24 % of a 3000-frame burst lost; paced 2000 frames/s arrived
complete). :func:`cross_process_wiring` therefore moves CAN-carried channels onto
the rig's serial-stream alternative (``[instruments.laser_serial]``, ``enabled =
false`` in the rig configs) - a pty is flow-controlled, point to point, and cannot
see another bench's frames.

Run it:
    python -m sim_backends.process --rig brake-2dof --workdir DIR [--effect NAME[:k=v,...]]...
        [--time-scale X] [--owner-pid PID] [--linger-s S]
stdout: one JSON line ``{"ready": true, "pid": ..., "control": "tcp://...", "endpoints": {...}}``.
The control socket (REP, loopback) answers JSON ``{"op": "status"}`` (belt speed, regulator
state, watchdog trips) and ``{"op": "exit"}``. SIGTERM/SIGINT stop the bench. With
``--owner-pid`` the bench exits by itself once that process is gone, the belt has been at
rest and nobody has asked for its status for ``--linger-s`` seconds (so orphans do not pile up).
Starting, asking and ending it from another process: bench_client.py (no simulator imported there).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import zmq

from daq.config import load_rig
from daq.errors import InputError
from daq.sim.effectset import parse_effect
from daq.streaming.child_process import pid_alive

from .bench_client import cross_process_wiring
from .hardware import SimulatedHardware

STANDSTILL = 1e-3  # [m/s]


def _serve(args: argparse.Namespace) -> int:
    cfg = cross_process_wiring(load_rig(args.rig))
    effects = [parse_effect(x, "--effect") for x in args.effect]
    hw = SimulatedHardware(cfg, Path(args.workdir), effects=effects, time_scale=args.time_scale,
                           seed=args.seed).start()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    ctx = zmq.Context()
    sock = ctx.socket(zmq.REP)
    sock.setsockopt(zmq.LINGER, 0)
    sock.bind("tcp://127.0.0.1:*")
    control = sock.getsockopt_string(zmq.LAST_ENDPOINT)
    info = {"ready": True, "pid": os.getpid(), "rig": cfg.rig, "control": control, "endpoints": hw.endpoints(),
            "instruments": [n for n, i in cfg.instruments.items() if i.enabled]}
    (Path(args.workdir) / "sim.json").write_text(json.dumps(info))
    print(json.dumps(info), flush=True)
    last_asked = time.monotonic()
    rest_since: float | None = None
    try:
        while not stop.is_set():
            if sock.poll(100):
                try:
                    req = json.loads(sock.recv())
                    op = req.get("op") if isinstance(req, dict) else None
                except ValueError:
                    op = None
                last_asked = time.monotonic()
                if op == "status":
                    sock.send_string(json.dumps(_status(hw)))
                elif op == "exit":
                    sock.send_string(json.dumps({"ok": True}))
                    break
                else:
                    sock.send_string(json.dumps({"ok": False, "error": "ops: status, exit"}))
            if args.owner_pid and not pid_alive(args.owner_pid):
                now = time.monotonic()
                rest_since = (rest_since or now) if hw.rig.belt_speed <= STANDSTILL else None
                if rest_since is not None and now - max(rest_since, last_asked) > args.linger_s:
                    print(f"sim: owner {args.owner_pid} gone, belt at rest: exiting", file=sys.stderr, flush=True)
                    break
    finally:
        print(f"sim: the physics was behind the wall clock by up to {hw.rig.behind_max_s * 1e3:.1f} ms",
              file=sys.stderr, flush=True)
        hw.stop()
        sock.close()
        ctx.term()
    return 0


def _status(hw) -> dict[str, Any]:
    m = hw.motor
    out: dict[str, Any] = {"ok": True, "t": hw.rig.t, "belt_speed": hw.rig.belt_speed, "target": hw.rig.target,
                           "behind_max_s": hw.rig.behind_max_s}
    if m is not None:
        out.update(motor_state=m.state, setpoint=m.setpoint, watchdog_trips=m.watchdog_trips, commands=m.commands,
                   checksum_errors=m.checksum_errors)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sim_backends.process", description="a simulated bench")
    ap.add_argument("--rig", required=True)
    ap.add_argument("--workdir", required=True)
    ap.add_argument("--effect", action="append", default=[])
    ap.add_argument("--time-scale", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--owner-pid", type=int, default=0)
    ap.add_argument("--linger-s", type=float, default=30.0)
    args = ap.parse_args(argv)
    try:
        return _serve(args)
    except InputError as exc:
        print(str(exc), file=sys.stderr, flush=True)
        return 2


if __name__ == "__main__":
    sys.exit(main())
