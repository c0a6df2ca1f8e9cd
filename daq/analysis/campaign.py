"""``daq campaign drum``: paper 002's grid of thrusts x drum speeds, run through the daemon, resumable.

Why a module of its own: a campaign is hours of unattended rig time, so it is state, not a loop.
Each cell (thrust P, drum speed v0) is one scripted ramp (``daq.analysis.paper002.cell_ramp``)
recorded by the daemon into its own file, then analysed (``drum-mu``: mu(t) by eq. (2), law (3)
A-E with standard errors and R^2); after each cell the state file ``OUT/campaign.json`` is
rewritten atomically (temporary file + rename), so a kill at any instant leaves either the old
or the new state. Rerunning into the same ``--out`` (or ``--resume``) skips finished cells and
redoes an interrupted one; its partial recording is moved to ``OUT/partial/`` (kept, never
analysed).

Thrust: on paper 002's stand the thrust is set with a screw (element 5) and read by strain
gauge B. Simulated (``--sim``), each thrust row gets a copy of the rig config with
``mechanics.thrust_N = P`` and its own ``daq daemon --rig COPY.toml --sim``. On real hardware
the operator runs ``daq daemon --rig CONFIG.toml`` and passes ``--endpoint``; before each thrust
row the campaign asks on the terminal for the thrust to be set (``--yes``: it already is, or is
set by other means), and every cell reports the thrust gauge's mean.

Layout of OUT: campaign.json (state), rigs/ (config per thrust row), ramps/ (programme per
cell), recordings/ (one run file per cell), cells/<cell>/ (drum-mu.json and figures), partial/,
logs/ (daemon output), table.csv, table.json, coefficients.png, r2.png.
"""

from __future__ import annotations

import argparse
import csv
import ctypes
import datetime as _dt
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
import zlib
from pathlib import Path
from typing import Any, Callable, Literal

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import tomli_w
from matplotlib.ticker import FixedLocator, NullFormatter, NullLocator
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from daq.config import config_text, load_rig
from daq.daemon.control import ControlClient
from daq.errors import InputError
from daq.io.interchange import atomic_path
from daq.ramps import check_limits, ramp_table
from daq.sim.effectset import parse_effect
from sim_backends.process import request as sim_request

from .paper002 import HOLD_S, SWEEP_S, UNITS, V_MIN, _save, analyse_drum_mu, cell_ramp, figures

FORMAT = "friction-daq drum campaign 1"
STATE = "campaign.json"
P_SEED = 28.539  # [N] paper 002 Fig. 5
# paper 002 names five thrusts P1..P5 and nine drum speeds v1..v9 but prints only P = 28.539 N and
# v0 = 0.0066 m/s (Fig. 5). Our choices: P x {0.5, 0.75, 1, 1.25, 1.5}; speeds roughly geometric
# from 2.2 to 30 mm/s through 6.6 mm/s (the paper's) and 12 mm/s (the rig's default), covering
# the steady-sliding band below the hump, the velocity-weakening band (self-excited vibration,
# ~6.6-20 mm/s) and steady sliding above it.
DEFAULT_THRUSTS = tuple(round(P_SEED * f, 3) for f in (0.5, 0.75, 1.0, 1.25, 1.5))
DEFAULT_SPEEDS = (0.0022, 0.0033, 0.0044, 0.0066, 0.009, 0.012, 0.016, 0.022, 0.030)
RAMP_ACTIVE = ("idle", "lead-in", "running")
START_TIMEOUT_S = 180.0  # daemon start (numba caches on a cold machine)
ROOT = Path(__file__).resolve().parent.parent


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


# ----------------------------------------------------------------------------- state (pydantic, JSON)


class CampaignCfg(BaseModel):
    """What the campaign runs; stored in the state so a resume runs the very same grid."""

    model_config = ConfigDict(extra="forbid")
    rig: str = Field(description="rig config (id or TOML path) the thrust rows are copies of")
    thrusts_N: list[float]
    speeds_m_per_s: list[float]
    hold_s: float
    sweep_s: float
    time_scale: float
    sim: bool
    effects: list[str] = Field(default_factory=list)
    endpoint: str | None = None
    v_min_m_per_s: float
    cell_figures: bool = True


