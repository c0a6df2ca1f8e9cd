"""``daq campaign drum`` on the command line: options, the default grid, resume checks, the operator's prompts.

Why here and not in ``daq.analysis.campaign``: ``daq --help`` imports every command-line module,
and the campaign's machinery (numpy, matplotlib, pydantic models, the daemon client) costs ~175 ms;
so this module imports it only when the command runs. The campaign itself (state, per-row daemons,
run loop, table and figures) is the package ``daq.analysis.campaign``; method in docs/campaign.md.

Thrust on real hardware: on paper 002's stand the thrust is set with a screw (element 5) and read
by strain gauge B. The operator runs ``daq daemon --rig CONFIG.toml`` and passes ``--endpoint``;
before each thrust row the campaign asks on the terminal for the thrust to be set (``--yes``: it
already is, or is set by other means). Simulated (``--sim``), each thrust row gets its own daemon.
A rerun into the same ``--out`` resumes the stored campaign, and only that one: options not given
take the stored values, a different grid is refused.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from daq.errors import InputError
from daq.io.jsonout import print_json

if TYPE_CHECKING:
    from daq.analysis.campaign.state import CampaignCfg

P_SEED = 28.539  # [N] paper 002 Fig. 5
# paper 002 names five thrusts P1..P5 and nine drum speeds v1..v9 but prints only P = 28.539 N and
# v0 = 0.0066 m/s (Fig. 5). Our choices: P x {0.5, 0.75, 1, 1.25, 1.5}; speeds roughly geometric
# from 2.2 to 30 mm/s through 6.6 mm/s (the paper's) and 12 mm/s (the rig's default), covering
# the steady-sliding band below the hump, the velocity-weakening band (self-excited vibration,
# ~6.6-20 mm/s) and steady sliding above it.
DEFAULT_THRUSTS = tuple(round(P_SEED * f, 3) for f in (0.5, 0.75, 1.0, 1.25, 1.5))
DEFAULT_SPEEDS = (0.0022, 0.0033, 0.0044, 0.0066, 0.009, 0.012, 0.016, 0.022, 0.030)


def parse_list(text: str, flag: str, unit: str) -> list[float]:
    """'1,2.5,3' -> floats > 0, distinct; InputError naming the flag and the item."""
    items = [x.strip() for x in text.split(",")]
    out: list[float] = []
    for i, x in enumerate(items):
        try:
            v = float(x)
        except ValueError:
            raise InputError(flag, f"{flag}[{i}]", f"not a number: {x!r}") from None
        if not (math.isfinite(v) and v > 0):
            raise InputError(flag, f"{flag}[{i}]", f"must be a finite value > 0 {unit}, got {x!r}")
        if v in out:
            raise InputError(flag, f"{flag}[{i}]", f"{x} given twice")
        out.append(v)
    if not out:
        raise InputError(flag, flag, "empty list")
    return out


def make_cfg(args: argparse.Namespace) -> CampaignCfg:
    """The campaign's settings from the command line (defaults: the full 5 x 9 grid)."""
    # heavy: imported when the command runs (start-up time of daq --help)
    from daq.analysis.campaign.state import CampaignCfg, cell_programme
    from daq.analysis.paper002.kinematics import V_MIN
    from daq.analysis.paper002.programme import HOLD_S, SWEEP_S
    from daq.config import load_rig, user_rig_file
    from daq.sim.effectset import parse_effect

    cfg = load_rig(args.rig)
    if cfg.rig != "drum-pendulum":
        raise InputError(args.rig, "rig", f"the drum campaign needs a drum-pendulum config, not {cfg.rig}")
    thrusts = parse_list(args.thrusts, "--thrusts", "N") if args.thrusts else list(DEFAULT_THRUSTS)
    speeds = parse_list(args.speeds, "--speeds", "m/s") if args.speeds else list(DEFAULT_SPEEDS)
    hold = HOLD_S if args.hold is None else args.hold
    sweep = SWEEP_S if args.sweep is None else args.sweep
    ts = 1.0 if args.time_scale is None else args.time_scale
    for flag, v in (("--hold", hold), ("--sweep", sweep), ("--time-scale", ts)):
        if not (math.isfinite(v) and v > 0):
            raise InputError(flag, flag, f"must be > 0, got {v}")
    if ts > 1:
        raise InputError("--time-scale", "--time-scale", "must be in (0, 1]: it compresses the programme")
    for e in args.effect:
        parse_effect(e, "--effect")
    if args.effect and not args.sim:
        raise InputError("--effect", "--sim", "hidden effects need the simulated rig (--sim)")
    if not args.sim and not args.endpoint:
        raise InputError("--endpoint", "--endpoint", "real hardware: start `daq daemon --rig CONFIG.toml` and pass "
                         "its control endpoint, or run against the simulated rig with --sim")
    rig = user_rig_file(args.rig) or args.rig
    c = CampaignCfg(rig=rig, thrusts_N=thrusts, speeds_m_per_s=speeds, hold_s=hold, sweep_s=sweep, time_scale=ts,
                    sim=bool(args.sim), effects=list(args.effect), endpoint=args.endpoint,
                    v_min_m_per_s=V_MIN, cell_figures=not args.no_cell_figures)
    for v in speeds:  # every programme must be runnable before the first one starts
        cell_programme(c, v, cfg)
    return c


