"""``daq daemon`` and ``daq ctl``: the operator daemon and its control client on the command line.

Kept apart from daq/cli/main.py because the daemon's options (keys, endpoints, sim
faults) are many and only the operator needs them. See docs/daemon.md.

Keys (``--keys DIR``), as written by ``daq ctl keygen DIR --operator NAME --observer NAME``:
  daemon side: DIR/server.key_secret, DIR/operators/*.key, DIR/observers/*.key (public keys);
  client side: a directory with client.key_secret and server.key (keygen writes DIR/clients/NAME/).
With keys the control socket is CURVE-encrypted and authenticated (also on loopback); without
keys it must bind to loopback.

Heavy modules are imported inside the command functions (marked ``# heavy``): `daq --help`
imports every cli module and must stay fast.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import shutil
import sys
import time
from datetime import datetime
from pathlib import Path
from typing import Any

from daq.errors import DaqError, InputError

DEFAULT_CONTROL = "tcp://127.0.0.1:5570"
DEFAULT_BUS = "tcp://127.0.0.1:5560"
RAMP_ACTIVE = ("idle", "lead-in", "running")


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``daemon`` and ``ctl`` subcommands to the ``daq`` parser."""
    p = sub.add_parser("daemon", help="run the operator daemon for one rig (drivers, bus, recorder, estimator)")
    p.add_argument("--rig", required=True, help="rig id or config TOML")
    p.add_argument("--sim", action="store_true", help="simulated instruments (a bench process that outlives us)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME[:k=v,...]",
                   help="hidden effect of the simulated rig (repeatable; --sim only)")
    p.add_argument("--time-scale", type=float, default=1.0, help="simulated physics speed vs wall clock (--sim)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the simulated instruments' noise (--sim)")
    p.add_argument("--data-dir", default="data", help="where recordings go (default: ./data)")
    p.add_argument("--control", default=DEFAULT_CONTROL, help=f"control socket (default {DEFAULT_CONTROL})")
    p.add_argument("--keys", help="CURVE key directory (server.key_secret, operators/, observers/)")
    p.add_argument("--bus", default=DEFAULT_BUS, help=f"sample bus endpoint (default {DEFAULT_BUS})")
    p.add_argument("--workdir", help="where simulated devices appear (--sim; default: the last session's bench "
                                     "if it still runs, else a temp dir)")
    p.add_argument("--state-dir", help="where the rig's session state and lock live (default DATA_DIR/.daq-daemon): "
                                       "how the last session ended")
    p.add_argument("--web", metavar="[HOST:]PORT", help="serve the live page (docs/daemon.md); loopback unless "
                                                        "--keys; PORT 0: any free port")
    p.set_defaults(func=cmd_daemon)

    c = sub.add_parser("ctl", help="talk to a running daemon: status, ramp, stop, estop, reset, record, note")
    c.add_argument("--endpoint", default=DEFAULT_CONTROL, help=f"the daemon's control socket ({DEFAULT_CONTROL})")
    c.add_argument("--keys", help="client key directory (client.key_secret and server.key)")
    c.add_argument("--timeout", type=float, default=15.0, help="seconds to wait for a reply")
    cs = c.add_subparsers(dest="action", required=True)
    s = cs.add_parser("status", help="streams, rates, drops, belt speed, estimator output")
    s.add_argument("--json", action="store_true", help="one JSON object on stdout")
    s.set_defaults(func=cmd_ctl_status)
    r = cs.add_parser("ramp", help="run a ramp file and show its progress until it ends")
    r.add_argument("file")
    r.add_argument("--time-scale", type=float, default=1.0, help="multiply the programme's times (<= 1)")
    r.add_argument("--no-wait", action="store_true", help="start it and return")
    r.set_defaults(func=cmd_ctl_ramp)
    for name, hlp in (("stop", "controlled ramp to rest"), ("estop", "emergency stop (latched)")):
        cs.add_parser(name, help=hlp).set_defaults(func=cmd_ctl_simple, op=name)
    cs.add_parser("reset", help="at standstill: clear the regulator's latch (e-stop, watchdog) and acknowledge "
                                "an unclean end of the last session; motion is refused until then").set_defaults(
        func=cmd_ctl_reset)
    rec = cs.add_parser("record", help="record start [--path FILE] | record stop | record rotate [--path FILE] (the "
                                       "next file starts before this one closes: no hole between them)")
    rec.add_argument("what", choices=["start", "stop", "rotate"])
    rec.add_argument("--path", help="run file (record start/rotate; default DATA_DIR/RIG-STAMP.h5)")
    rec.set_defaults(func=cmd_ctl_record)
    n = cs.add_parser("note", help="an operator note in the run's event table")
    n.add_argument("text", nargs="+")
    n.set_defaults(func=cmd_ctl_note)
    k = cs.add_parser("keygen", help="make CURVE keys: server, operators, observers, client bundles")
    k.add_argument("dir")
    k.add_argument("--operator", action="append", default=[], metavar="NAME")
    k.add_argument("--observer", action="append", default=[], metavar="NAME")
    k.set_defaults(func=cmd_ctl_keygen)