class CellCoef(BaseModel):
    model_config = ConfigDict(extra="forbid")
    value: float
    se: float | None
    identified: bool


class CellResult(BaseModel):
    model_config = ConfigDict(extra="forbid")
    coefficients: dict[str, CellCoef]
    R2: float
    rms: float
    n: int
    n_eff: float
    thrust_measured_N: float
    v_range_m_per_s: tuple[float, float]


class Cell(BaseModel):
    model_config = ConfigDict(extra="forbid")
    key: str
    thrust_N: float
    v0_m_per_s: float
    status: Literal["pending", "running", "interrupted", "done", "failed"] = "pending"
    attempts: int = 0
    recording: str | None = None
    ramp: str | None = None
    report: str | None = None
    started: str | None = None
    finished: str | None = None
    wall_s: float | None = None
    result: CellResult | None = None
    error: str | None = None
    partial: list[str] = Field(default_factory=list, description="recordings of interrupted attempts, kept aside")


class DaemonInfo(BaseModel):
    """The daemon (and simulated bench) this campaign started, so a resume after a kill can end them."""

    model_config = ConfigDict(extra="forbid")
    pid: int
    control: str
    sim_bench_pid: int | None = None
    sim_control: str | None = None
    thrust_N: float


class CampaignState(BaseModel):
    model_config = ConfigDict(extra="forbid")
    format: str = FORMAT
    cfg: CampaignCfg
    cells: list[Cell]
    daemon: DaemonInfo | None = Field(None, description="the daemon running now (None between rows)")
    daemons: list[DaemonInfo] = Field(default_factory=list, description="every daemon this campaign started")
    created: str
    updated: str
    runs: int = 0


def cell_key(thrust: float, v0: float) -> str:
    return f"P{thrust:g}N_v{v0 * 1e3:g}mm"


def save_state(path: Path, st: CampaignState) -> None:
    """Write the state atomically: a kill leaves the previous or the new file, never half of one."""

    st.updated = _now()
    with atomic_path(path) as tmp:
        with open(tmp, "w") as fh:
            fh.write(st.model_dump_json(indent=2))
            fh.flush()
            os.fsync(fh.fileno())


def load_state(path: Path) -> CampaignState:
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise InputError(str(path), "(file)", exc.strerror or str(exc)) from None
    except json.JSONDecodeError as exc:
        raise InputError(str(path), f"line {exc.lineno}", f"not JSON: {exc.msg}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(str(path), "format", f"not a drum campaign state (expected {FORMAT!r})")
    try:
        return CampaignState.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = ".".join(str(x) for x in err["loc"]) or "(root)"
        raise InputError(str(path), field, err["msg"]) from None


# ----------------------------------------------------------------------------- grid and config


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
    rig = str(Path(args.rig).resolve()) if Path(args.rig).suffix else args.rig
    c = CampaignCfg(rig=rig, thrusts_N=thrusts, speeds_m_per_s=speeds, hold_s=hold, sweep_s=sweep, time_scale=ts,
                    sim=bool(args.sim), effects=list(args.effect), endpoint=args.endpoint,
                    v_min_m_per_s=V_MIN, cell_figures=not args.no_cell_figures)
    for v in speeds:  # every programme must be runnable before the first one starts
        cell_programme(c, v, cfg)
    return c


def cell_programme(c: CampaignCfg, v0: float, rig=None):
    """One cell's Ramp, checked against the rig's drive limits (InputError naming --speeds)."""

    rig = rig or load_rig(c.rig)
    d = rig.drive
    if v0 > d.max_speed_m_per_s:
        raise InputError("--speeds", "--speeds", f"{v0:g} m/s exceeds the drive limit {d.max_speed_m_per_s} m/s")
    ramp = cell_ramp(v0, hold_s=c.hold_s, sweep_s=c.sweep_s, time_scale=c.time_scale,
                     max_accel=d.max_accel_m_per_s2, max_speed=d.max_speed_m_per_s)
    rt, rv = ramp_table(ramp, "--speeds")
    check_limits(rt, rv, d.max_speed_m_per_s, d.max_accel_m_per_s2, "--speeds")
    return ramp


def new_state(c: CampaignCfg) -> CampaignState:
    cells = [Cell(key=cell_key(p, v), thrust_N=p, v0_m_per_s=v) for p in c.thrusts_N for v in c.speeds_m_per_s]
    return CampaignState(cfg=c, cells=cells, created=_now(), updated=_now())


def row_config(c: CampaignCfg, thrust: float, out: Path) -> Path:
    """A copy of the rig config with mechanics.thrust_N = P (what a thrust row's daemon runs)."""

    cfg = load_rig(c.rig)
    cfg = cfg.model_copy(update={"mechanics": cfg.mechanics.model_copy(update={"thrust_N": float(thrust)})})
    path = out / "rigs" / f"{cfg.rig}-P{thrust:g}N.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    text = config_text(cfg)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return path


# ----------------------------------------------------------------------------- processes


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM when the campaign dies (even by kill -9), so the daemon
    ramps the drum down and closes its recording instead of running on as an orphan (Linux)."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def _alive(pid: int | None) -> bool:
    if not pid:
        return False
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, PermissionError):
        return False
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return True


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode("utf-8", "replace")
    except OSError:
        return ""