def _say_factory(tty: bool) -> Callable[..., None]:
    state = {"transient": False}

    def say(msg: str, transient: bool = False) -> None:
        if tty and transient:
            print("\r" + msg[:160].ljust(160), end="", file=sys.stderr, flush=True)
            state["transient"] = True
            return
        if state["transient"]:
            print(file=sys.stderr)
            state["transient"] = False
        print(msg, file=sys.stderr, flush=True)
    return say


def _confirm_factory(yes: bool, say: Callable[[str], None]) -> Callable[[float], None]:
    def confirm(thrust: float) -> None:
        msg = (f"campaign: set the thrust of the friction element to P = {thrust:g} N (screw 5, read it on "
               "strain gauge B: `daq ctl status`)")
        if yes:
            say(msg + " -- confirmed in advance (--yes)")
            return
        say(msg + ", then press Enter (Ctrl-C stops; the campaign can be resumed)")
        line = sys.stdin.readline()
        if not line:
            raise InputError("stdin", "confirmation", "no operator at the terminal (end of input); pass --yes if the "
                             "thrust is set by other means")
    return confirm


def cmd_campaign_drum(args: argparse.Namespace) -> int:
    # heavy: imported when the command runs (start-up time of daq --help)
    from daq.analysis.campaign.run import Campaign, Interrupted, hms
    from daq.analysis.campaign.state import STATE, load_state, new_state
    from daq.analysis.campaign.table import grid_figures, table_rows, write_table

    out = Path(args.out).absolute()
    state_path = out / STATE
    tty = sys.stderr.isatty()
    say = _say_factory(tty)
    if state_path.exists():
        st = load_state(state_path)
        given = make_cfg(_with_stored(args, st.cfg))
        _check_same(st.cfg, given)
        st.cfg = given
    else:
        if args.resume:
            raise InputError(str(state_path), "(file)", "no campaign to resume in this --out")
        st = new_state(make_cfg(args))
        out.mkdir(parents=True, exist_ok=True)
    camp = Campaign(out, st, say=say, confirm=None if st.cfg.sim else _confirm_factory(args.yes, say), tty=tty)

    def on_signal(signum, frame):  # noqa: ARG001
        camp.stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    t0 = time.monotonic()
    try:
        camp.prepare()
        n = len(st.cells)
        say(f"campaign: {len(st.cfg.thrusts_N)} thrusts x {len(st.cfg.speeds_m_per_s)} drum speeds = {n} cells -> "
            f"{out} (state: {state_path.name})")
        camp.run()
    except Interrupted:
        say(f"campaign: interrupted; state saved in {state_path}; rerun the same command (or --resume) to continue")
        return 130
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    csv_path, json_path = write_table(out, st)
    figs = grid_figures(out, st)
    done = sum(1 for c in st.cells if c.status == "done")
    failed = [c.key for c in st.cells if c.status == "failed"]
    summary = {"out": str(out), "state": str(state_path), "cells": len(st.cells), "done": done, "failed": failed,
               "table_csv": str(csv_path), "table_json": str(json_path), "figures": [str(p) for p in figs],
               "seconds": time.monotonic() - t0, "rows": table_rows(st)}
    if args.json:
        print_json(summary)
    else:
        say(f"campaign: {done}/{len(st.cells)} cells done in {hms(summary['seconds'])}"
            + (f"; failed: {', '.join(failed)} (rerun to retry)" if failed else "")
            + f"; table {csv_path}, figure {figs[0]}")
    return 0 if not failed else 1