# ----------------------------------------------------------------------------- daemon


def server_keys(keys: str | None) -> dict[str, Path | None]:
    """ControlCfg fields from a daemon key directory (InputError naming the missing file)."""
    if keys is None:
        return {}
    d = Path(keys)
    secret = d / "server.key_secret"
    if not secret.is_file():
        raise InputError(str(d), "server.key_secret", "missing (make keys with: daq ctl keygen DIR)")
    ops, obs = d / "operators", d / "observers"
    if not ops.is_dir() and not obs.is_dir():
        raise InputError(str(d), "operators", "no operators/ or observers/ directory of public keys")
    return {"server_secret_file": secret, "operators_dir": ops if ops.is_dir() else None,
            "observers_dir": obs if obs.is_dir() else None}


def parse_web(value: str, curve: bool) -> tuple[str, int]:
    """``--web [HOST:]PORT`` as (host, port): loopback by default, any other address only with CURVE keys."""
    # heavy: zmq only when the command runs
    from daq.daemon.control import is_local_endpoint

    host, sep, port = value.rpartition(":")
    host = host.strip("[]") if sep else ""
    try:
        number = int(port)
    except ValueError:
        raise InputError(value, "--web", "expected [HOST:]PORT") from None
    if not 0 <= number <= 65535:
        raise InputError(value, "--web", f"port {number} is not in 0..65535")
    host = host or "127.0.0.1"
    if not curve and not is_local_endpoint(f"tcp://{host}:0"):
        raise InputError(value, "--web", f"refusing non-loopback {host!r} without CURVE keys (--keys): "
                                           "bind to 127.0.0.1, or configure keys")
    return host, number