def _wait_gone(pid: int | None, timeout: float) -> bool:
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if not _alive(pid):
            return True
        time.sleep(0.1)
    return not _alive(pid)


def end_stale(info: DaemonInfo | None, say: Callable[[str], None]) -> None:
    """End the daemon and bench a killed campaign left (by their recorded ids, only if they are ours)."""
    if info is None:
        return

    if _alive(info.pid) and "daemon" in _cmdline(info.pid):
        say(f"campaign: waiting for the daemon of the interrupted run (pid {info.pid}) to ramp down and exit")
        if not _wait_gone(info.pid, 2.0):  # it got SIGTERM from the kernel when we died; give it time
            os.kill(info.pid, signal.SIGTERM)
            if not _wait_gone(info.pid, 30.0):
                os.kill(info.pid, signal.SIGKILL)
                _wait_gone(info.pid, 5.0)
    bench = info.sim_bench_pid
    if bench and _alive(bench) and "sim_backends" in _cmdline(bench) and not _wait_gone(bench, 5.0):
        if info.sim_control:
            try:
                sim_request(info.sim_control, "exit", timeout_s=1.0)
            except TimeoutError:
                pass
        if not _wait_gone(bench, 5.0):
            os.kill(bench, signal.SIGKILL)


class DaemonRow:
    """``daq daemon --rig ROW.toml --sim`` for one thrust row, on free loopback ports."""

    def __init__(self, rig_toml: Path, out: Path, effects: list[str], tag: str) -> None:
        logs = out / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        stamp = time.strftime("%Y%m%d-%H%M%S")
        self.log_path = logs / f"daemon-{tag}-{stamp}.log"
        cmd = [sys.executable, "-m", "daq.cli", "daemon", "--rig", str(rig_toml), "--sim",
               "--data-dir", str(out / "recordings"), "--control", "tcp://127.0.0.1:0", "--bus", "tcp://127.0.0.1:0",
               "--workdir", str(out / "dev" / f"{tag}-{stamp}-{os.getpid()}"),
               "--seed", str(zlib.crc32(tag.encode()) & 0x7FFFFFFF)]  # each row's instruments: their own noise
        for e in effects:
            cmd += ["--effect", e]
        # output to a file, not a pipe: a daemon whose campaign was killed must not die of a broken pipe
        with open(self.log_path, "a") as log:
            self.proc = subprocess.Popen(cmd, cwd=str(ROOT), stdout=log, stderr=subprocess.STDOUT,
                                         stdin=subprocess.DEVNULL, preexec_fn=_die_with_parent)
        line = ""
        t_end = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < t_end and self.proc.poll() is None:
            line = next((x for x in self.log_path.read_text().splitlines() if "daq daemon: ready" in x), "")
            if line:
                break
            time.sleep(0.1)
        if not line:
            if self.proc.poll() is None:
                self.proc.kill()
            self.proc.wait(10)
            raise RuntimeError(f"daemon did not start (exit status {self.proc.poll()}; see {self.log_path})")
        fields = dict(re.findall(r"(\w+)=(\S+)", line))
        self.control = fields["control"]
        self.sim_control = fields.get("sim_control")
        self.sim_pid = int(fields["sim_bench_pid"]) if "sim_bench_pid" in fields else None

    def info(self, thrust: float) -> DaemonInfo:
        return DaemonInfo(pid=self.proc.pid, control=self.control, sim_bench_pid=self.sim_pid,
                          sim_control=self.sim_control, thrust_N=thrust)

    def close(self) -> None:
        """SIGTERM (the daemon ramps down and closes any recording), then end the simulated bench."""

        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        # the daemon ends its bench as it shuts down; ask it ourselves only if it is still there
        if self.sim_pid and not _wait_gone(self.sim_pid, 5.0):
            if self.sim_control:
                try:
                    sim_request(self.sim_control, "exit", timeout_s=1.0)
                except TimeoutError:
                    pass
            if not _wait_gone(self.sim_pid, 5.0):
                os.kill(self.sim_pid, signal.SIGKILL)