def _with_stored(args: argparse.Namespace, c: CampaignCfg) -> argparse.Namespace:
    """Options not given on this command line take the stored campaign's values."""
    a = argparse.Namespace(**vars(args))
    if a.thrusts is None:
        a.thrusts = ",".join(repr(x) for x in c.thrusts_N)
    if a.speeds is None:
        a.speeds = ",".join(repr(x) for x in c.speeds_m_per_s)
    a.hold = c.hold_s if a.hold is None else a.hold
    a.sweep = c.sweep_s if a.sweep is None else a.sweep
    a.time_scale = c.time_scale if a.time_scale is None else a.time_scale
    if a.rig_given is False:
        a.rig = c.rig
    if not a.sim and not a.endpoint:
        a.sim = c.sim
        a.endpoint = c.endpoint
    if not a.effect:
        a.effect = list(c.effects)
    return a


def _check_same(stored: CampaignCfg, given: CampaignCfg) -> None:
    """A resume must run the stored grid: anything else would mix incomparable cells."""
    for field, flag in (("thrusts_N", "--thrusts"), ("speeds_m_per_s", "--speeds"), ("hold_s", "--hold"),
                        ("sweep_s", "--sweep"), ("time_scale", "--time-scale"), ("rig", "--rig"), ("sim", "--sim"),
                        ("effects", "--effect")):
        a, b = getattr(stored, field), getattr(given, field)
        if a != b:
            raise InputError(flag, flag, f"this --out holds a campaign with {field} = {a}, not {b}: "
                             "resume it as it was, or use another --out")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("campaign", help="run an identification campaign over a grid through the daemon")
    cs = p.add_subparsers(dest="campaign", required=True, metavar="CAMPAIGN")
    d = cs.add_parser("drum", help="paper 002: thrusts x drum speeds, law (3) A-E per cell (resumable)")
    d.add_argument("--rig", default=None, help="drum-pendulum config id or TOML (default drum-pendulum)")
    d.add_argument("--thrusts", help=f"thrusts P [N], comma-separated (default {','.join(map(str, DEFAULT_THRUSTS))})")
    d.add_argument("--speeds", help="drum surface speeds v0 [m/s], comma-separated "
                   f"(default {','.join(map(str, DEFAULT_SPEEDS))})")
    d.add_argument("--hold", type=float, help="seconds at v0 in each cell's programme (default 10)")
    d.add_argument("--sweep", type=float, help="seconds of the speed sweep after the hold (default 30)")
    d.add_argument("--time-scale", type=float, help="multiply the programme's durations (<= 1; default 1)")
    d.add_argument("--out", required=True, help="campaign folder (state, recordings, table, figures)")
    d.add_argument("--sim", action="store_true", help="simulated rig: one `daq daemon --sim` per thrust row")
    d.add_argument("--effect", action="append", default=[], metavar="NAME[:k=v,...]",
                   help="hidden effect of the simulated rig (repeatable; --sim only)")
    d.add_argument("--endpoint", help="real hardware: the control endpoint of the operator's running daemon")
    d.add_argument("--yes", action="store_true", help="real hardware: do not ask before each thrust row")
    d.add_argument("--resume", action="store_true", help="continue the campaign in --out (rerunning does the same)")
    d.add_argument("--no-cell-figures", action="store_true", help="skip the three figures per cell")
    d.add_argument("--json", action="store_true", help="one JSON summary on stdout at the end")
    d.set_defaults(func=_cmd)


def _cmd(args: argparse.Namespace) -> int:
    args.rig_given = args.rig is not None
    if args.rig is None:
        args.rig = "drum-pendulum"
    return cmd_campaign_drum(args)