def cmd_daemon(args: argparse.Namespace) -> int:
    # heavy: zmq, pydantic and the daemon only when the command runs
    import zmq
    from pydantic import ValidationError

    from daq.config import load_rig
    from daq.daemon.control import ControlCfg, ControlServer, check_endpoint_security
    from daq.daemon.rig_lock import RigBusy
    from daq.daemon.service import Daemon, DaemonCfg
    from daq.daemon.session_state import STATE_DIR_NAME, SessionBusy
    from daq.sim.effectset import parse_effect

    load_rig(args.rig)  # bad rig: InputError before anything starts
    for e in args.effect:
        parse_effect(e, "--effect")
    if args.effect and not args.sim:
        raise InputError("--effect", "--sim", "hidden effects need a simulated rig (--sim)")
    if not args.time_scale > 0:
        raise InputError("--time-scale", "--time-scale", "must be > 0")
    try:
        ccfg = ControlCfg(endpoint=args.control, **server_keys(args.keys))
        check_endpoint_security(ccfg)
    except (ValidationError, ValueError) as exc:
        raise InputError(args.keys or args.control, "--control", str(exc).splitlines()[0]) from None
    web_at = parse_web(args.web, ccfg.curve) if args.web else None
    state_dir = Path(args.state_dir) if args.state_dir else Path(args.data_dir) / STATE_DIR_NAME
    daemon = Daemon(DaemonCfg(rig=args.rig, data_dir=Path(args.data_dir), bus_endpoint=args.bus, state_dir=state_dir,
                              control_endpoint=args.control), bench=_sim_bench(args) if args.sim else None)
    done = daemon.install_signal_handlers()  # before start: a SIGTERM while starting still ramps down
    try:
        daemon.start()
    except (SessionBusy, RigBusy) as exc:
        print(f"daq daemon: {exc}", file=sys.stderr, flush=True)
        return 1
    except zmq.ZMQError as exc:  # a socket another program holds: one line, not a traceback (issue 29)
        print(f"daq daemon: cannot bind the sample bus {args.bus}: {exc}", file=sys.stderr, flush=True)
        return 1
    if daemon.motion.unclean is not None:
        print(f"daq daemon: WARNING: {daemon.motion.unclean.summary()}; motion refused until `daq ctl reset`",
              file=sys.stderr, flush=True)
    server = web = None
    try:
        try:
            server = ControlServer(daemon.handlers(), ccfg).start()
        except zmq.ZMQError as exc:
            print(f"daq daemon: cannot bind the control socket {args.control}: {exc}", file=sys.stderr, flush=True)
            return 1
        if web_at is not None:
            web = _start_web(daemon, server, web_at, ccfg.curve)
        sim = f" sim_bench_pid={daemon.bench.pid} sim_control={daemon.bench.control}" if daemon.bench else ""
        est = f" estimator={daemon.estimator.endpoint}" if daemon.estimator else ""
        print(f"daq daemon: ready rig={daemon.rig.rig} control={server.endpoint} curve={ccfg.curve} "
              f"bus={daemon.acq.endpoint}{est}{sim}{f' web={web.url}' if web else ''}", flush=True)
        while not done.wait(0.5):
            pass
        print("daq daemon: signal received: controlled ramp-down, closing the recording", flush=True)
    finally:
        if web is not None:
            web.stop()
        if server is not None:
            server.stop()
        daemon.shutdown()
    print("daq daemon: stopped", flush=True)
    return 0


def _sim_bench(args: argparse.Namespace):
    """``--sim``: the factory of the simulated bench the daemon drives (the daemon does not know the simulator)."""
    # heavy: the simulator only with --sim
    from daq.daemon.sim_bench import SimBenchCfg, sim_bench_factory

    return sim_bench_factory(SimBenchCfg(rig=args.rig, effects=args.effect, time_scale=args.time_scale, seed=args.seed,
                                         workdir=Path(args.workdir) if args.workdir else None))


def _start_web(daemon, server, at: tuple[str, int], curve: bool):
    """The live page's process (daq/web/): on the daemon's bus, commanding through ``server.handle``.

    With CURVE keys a page is an observer unless it gives the operator token made here and
    printed once on stderr (the operator's link carries it in its ``#token=`` fragment)."""
    # heavy: starlette only when --web is given
    from daq.web.messages import WebCfg
    from daq.web.process import WebProcess

    token = secrets.token_urlsafe(24) if curve else None
    also = [daemon.estimator.endpoint] if daemon.estimator else []
    cfg = WebCfg(host=at[0], port=at[1], bus=daemon.acq.endpoint, also=also, rig=daemon.rig.rig, curve=curve,
                 token=token, parent_pid=os.getpid())
    def ended(code: int) -> None:  # acquisition and recording do not depend on the page: say so, go on
        detail = f"the web page process ended unexpectedly (exit {code}); acquisition and recording go on"
        print(f"daq daemon: {detail}", file=sys.stderr, flush=True)
        daemon.acq.publish_event("web_died", "daemon", detail)

    web = WebProcess(cfg, server.handle, daemon.cfg.start_timeout_s, on_exit=ended)
    daemon.web = web
    if token:
        print(f"daq daemon: web page {web.url} (observers); operator link, keep it secret: {web.url}#token={token}",
              file=sys.stderr, flush=True)
    return web


# ----------------------------------------------------------------------------- ctl