# ----------------------------------------------------------------------------- the run


class Interrupted(Exception):
    """SIGINT/SIGTERM: stop after a controlled ramp-down; the state says where."""


class Campaign:
    """Runs the pending cells of a state, row by row, saving the state after every step."""

    def __init__(self, out: Path, state: CampaignState, *, say: Callable[[str], None],
                 confirm: Callable[[float], None] | None = None, tty: bool = False) -> None:
        self.out = out
        self.st = state
        self.path = out / STATE
        self.say = say
        self.confirm = confirm
        self.tty = tty
        self.stop = threading.Event()
        self.cell_walls: list[float] = []
        self.row_start_s: list[float] = []

    # --- bookkeeping
    def save(self) -> None:
        save_state(self.path, self.st)

    def _aside(self, cell: Cell) -> None:
        """An interrupted attempt's recording goes to partial/ (kept, not trusted); the cell is redone."""
        if cell.recording and Path(cell.recording).exists():
            dst = self.out / "partial" / f"{Path(cell.recording).stem}.attempt{cell.attempts}.h5"
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.move(cell.recording, dst)
            cell.partial.append(str(dst))
            self.say(f"campaign: {cell.key}: interrupted attempt {cell.attempts}; its recording kept aside in {dst}")
        cell.status, cell.recording, cell.result, cell.error = "pending", None, None, None

    def prepare(self) -> None:
        """After a kill or an interrupt: end what the last run left, put partial recordings aside."""
        end_stale(self.st.daemon, self.say)
        self.st.daemon = None
        for c in self.st.cells:
            if c.status in ("running", "interrupted", "failed"):
                self._aside(c)
        self.st.runs += 1
        self.save()

    def pending(self) -> list[Cell]:
        return [c for c in self.st.cells if c.status != "done"]

    def eta(self, remaining_cells: int, remaining_rows: int, programme_s: float) -> float:
        per_cell = float(np.mean(self.cell_walls)) if self.cell_walls else programme_s + 8.0
        per_row = float(np.mean(self.row_start_s)) if self.row_start_s else 10.0
        return remaining_cells * per_cell + remaining_rows * per_row

    # --- main loop
    def run(self) -> CampaignState:

        c = self.st.cfg
        rig = load_rig(c.rig)
        todo = self.pending()
        n_total, n_done0 = len(self.st.cells), len(self.st.cells) - len(todo)
        if n_done0:
            self.say(f"campaign: resuming: {n_done0}/{n_total} cells finished, {len(todo)} to run")
        rows = [p for p in c.thrusts_N if any(x.thrust_N == p for x in todo)]
        prog_s = {v: _programme_s(cell_programme(c, v, rig)) for v in c.speeds_m_per_s}
        k = n_done0
        for ri, thrust in enumerate(rows):
            cells = [x for x in todo if x.thrust_N == thrust]
            daemon = None
            t_row = time.monotonic()
            try:
                if c.sim:
                    toml = row_config(c, thrust, self.out)
                    self.say(f"campaign: thrust row P = {thrust:g} N: starting daq daemon --rig {toml.name} --sim")
                    daemon = DaemonRow(toml, self.out, c.effects, f"P{thrust:g}N")
                    self.st.daemon = daemon.info(thrust)
                    self.st.daemons.append(self.st.daemon)
                    self.save()
                    endpoint = daemon.control
                else:
                    if self.confirm is not None:
                        self.confirm(thrust)
                    endpoint = c.endpoint
                self.row_start_s.append(time.monotonic() - t_row)
                for cell in cells:
                    if self.stop.is_set():
                        raise Interrupted()
                    k += 1
                    remaining = sum(1 for x in todo if x.status != "done") - 1
                    eta = self.eta(remaining, len(rows) - ri - 1, prog_s[cell.v0_m_per_s])
                    self.run_cell(cell, endpoint, f"cell {k}/{n_total}", prog_s[cell.v0_m_per_s], eta)
            finally:
                if daemon is not None:
                    daemon.close()
                    self.st.daemon = None
                    self.save()
        return self.st

    def run_cell(self, cell: Cell, endpoint: str, label: str, programme_s: float, eta_rest: float) -> None:


        c = self.st.cfg
        ramp = cell_programme(c, cell.v0_m_per_s)
        ramp_path = self.out / "ramps" / f"{cell.key}.toml"
        ramp_path.parent.mkdir(parents=True, exist_ok=True)
        ramp_path.write_text(tomli_w.dumps(ramp.model_dump(mode="json", exclude_none=True)))
        rec = self.out / "recordings" / f"{cell.key}.h5"
        rec.parent.mkdir(parents=True, exist_ok=True)
        if rec.exists():  # left by a run that died before it could note the cell as running
            dst = self.out / "partial" / f"{rec.stem}.orphan-{int(time.time())}.h5"
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.move(str(rec), dst)
            cell.partial.append(str(dst))
        cell.status, cell.attempts, cell.recording, cell.ramp = "running", cell.attempts + 1, str(rec), str(ramp_path)
        cell.started, cell.finished, cell.error = _now(), None, None
        self.save()
        t0 = time.monotonic()
        head = f"campaign: {label}  P = {cell.thrust_N:g} N  v0 = {cell.v0_m_per_s * 1e3:g} mm/s"
        self.say(f"{head}: recording {rec.name} ({programme_s:.1f} s programme)")
        client = ControlClient(endpoint, timeout_s=20.0)
        try:
            self._call(client, "record_start", path=str(rec))
            self._call(client, "ramp", file=str(ramp_path), time_scale=1.0)
            state = self._follow(client, str(ramp_path), head, t0, programme_s, eta_rest)
            self._wait_rest(client)
            time.sleep(0.3)  # the ramp-down's last samples reach the recorder
            self._call(client, "record_stop")
            if state != "finished":
                raise RuntimeError(f"ramp ended '{state}'")
        except Interrupted:
            self._abort(client)
            cell.status = "interrupted"
            cell.error = "interrupted by signal"
            self.save()
            raise
        except Exception as exc:  # noqa: BLE001 - a failed cell is noted; the campaign goes on
            self._abort(client)
            cell.status, cell.error = "failed", f"{type(exc).__name__}: {exc}"
            cell.wall_s = time.monotonic() - t0
            self.save()
            self.say(f"{head}: FAILED: {cell.error}")
            return
        finally:
            client.close()
        self.analyse(cell, rec, head)
        cell.wall_s = time.monotonic() - t0
        if cell.status == "done":
            self.cell_walls.append(cell.wall_s)
        self.save()

    def analyse(self, cell: Cell, rec: Path, head: str) -> None:

        try:
            res, series = analyse_drum_mu(rec, v_min=self.st.cfg.v_min_m_per_s)
        except (InputError, ValueError, RuntimeError) as exc:
            cell.status, cell.error, cell.finished = "failed", f"analysis: {exc}", _now()
            self.say(f"{head}: analysis FAILED: {exc}")
            return
        rep = self.out / "cells" / cell.key
        if self.st.cfg.cell_figures:
            res.figures = [str(p) for p in figures(res, series, rep)]
        rep.mkdir(parents=True, exist_ok=True)
        with atomic_path(rep / "drum-mu.json") as tmp:
            tmp.write_text(res.model_dump_json(indent=2))
        f = res.fit
        cell.result = CellResult(
            coefficients={k: CellCoef(value=v.value, se=v.se, identified=v.identified)
                          for k, v in f.coefficients.items()},
            R2=f.R2, rms=f.rms, n=f.n, n_eff=f.n_eff, thrust_measured_N=res.thrust_N["mean"],
            v_range_m_per_s=f.v_range_m_per_s)
        cell.report, cell.status, cell.finished = str(rep), "done", _now()
        co = f.coefficients
        self.say(f"{head}: done: A={co['A'].value:.4g} B={co['B'].value:.4g} C={co['C'].value:.4g} "
                 f"D={co['D'].value:.4g} E={co['E'].value:.4g} R²={f.R2:.4f} (N = {res.thrust_N['mean']:.2f} N)")

    # --- daemon conversation
    def _call(self, client, op: str, **kw: Any) -> dict:
        try:
            r = client.request(op, **kw)
        except TimeoutError:
            raise RuntimeError(f"the daemon did not answer {op!r}") from None
        if not r.ok:
            raise RuntimeError(f"{op}: {r.error}")
        return r.result or {}

    def _follow(self, client, source: str, head: str, t0: float, programme_s: float, eta_rest: float) -> str:
        last = 0.0
        while True:
            if self.stop.is_set():
                raise Interrupted()
            st = self._call(client, "status")
            ramp = st.get("ramp") or {}
            if ramp.get("source") == source and ramp.get("state") not in RAMP_ACTIVE:
                return str(ramp.get("state"))
            now = time.monotonic()
            if ramp and (now - last >= (0.5 if self.tty else 5.0)):
                left = max(programme_s - (now - t0), 0.0) + eta_rest
                belt = (st.get("belt") or {}).get("measured")
                self.say(f"{head}: ramp {100 * ramp.get('fraction', 0):3.0f} %  drum "
                         f"{(belt or 0) * 1e3:5.1f} mm/s  campaign ETA {_hms(left)}", transient=True)
                last = now
            time.sleep(0.2)

    def _wait_rest(self, client, timeout: float = 15.0) -> None:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            belt = (self._call(client, "status").get("belt") or {}).get("measured")
            if belt is not None and abs(belt) < 5e-3:
                return
            time.sleep(0.1)

    def _abort(self, client) -> None:
        """Controlled stop and close the recording; errors here only mean there is nothing to stop."""
        for op in ("stop", "record_stop"):
            try:
                client.request(op)
            except Exception:  # noqa: BLE001
                pass


