"""Execute a belt/drum speed programme on a motor regulator: the core of ``daq ctl ramp FILE``.

The programme is the piecewise-linear (t, v) table of ``daq.ramps`` (``ramp_table`` /
``load_ramp``). ``RampRunner`` checks it against the rig's drive limits *before* any
command reaches the regulator (a refused ramp raises ``InputError`` and never touches
the motor), sets the regulator's acceleration once so it can follow, brings the belt
to the programme's first speed (lead-in, recorded at t < 0), then streams set points
interpolated at the current time at ``rate_hz`` (>= 50 Hz, default 100 Hz) from its own
thread. Progress goes to a callback and ``progress()``; segment start/end events to
another callback; every set point sent is kept in ``history`` (t, vb_set, vb) so a
caller can publish or record ``vb_set`` beside the measured ``vb``.

Time scaling: ``RampRunnerCfg.time_scale`` multiplies the table's *times* (speeds
unchanged) before the limit check, e.g. ``time_scale = 3/45`` runs the paper-001 seed
ramp (V0 = 0.17 m/s, Tmax = 45 s) in 3 s. Accelerations grow by ``1/time_scale`` and
are checked on the scaled table, so a compression the drive cannot follow is refused.

Safety stays in the regulator (limits, watchdog, e-stop latch); the runner adds the
pre-motion check and, on a regulator error mid-ramp, a controlled stop attempt and a
recorded reason.

Decision record: docs/decisions/0014-safety-in-the-regulator.md.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field

from daq.errors import DaqError, InputError
from daq.ramps import Ramp, check_limits, load_ramp, ramp_table
from daq.strict import Closed
from drivers.motor import MotorDrive, MotorError, MotorUnavailable

State = Literal["idle", "lead-in", "running", "finished", "stopped", "estopped", "aborted"]


class RampRunnerCfg(Closed):
    """How a programme is executed (not what it is)."""

    model_config = ConfigDict(frozen=True)
    rate_hz: float = Field(100.0, ge=50.0, le=1000.0, description="set-point rate")
    at_end: Literal["hold", "stop"] = Field("stop", description="after the last point: hold its speed or STOP")
    time_scale: float = Field(1.0, gt=0.0, description="multiplies the table's times (speeds unchanged)")
    accel_m_per_s2: float | None = Field(None, gt=0.0, description="regulator ACC; default the rig's limit")
    measure_every: int = Field(1, ge=1, description="read the tachometer every N set points")
    lead_in_tol_m_per_s: float = Field(0.005, gt=0.0, description="lead-in done when |vb - v(0)| is below this")
    lead_in_timeout_s: float = Field(1.0, ge=0.0, description="extra lead-in time beyond |dv|/accel")


@dataclass(frozen=True)
class RampEvent:
    """A segment boundary or the end of the run, for the daemon's event stream."""

    kind: Literal["segment_start", "segment_end", "finished", "stopped", "estopped", "aborted"]
    t: float  # programme time [s] (scaled)
    index: int | None = None  # segment index
    segment: str | None = None  # segment kind (hold, linear, exponential, seed, table)
    reason: str = ""


@dataclass(frozen=True)
class RampProgress:
    """Where the run is, for status displays."""

    state: State
    t: float
    fraction: float
    segment: int
    commanded: float
    measured: float | None


def scale_times(rt: np.ndarray, factor: float) -> np.ndarray:
    """Time-scale a programme: t -> factor * t (speeds unchanged, accelerations / factor)."""
    return np.asarray(rt, dtype=float) * float(factor)


def segment_bounds(ramp: Ramp | None, rt: np.ndarray) -> tuple[list[str], np.ndarray]:
    """Segment kinds and start times (unscaled) from the Ramp's segments; a CSV table is one segment."""
    if ramp is None:
        return ["table"], np.array([float(rt[0])])
    kinds, starts, t = [], [], 0.0
    for seg in ramp.segment:
        kinds.append(seg.kind)
        starts.append(t)
        t += float(seg.duration_s if seg.duration_s is not None else (seg.Tmax_s or 0.0))
    return kinds, np.asarray(starts, dtype=float)