def _client(args: argparse.Namespace):
    # heavy: zmq, pydantic and the daemon only when the command runs
    from daq.daemon.control import ControlClient

    if args.keys is None:
        return ControlClient(args.endpoint, timeout_s=args.timeout)
    d = Path(args.keys)
    for name in ("client.key_secret", "server.key"):
        if not (d / name).is_file():
            raise InputError(str(d), name, "missing (client keys: daq ctl keygen DIR --operator NAME)")
    return ControlClient(args.endpoint, client_secret_file=d / "client.key_secret",
                         server_public_file=d / "server.key", timeout_s=args.timeout)


class CtlFailed(DaqError):
    """The daemon refused or failed a request (exit status 1; bad input is an InputError, exit 2)."""

    def __init__(self, message: str, status: int) -> None:
        super().__init__(message)
        self.status = status


def _call(args: argparse.Namespace, op: str, client=None, **kw: Any) -> dict[str, Any]:
    """One request; bad input (file/field) raises InputError (exit 2), other refusals CtlFailed (exit 1)."""
    own = client is None
    c = client or _client(args)
    try:
        try:
            r = c.request(op, **kw)
        except TimeoutError:
            raise CtlFailed(f"no reply from {args.endpoint} within {args.timeout:g} s "
                            "(daemon not running, or its CURVE keys do not admit this client)", 1) from None
    finally:
        if own:
            c.close()
    if r.ok:
        return r.result
    if r.code in ("input", "malformed"):
        src, _, rest = (r.error or "").partition(": ")
        field, _, msg = rest.partition(": ")
        raise InputError(src, field, msg) if msg else InputError(op, "request", r.error or "refused")
    raise CtlFailed(r.error or "refused", 1)


def _run(fn, args: argparse.Namespace) -> int:
    try:
        return fn(args)
    except CtlFailed as exc:
        print(f"daq ctl: {exc}", file=sys.stderr)
        return exc.status


def _fmt(x: Any, spec: str = ".4f") -> str:
    """A number for the status text; "-" for a null (e.g. ``gamma_se`` after a watchdog stop, issue 29) and the
    value as it is if it is not a number, so no reply field can crash the text."""
    if x is None:
        return "-"
    try:
        return format(x, spec)
    except (TypeError, ValueError):
        return str(x)


def _local(iso: str | None) -> str:
    """An ISO time from status as the operator's local wall clock."""
    try:
        return datetime.fromisoformat(iso).astimezone().strftime("%H:%M:%S") if iso else "?"
    except ValueError:
        return iso or "?"


def _truth_lines(st: dict[str, Any]) -> list[str]:
    """What went wrong before now: an unclean end of the last session, a latched regulator, a lost recording."""
    lines = []
    last = st.get("last_session")
    if last:
        lines.append(f"LAST SESSION ENDED UNCLEANLY: daemon pid {last['pid']}, alive until after "
                     f"{_local(last.get('last_alive_at'))}"
                     + (f"; was recording {last['recording']['path']} ({last.get('recording_outcome')})"
                        if last.get("recording") else "")
                     + (f"; was running ramp {last['ramp']}" if last.get("ramp") else "")
                     + (f"; {last['note']}" if last.get("note") else ""))
    reg = st.get("regulator")
    if reg:
        trips = f", {reg['watchdog_trips']} watchdog trip(s)" if reg.get("watchdog_trips") is not None else ""
        lines.append(f"regulator {reg.get('state') or 'UNREADABLE ' + str(reg.get('error'))}"
                     f"{' LATCHED' if reg.get('latched') else ''}{trips} (read {_local(reg.get('read_at'))})")
    motion = st.get("motion") or {}
    if motion and not motion.get("allowed", True):
        lines.append("motion    REFUSED until `daq ctl reset`")
    fail = st.get("recording_failure")
    if fail:
        lines.append(f"recording ENDED UNEXPECTEDLY at {_local(fail.get('ended_at'))}: recorder pid {fail['pid']} "
                     f"{fail['exit']}; {fail['path']}: {fail['recovery']}")
    return lines