def _programme_s(ramp) -> float:
    return float(sum(s.duration_s or 0.0 for s in ramp.segment))


def _hms(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


# ----------------------------------------------------------------------------- table and figures


COLUMNS = ("thrust_N", "v0_m_per_s", "status", "A", "A_se", "B", "B_se", "C", "C_se", "D", "D_se", "E", "E_se",
           "R2", "n", "thrust_measured_N", "recording")


def table_rows(st: CampaignState) -> list[dict[str, Any]]:
    rows = []
    for c in st.cells:
        r: dict[str, Any] = {"thrust_N": c.thrust_N, "v0_m_per_s": c.v0_m_per_s, "status": c.status}
        res = c.result
        for k in ("A", "B", "C", "D", "E"):
            r[k] = res.coefficients[k].value if res else None
            r[f"{k}_se"] = res.coefficients[k].se if res else None
        r["R2"] = res.R2 if res else None
        r["n"] = res.n if res else None
        r["thrust_measured_N"] = res.thrust_measured_N if res else None
        r["recording"] = c.recording
        rows.append(r)
    return rows


def write_table(out: Path, st: CampaignState) -> tuple[Path, Path]:


    rows = table_rows(st)
    csv_path, json_path = out / "table.csv", out / "table.json"
    with atomic_path(csv_path) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=COLUMNS)
            w.writeheader()
            for r in rows:
                w.writerow({k: ("" if v is None else v) for k, v in r.items()})
    with atomic_path(json_path) as tmp:
        tmp.write_text(json.dumps({"law": "mu(v) = A [1 - exp(-B v)] exp(-C v) + D v + E", "cells": rows}, indent=2))
    return csv_path, json_path


