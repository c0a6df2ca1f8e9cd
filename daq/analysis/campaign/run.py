"""The drum campaign's run loop: row by row, cell by cell, through the daemon, the state saved after every step.

Each cell (thrust P, drum speed v0) is one scripted ramp (``daq.analysis.paper002.programme.cell_ramp``)
recorded by the daemon into its own file, then analysed (``drum-mu``: mu(t) by eq. (2), law (3) A-E
with standard errors and R^2). Rerunning into the same ``--out`` (or ``--resume``) skips finished
cells and redoes an interrupted one; its partial recording is moved to ``OUT/partial/`` (kept, never
analysed). On real hardware the operator runs ``daq daemon --rig CONFIG.toml`` and the campaign
talks to its ``--endpoint``; before each thrust row it asks for the thrust to be set (``confirm``),
and every cell reports the thrust gauge's mean.
"""

from __future__ import annotations

import shutil
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import tomli_w

from daq.analysis.paper002.analysis import analyse_drum_mu
from daq.analysis.paper002.figures import figures
from daq.config import load_rig
from daq.daemon.control import ControlClient
from daq.errors import DaqError, InputError
from daq.io.files import atomic_path

from .state import STATE, CampaignState, Cell, CellCoef, CellResult, cell_programme, row_config, save_state, utc_now
from .supervision import DaemonRow, end_stale

RAMP_ACTIVE = ("idle", "lead-in", "running")


class Interrupted(DaqError):
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
        cell.started, cell.finished, cell.error = utc_now(), None, None
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
            cell.status, cell.error, cell.finished = "failed", f"analysis: {exc}", utc_now()
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
        cell.report, cell.status, cell.finished = str(rep), "done", utc_now()
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
                         f"{(belt or 0) * 1e3:5.1f} mm/s  campaign ETA {hms(left)}", transient=True)
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


def hms(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"