def format_status(st: dict[str, Any]) -> str:
    belt = st.get("belt") or {}
    age = belt.get("age_s")
    lines = [f"rig {st['rig']}{' (simulated)' if st.get('sim') else ''}  pid {st['pid']}  "
             f"up {_fmt(st.get('uptime_s'), '.0f')} s  bus {st['bus']}",
             *_truth_lines(st),
             f"belt      measured {_fmt(belt.get('measured'))} m/s{f' ({age:.1f} s ago)' if age is not None else ''}"
             f"  commanded {_fmt(belt.get('commanded'))} m/s  regulator set point {_fmt(belt.get('setpoint'))} m/s  "
             f"link {belt.get('regulator')}"]
    lines.append("streams")
    for name, s in sorted(st.get("streams", {}).items()):
        lines.append(f"  {name:16s} {_fmt(s.get('rate_hz'), '9.1f')} samples/s  {_fmt(s.get('samples'), '>10d')} "
                     f"samples  {_fmt(s.get('blocks'), '>7d')} blocks")
    for name, s in sorted(st.get("sources", {}).items()):
        lines.append(f"  source {name:16s} {_fmt(s.get('state'), '12s')} lost frames {s['lost_frames']}  "
                     f"checksum errors {s['checksum_errors']}  reconnects {s['reconnects']}")
    lines.append("drops     " + "  ".join(f"{k} {v}" for k, v in st.get("drops", {}).items()))
    web = st.get("web")
    if web:
        lines.append(f"web page  {web['url']}  pid {web['pid']} "
                     + ("alive" if web["alive"] else f"ENDED (exit {web['exit']}): the page is gone"))
    est = st.get("estimator")
    if est:
        last, fit = est.get("last") or {}, est.get("fit") or {}
        lines.append(f"estimator pid {est['pid']} {'alive' if est['alive'] else 'DEAD'}  "
                     f"{_fmt(est.get('blocks_per_s'), '.1f')} blocks/s in  lost {est.get('lost_blocks', 0)}  "
                     f"gaps {est.get('gaps', 0)}  stick-slip cycles {est.get('cycles', 0)}")
        if last:
            lines.append(f"          F_est {_fmt(last.get('F_est'), '.3f')} N  "
                         f"mu_est {_fmt(last.get('mu_est'), '.3f')}  v_rel {_fmt(last.get('v_rel'))} m/s  "
                         f"{'slip' if last.get('slip') else 'stick'}")
        if fit:
            lines.append("          fit " + "  ".join(f"{k} {_fmt(v, '.4g')}" for k, v in fit.items() if k != "t"))
    rec = st.get("recording")
    lines.append(f"recording {rec['path']} (pid {rec['pid']})  {rec['progress']}" if rec else "recording off")
    ramp = st.get("ramp")
    if ramp:
        frac = ramp.get("fraction")
        lines.append(f"ramp      {ramp.get('state')} {_fmt(None if frac is None else 100 * frac, '.0f')} %  "
                     f"t {_fmt(ramp.get('t'), '.1f')}/{_fmt(ramp.get('duration'), '.1f')} s  "
                     f"commanded {_fmt(ramp.get('commanded'))} m/s  "
                     f"measured {_fmt(ramp.get('measured'))} m/s  {ramp.get('reason') or ''}")
    return "\n".join(lines)


def cmd_ctl_status(args: argparse.Namespace) -> int:
    def run(a):
        st = _call(a, "status")
        if a.json:
            print(json.dumps(st), flush=True)
            return 0
        try:
            text = format_status(st)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:  # a reply from another version: one line
            raise CtlFailed(f"cannot show the daemon's status as text ({type(exc).__name__}: {exc}); "
                            "use `daq ctl status --json`", 1) from None
        print(text, flush=True)
        return 0
    return _run(run, args)


def cmd_ctl_simple(args: argparse.Namespace) -> int:
    def run(a):
        print(json.dumps(_call(a, a.op)))
        return 0
    return _run(run, args)


def cmd_ctl_reset(args: argparse.Namespace) -> int:
    def run(a):
        res = _call(a, "reset")
        ack = f"; acknowledged: {res['acknowledged']}" if res.get("acknowledged") else ""
        print(f"reset: regulator {res.get('regulator_before')} -> {res.get('regulator')}{ack}", flush=True)
        return 0
    return _run(run, args)