def _config_law(c: CampaignCfg) -> dict[str, float]:
    """The simulated rig's own law (3): its config's A, B, C, E and the seed effect's D (reference lines)."""

    cfg = load_rig(c.rig)
    f = cfg.friction
    d = float((cfg.seed_effects.get("velocity-strengthening") or {}).get("D", 0.0))
    return {"A": f.A, "B": f.B_s_per_m, "C": f.C_s_per_m, "D": d, "E": f.E}


def grid_figures(out: Path, st: CampaignState) -> list[Path]:
    """A-E against drum speed, one line per thrust, error bars = 1 standard error; R^2 likewise."""

    matplotlib.use("Agg")


    c = st.cfg
    done = [x for x in st.cells if x.status == "done" and x.result is not None]
    colors = plt.cm.viridis(np.linspace(0, 0.85, max(len(c.thrusts_N), 1)))
    nominal = _config_law(c) if c.sim else {}
    fig, axs = plt.subplots(2, 3, figsize=(15, 8.5), constrained_layout=True)
    names = ("A", "B", "C", "D", "E", "R2")
    n_rows = len(c.thrusts_N)
    for ax, name in zip(axs.flat, names):
        for i, (color, p) in enumerate(zip(colors, c.thrusts_N)):
            cells = sorted((x for x in done if x.thrust_N == p), key=lambda x: x.v0_m_per_s)
            if not cells:
                continue
            dodge = 10 ** (0.012 * (i - (n_rows - 1) / 2))  # side by side, so the error bars stay readable
            v = np.array([x.v0_m_per_s * 1e3 for x in cells]) * dodge
            if name == "R2":
                y = np.array([x.result.R2 for x in cells])
                ax.plot(v, y, "o-", color=color, label=f"P = {p:g} N")
                continue
            y = np.array([x.result.coefficients[name].value for x in cells])
            e = np.array([x.result.coefficients[name].se or np.nan for x in cells])
            ok = np.array([x.result.coefficients[name].identified for x in cells])
            ax.errorbar(v, y, yerr=e, color=color, lw=1, capsize=3, marker=None, label=f"P = {p:g} N")
            ax.plot(v[ok], y[ok], "o", color=color)
            ax.plot(v[~ok], y[~ok], "o", mfc="white", color=color)
        if name in nominal:
            ax.axhline(nominal[name], color="0.4", ls="--", lw=1, label="simulated rig's law (config)")
        if name != "R2" and done:  # a cell with a huge error bar, or not identified, must not flatten the others
            scaled = [x for x in done if x.result.coefficients[name].identified] or done
            ys = np.array([x.result.coefficients[name].value for x in scaled]
                          + ([nominal[name]] if name in nominal else []))
            ses = np.array([x.result.coefficients[name].se or 0.0 for x in scaled])
            pad = 2.5 * float(np.median(ses)) + 0.05 * float(np.ptp(ys)) + 1e-12
            lo_y, hi_y = ys.min() - pad, ys.max() + pad
            ax.set_ylim(lo_y, hi_y)
            off = sum(1 for x in done if not lo_y <= x.result.coefficients[name].value <= hi_y)
            if off:
                ax.text(0.98, 0.97, f"{off} cell(s) off scale (not identified)", transform=ax.transAxes,
                        fontsize=8, color="0.3", ha="right", va="top")
        ax.set_xscale("log")
        speeds = sorted(c.speeds_m_per_s)
        ax.set_xlim(speeds[0] * 1e3 / 1.25, speeds[-1] * 1e3 * 1.25)

        ax.xaxis.set_major_locator(FixedLocator([v * 1e3 for v in speeds]))
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda x, _: f"{x:g}"))
        ax.xaxis.set_minor_locator(NullLocator())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("drum speed v0 [mm/s] (log scale)")
        unit = "" if name == "R2" or UNITS[name] == "-" else f" [{UNITS[name]}]"
        ax.set_ylabel(("R²" if name == "R2" else name) + unit)
        ax.set_title("goodness of fit R²" if name == "R2" else f"law (3) coefficient {name}", fontsize=10)
        ax.grid(alpha=0.3)
    axs.flat[0].legend(fontsize=8)
    n_done = len(done)
    fig.suptitle(f"paper 002 campaign: law (3) μ(v) = A[1−exp(−Bv)]exp(−Cv) + Dv + E per (P, v0); "
                 f"{n_done}/{len(st.cells)} cells; bars = ±1 standard error, open markers: se > 25 %", fontsize=11)
    return [_save(fig, out / "coefficients.png")]


# ----------------------------------------------------------------------------- command line


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
        sys.stdout.write(json.dumps(summary, indent=2, default=float) + "\n")
    else:
        say(f"campaign: {done}/{len(st.cells)} cells done in {_hms(summary['seconds'])}"
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