class RampRunner:
    """Streams a validated speed programme to a ``MotorDrive`` from its own thread."""

    def __init__(self, motor: MotorDrive, rt: np.ndarray, rv: np.ndarray, *, max_speed: float, max_accel: float,
                 ramp: Ramp | None = None, cfg: RampRunnerCfg | None = None, source: str = "ramp",
                 on_progress: Callable[[RampProgress], None] | None = None,
                 on_event: Callable[[RampEvent], None] | None = None) -> None:
        self.cfg = cfg or RampRunnerCfg()
        self.motor = motor
        self.source = source
        rt = np.asarray(rt, dtype=float)
        rv = np.asarray(rv, dtype=float)
        if rt.ndim != 1 or rt.shape != rv.shape or rt.size < 2:
            raise InputError(source, "t", "need a table of at least two (t, v) points")
        if np.any(np.diff(rt) < 0):
            raise InputError(source, "t", "times must not decrease")
        self.rt = scale_times(rt - rt[0], self.cfg.time_scale)
        self.rv = rv
        check_limits(self.rt, self.rv, max_speed, max_accel, source)  # before any motion
        accel = self.cfg.accel_m_per_s2 if self.cfg.accel_m_per_s2 is not None else max_accel
        if accel > max_accel * (1 + 1e-9):
            raise InputError(source, "accel_m_per_s2", f"{accel} exceeds the rig limit {max_accel} m/s^2")
        self.accel = float(accel)
        self.max_speed = max_speed
        kinds, starts = segment_bounds(ramp, rt)
        self.segment_kinds = kinds
        self.segment_starts = scale_times(starts, self.cfg.time_scale)
        self.duration = float(self.rt[-1])
        self.on_progress = on_progress
        self.on_event = on_event
        self.events: list[RampEvent] = []
        self.state: State = "idle"
        self.reason = ""
        self.error: BaseException | None = None
        self._hist_t: list[float] = []
        self._hist_set: list[float] = []
        self._hist_meas: list[float] = []
        self._hist_lock = threading.Lock()
        self._cmd_lock = threading.Lock()  # one set point at a time; stop() waits for the one in flight
        self._halt = threading.Event()
        self._halt_kind: Literal["stopped", "estopped"] | None = None
        self._thread: threading.Thread | None = None
        self._progress = RampProgress("idle", 0.0, 0.0, 0, float(self.rv[0]), None)

    # --- construction from files and ramps
    @classmethod
    def from_ramp(cls, motor: MotorDrive, ramp: Ramp, max_speed: float, max_accel: float,
                  **kw: object) -> "RampRunner":
        """Runner for a Ramp model (segments known, so segment events are exact)."""
        rt, rv = ramp_table(ramp, str(kw.get("source", "ramp")))
        return cls(motor, rt, rv, max_speed=max_speed, max_accel=max_accel, ramp=ramp, **kw)  # type: ignore[arg-type]

    @classmethod
    def from_file(cls, motor: MotorDrive, path: str | Path, max_speed: float, max_accel: float,
                  **kw: object) -> "RampRunner":
        """Runner for a ramp file (.toml segments or .csv table), as ``ctl ramp FILE`` gets it."""
        ramp, rt, rv = load_ramp(path)
        kw.setdefault("source", str(path))
        return cls(motor, rt, rv, max_speed=max_speed, max_accel=max_accel, ramp=ramp, **kw)  # type: ignore[arg-type]

    # --- control
    def start(self) -> "RampRunner":
        """Start the run on its own thread (once)."""
        if self._thread is not None:
            raise RuntimeError("ramp runner already started")
        self._thread = threading.Thread(target=self._run, name="ramp-runner", daemon=True)
        self.state = "lead-in"
        self._thread.start()
        return self

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the run to end; True if it has."""
        if self._thread is not None:
            self._thread.join(timeout)
        return not self.running

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def stop(self) -> None:
        """Controlled ramp-down (regulator STOP) after the set point in flight; ends the run."""
        self._halt_kind = self._halt_kind or "stopped"
        self._halt.set()
        with self._cmd_lock:
            self.motor.stop()

    def estop(self) -> None:
        """Emergency stop, sent at once (the regulator latches and refuses later set points)."""
        self._halt_kind = "estopped"
        self._halt.set()
        self.motor.estop()

    # --- observation
    def progress(self) -> RampProgress:
        return self._progress

    @property
    def history(self) -> dict[str, np.ndarray]:
        """Set points sent: t [s] (programme time, < 0 during lead-in), vb_set, vb measured (NaN if unread)."""
        with self._hist_lock:
            return {"t": np.asarray(self._hist_t), "vb_set": np.asarray(self._hist_set),
                    "vb": np.asarray(self._hist_meas)}

    def segment_at(self, t: float) -> int:
        """Index of the segment running at programme time t."""
        return max(0, int(np.searchsorted(self.segment_starts, t, side="right")) - 1)

    def command_at(self, t: float) -> float:
        """The programme's speed at time t (linear interpolation, held at the ends)."""
        return float(np.interp(t, self.rt, self.rv))

    # --- the thread
    def _emit(self, ev: RampEvent) -> None:
        self.events.append(ev)
        if self.on_event is not None:
            try:
                self.on_event(ev)
            except Exception:  # a faulty listener must not stop the belt programme
                pass

    def _report(self, p: RampProgress) -> None:
        self._progress = p
        if self.on_progress is not None:
            try:
                self.on_progress(p)
            except Exception:
                pass

    def _send(self, t: float, v: float, measure: bool) -> float | None:
        """One set point (and optionally one tachometer reading); raises _Halted once stop/estop is in."""
        with self._cmd_lock:
            if self._halt.is_set():
                raise _Halted
            self.motor.set_speed(v)
            meas = self.motor.read_speed()[0] if measure else None
        with self._hist_lock:
            self._hist_t.append(t)
            self._hist_set.append(v)
            self._hist_meas.append(np.nan if meas is None else meas)
        return meas

    def _run(self) -> None:
        seg = -1
        t = 0.0
        try:
            with self._cmd_lock:
                if self._halt.is_set():
                    raise _Halted
                st = self.motor.status()
                if st.state != "RUNNING":
                    self.motor.enable()
                self.motor.set_accel(self.accel)
            t0 = self._lead_in()
            self.state = "running"
            period = 1.0 / self.cfg.rate_hz
            k = 0
            while True:
                t = time.monotonic() - t0
                done = t >= self.duration
                tc = min(t, self.duration)
                v = self.command_at(tc)
                new_seg = self.segment_at(tc)
                while seg < new_seg:
                    # stamped with the boundary's programme time, not the tick that noticed it (a late
                    # tick on a loaded machine would otherwise move the boundary)
                    tb = float(self.segment_starts[seg + 1])
                    if seg >= 0:
                        self._emit(RampEvent("segment_end", tb, seg, self.segment_kinds[seg]))
                    seg += 1
                    self._emit(RampEvent("segment_start", tb, seg, self.segment_kinds[seg]))
                meas = self._send(tc, v, measure=(k % self.cfg.measure_every == 0) or done)
                frac = 1.0 if self.duration <= 0 else min(1.0, tc / self.duration)
                self._report(RampProgress("running", tc, frac, seg, v, meas))
                if done:
                    break
                k += 1
                due = t0 + k * period
                now = time.monotonic()
                if due < now - period:  # fell behind (loaded machine): skip, never burst
                    k = int((now - t0) / period) + 1
                    due = t0 + k * period
                if self._halt.wait(max(0.0, due - time.monotonic())):
                    raise _Halted
            self._emit(RampEvent("segment_end", self.duration, seg, self.segment_kinds[seg]))
            if self.cfg.at_end == "stop":
                with self._cmd_lock:
                    if not self._halt.is_set():
                        self.motor.stop()
            self._finish("finished", "programme complete", self.duration, stopped=self.cfg.at_end == "stop")
        except _Halted:
            kind = self._halt_kind or "stopped"
            self._finish(kind, "e-stop requested" if kind == "estopped" else "stop requested", t, stopped=True)
        except (MotorError, MotorUnavailable) as exc:
            if self._halt.is_set():  # a set point refused because stop/estop got there first
                kind = self._halt_kind or "stopped"
                self._finish(kind, "e-stop requested" if kind == "estopped" else "stop requested", t, stopped=True)
                return
            self.error = exc
            why = f"regulator error: {exc}"
            stopped = False
            try:
                self.motor.stop()
            except (MotorError, MotorUnavailable) as exc2:
                why += f"; controlled stop failed too: {exc2}"
            else:
                why += "; controlled stop sent"
                stopped = True
            self._finish("aborted", why, t, stopped=stopped)

    def _lead_in(self) -> float:
        """Bring the belt to the programme's first speed before the clock starts (t < 0 in history)."""
        v0 = float(self.rv[0])
        meas = self.motor.read_speed()[0]
        limit = abs(v0 - meas) / self.accel + self.cfg.lead_in_timeout_s
        period = 1.0 / self.cfg.rate_hz
        t_start = time.monotonic()
        n0 = len(self._hist_t)
        try:
            while abs(meas - v0) > self.cfg.lead_in_tol_m_per_s:
                now = time.monotonic()
                if now - t_start > limit:
                    raise MotorUnavailable(
                        f"lead-in: belt at {meas:.4f} m/s did not reach {v0:.4f} m/s in {limit:.2f} s")
                got = self._send(now, v0, measure=True)  # absolute time; made relative below
                meas = got if got is not None else meas
                self._report(RampProgress("lead-in", 0.0, 0.0, 0, v0, meas))
                if self._halt.wait(period):
                    raise _Halted
        finally:
            t0 = time.monotonic()
            with self._hist_lock:
                for i in range(n0, len(self._hist_t)):
                    self._hist_t[i] -= t0
        return t0

    def _finish(self, state: State, reason: str, t: float, stopped: bool) -> None:
        """End the run; ``stopped``: the regulator was told to stop, so nothing is commanded any more (0, not
        the programme's last speed: a status must not show a speed the belt is no longer asked for)."""
        self.state = state
        self.reason = reason
        p = self._progress
        self._report(RampProgress(state, p.t, 1.0 if state == "finished" else p.fraction, p.segment,
                                  0.0 if stopped else p.commanded, p.measured))
        self._emit(RampEvent(state, t, reason=reason))  # type: ignore[arg-type]


class _Halted(DaqError):
    """Internal: stop()/estop() ended the run."""