def cmd_ctl_note(args: argparse.Namespace) -> int:
    def run(a):
        print(json.dumps(_call(a, "note", text=" ".join(a.text))))
        return 0
    return _run(run, args)


def cmd_ctl_record(args: argparse.Namespace) -> int:
    def run(a):
        kw = {"path": str(Path(a.path).absolute())} if a.path else {}
        if a.what == "start":
            res = _call(a, "record_start", **kw)
            print(f"recording to {res['recording']}")
        elif a.what == "rotate":
            res = _call(a, "record_rotate", **kw)
            print(f"recording to {res['recording']}; closed {res['closed']}")
        else:
            res = _call(a, "record_stop")
            print(f"closed {res['closed']}")
        return 0
    return _run(run, args)


def cmd_ctl_ramp(args: argparse.Namespace) -> int:
    path = Path(args.file).absolute()
    if not path.is_file():
        raise InputError(args.file, "(file)", "no such file")
    if not 0 < args.time_scale <= 1:
        raise InputError(args.file, "--time-scale", "must be in (0, 1]")

    def run(a):
        c = _client(a)
        try:
            res = _call(a, "ramp", client=c, file=str(path), time_scale=float(a.time_scale))
            print(f"ramp {path.name}: started, {res.get('duration_s', 0):.1f} s programme", flush=True)
            if a.no_wait:
                return 0
            return _follow(a, c, str(path))
        finally:
            c.close()
    return _run(run, args)


def _follow(args: argparse.Namespace, c, path: str) -> int:
    """Poll status until the ramp ends; Ctrl-C sends a controlled stop."""
    tty = sys.stdout.isatty()
    last_print = 0.0
    ramp: dict[str, Any] = {}
    try:
        while True:
            st = _call(args, "status", client=c)
            ramp = st.get("ramp") or {}
            if ramp.get("source") == path and ramp.get("state") not in RAMP_ACTIVE:
                break
            now = time.monotonic()
            if ramp and (tty or now - last_print >= 1.0):
                est = (st.get("estimator") or {}).get("last") or {}
                line = (f"ramp {ramp['state']:8s} {100 * ramp['fraction']:5.1f} %  t {ramp['t']:6.2f}/"
                        f"{ramp['duration']:.2f} s  set {ramp['commanded']:.4f}  belt "
                        f"{_fmt((st.get('belt') or {}).get('measured'))} m/s  F_est {_fmt(est.get('F_est'), '.3f')} N")
                print(("\r" + line) if tty else line, end="" if tty else "\n", flush=True)
                last_print = now
            time.sleep(0.25)
    except KeyboardInterrupt:
        _call(args, "stop", client=c)
        print("\nramp: interrupted, controlled stop sent", file=sys.stderr)
        return 130
    if tty:
        print()
    print(f"ramp {ramp.get('state')}: {ramp.get('reason', '')}", flush=True)
    return 0 if ramp.get("state") == "finished" else 1


def cmd_ctl_keygen(args: argparse.Namespace) -> int:
    # heavy: zmq, pydantic and the daemon only when the command runs
    from daq.daemon.control import generate_keys

    d = Path(args.dir)
    if not (args.operator or args.observer):
        raise InputError(args.dir, "--operator", "name at least one --operator or --observer")
    for n in args.operator + args.observer:
        if not n.isidentifier():
            raise InputError(args.dir, "--operator" if n in args.operator else "--observer",
                             f"{n!r}: use letters, digits and _ only")
    server_pub = d / "server.key"
    if not server_pub.exists():
        generate_keys(d, "server")
    for role, names in (("operators", args.operator), ("observers", args.observer)):
        for name in names:
            bundle = d / "clients" / name
            pub, sec = generate_keys(bundle, "client")
            (d / role).mkdir(parents=True, exist_ok=True)
            shutil.copy(pub, d / role / f"{name}.key")
            shutil.copy(server_pub, bundle / "server.key")
            print(f"{role[:-1]} {name}: give {bundle} to the client (daq ctl --keys {bundle})")
    print(f"daemon: daq daemon --keys {d} ...")
    return 0
