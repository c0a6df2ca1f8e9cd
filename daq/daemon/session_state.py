"""What the operator is told after a crash: the daemon's session state file and the recorder's end.

Why a state file: a daemon killed by ``kill -9``, an OOM kill or a power cut cannot say
anything about its own end, and the regulator's watchdog stops the belt silently (and
latches). The next daemon on the same rig is the first process that can tell the operator,
so each session leaves ``STATE_DIR/RIG.session.json`` (default ``DATA_DIR/.daq-daemon/``):
``running`` from start, refreshed every few seconds (``last_alive_at``: the end lies after
it), ``clean`` after an orderly shutdown. A start that finds ``running`` reports the unclean
end (stderr and status) and refuses motion until ``daq ctl reset``; the report is carried in
the file until then, so restarting twice does not forget it.

Why a lock beside it (``RIG.lock``, ``flock``): the kernel drops the lock when its holder
dies however it dies, so "the last session is still running" (refuse to start a second
daemon on the rig) and "the last session died" are told apart without trusting pids.

Why reattach to the simulated bench: on a real rig the regulator outlives the daemon and
its latched watchdog trip is there to be read; a fresh simulated bench would have forgotten
it. A ``--sim`` daemon that finds the previous session's bench still running, with the same
rig, effects, time scale and seed, therefore connects to it instead of starting another
(daq/daemon/sim_bench.py; this module keeps only the bench's reference, :class:`BenchRef`).

Decision record: docs/decisions/0017-crash-truth.md.
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError

from daq.errors import DaqError, InputError
from daq.io.h5recover import is_unclean
from daq.io.runfile import recover_run
from daq.streaming.child_process import pid_alive
from daq.strict import Closed

STATE_DIR_NAME = ".daq-daemon"  # under the data directory, unless --state-dir
HEARTBEAT_S = 2.0  # how often last_alive_at is refreshed: the bound on "when did it end"
LATCHED = ("ESTOP", "WATCHDOG")  # regulator states that refuse motion until RST at standstill


def utcnow() -> _dt.datetime:
    return _dt.datetime.now(_dt.timezone.utc)


def local(t: _dt.datetime | None) -> str:
    """A stored UTC time as the operator's local wall clock, to the second."""
    return "?" if t is None else t.astimezone().strftime("%Y-%m-%d %H:%M:%S")


def pid_runs(pid: int, module: str) -> bool:
    """True if ``pid`` is alive and is ``python -m MODULE`` (not a reused pid)."""
    if not pid_alive(pid):
        return False
    try:
        return module in Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
    except OSError:
        return True


def describe_exit(returncode: int | None) -> str:
    if returncode is None:
        return "still running"
    if returncode < 0:
        try:
            return f"killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"exited with status {returncode}"


# ----------------------------------------------------------------------------- the models (on disk, in status)


class BenchRef(Closed):
    """The simulated bench a session drove, enough to find it again and check it is the same one."""

    pid: int
    control: str
    workdir: str
    endpoints: dict[str, dict[str, Any]]
    rig: str
    effects: list[str]
    time_scale: float
    seed: int


class RecordingRef(Closed):
    path: str
    recorder_pid: int


class RegulatorReading(Closed):
    """The motor regulator as read by a starting daemon (STAT?), and the bench's trip counter with --sim."""

    state: str | None = Field(None, description="DISABLED, RUNNING, STOPPING, ESTOP, WATCHDOG; None if unreadable")
    latched: bool = False
    measured: float | None = None
    watchdog_trips: int | None = Field(None, description="simulated bench only; a real regulator has no counter")
    error: str | None = None
    read_at: _dt.datetime


class UncleanEnd(Closed):
    """A session that ended without an orderly shutdown, as the next one found it."""

    pid: int
    started_at: _dt.datetime
    last_alive_at: _dt.datetime = Field(description="the session ended after this (refreshed every HEARTBEAT_S)")
    found_at: _dt.datetime
    found_by_pid: int
    recording: RecordingRef | None = None
    recording_outcome: str | None = None
    ramp: str | None = None
    regulator: RegulatorReading | None = None
    note: str = ""

    def summary(self) -> str:
        """One line for stderr and status."""
        what = []
        if self.ramp:
            what.append(f"running ramp {self.ramp}")
        if self.recording:
            what.append(f"recording {self.recording.path}" +
                        (f" ({self.recording_outcome})" if self.recording_outcome else ""))
        doing = f"; it was {' and '.join(what)}" if what else ""
        reg = ""
        if self.regulator is not None:
            r = self.regulator
            if r.state is None:
                reg = f"; regulator unreadable at start ({r.error})"
            else:
                trips = f", {r.watchdog_trips} watchdog trip(s)" if r.watchdog_trips is not None else ""
                reg = f"; regulator at start: {r.state}{' (latched)' if r.latched else ''}{trips}"
        note = f"; {self.note}" if self.note else ""
        return (f"the last session (daemon pid {self.pid}, started {local(self.started_at)}) ended uncleanly "
                f"after {local(self.last_alive_at)}{doing}{reg}{note}")


class SessionFile(Closed):
    """``RIG.session.json``: one daemon session, and an unacknowledged unclean end before it."""

    version: Literal[1] = 1
    rig: str
    state: Literal["running", "clean"]
    pid: int
    started_at: _dt.datetime
    last_alive_at: _dt.datetime
    ended_at: _dt.datetime | None = None
    sim_bench: BenchRef | None = None
    recording: RecordingRef | None = None
    ramp: str | None = None
    unclean_end: UncleanEnd | None = Field(None, description="carried from session to session until daq ctl reset")


class RecordingEnd(Closed):
    """A recorder that died while the daemon still wanted it (kill -9, OOM, a write error)."""

    path: str
    pid: int
    exit: str  # "killed by SIGKILL", "exited with status 1"
    returncode: int | None
    ended_at: _dt.datetime
    last_progress: str = ""
    recovered: bool = False
    recovery: str = ""
    recovery_s: float | None = None

    def summary(self) -> str:
        said = self.last_progress.removeprefix("recorder: ") if self.last_progress.startswith("recorder: stopped") \
            else ""  # its own last word, e.g. "stopped before the disk was full: ..."
        return (f"recording ENDED UNEXPECTEDLY at {local(self.ended_at)}: recorder pid {self.pid} {self.exit}"
                f"{f' ({said})' if said else ''}; {self.path}: {self.recovery}")


# ----------------------------------------------------------------------------- the file and its lock


class SessionBusy(DaqError, RuntimeError):
    """Another live daemon holds this rig's session lock."""


class MotionRefused(DaqError, RuntimeError):
    """A ramp (or reset) the daemon will not run now; the message names the reason and the way out."""


class SessionKeeper:
    """Owns ``STATE_DIR/RIG.session.json`` and ``RIG.lock`` for the life of one daemon."""

    def __init__(self, state_dir: Path, rig: str) -> None:
        self.dir = Path(state_dir)
        self.rig = rig
        self.path = self.dir / f"{rig}.session.json"
        self.lock_path = self.dir / f"{rig}.lock"
        self.current: SessionFile | None = None
        self.previous: SessionFile | None = None
        self.previous_error: str | None = None  # the previous file existed but could not be read
        self._fd: int | None = None
        self._mutex = threading.Lock()
        self._last_write = 0.0

    def acquire(self) -> None:
        """Take the rig's lock and read the previous session; SessionBusy if a live daemon holds it."""
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise InputError(str(self.dir), "--state-dir", f"cannot use: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            holder = self._read_pid()
            raise SessionBusy(f"rig {self.rig}: another daemon{f' (pid {holder})' if holder else ''} is running "
                              f"with state directory {self.dir}") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        self.previous, self.previous_error = self._read()

    def _read_pid(self) -> int | None:
        try:
            return int(self.lock_path.read_text().split()[0])
        except (OSError, ValueError, IndexError):
            return None

    def _read(self) -> tuple[SessionFile | None, str | None]:
        try:
            text = self.path.read_text()
        except FileNotFoundError:
            return None, None
        except OSError as exc:
            return None, f"{self.path}: {exc.strerror or exc}"
        try:
            return SessionFile.model_validate_json(text), None
        except ValidationError as exc:
            return None, f"{self.path}: unreadable ({exc.error_count()} error(s): {exc.errors()[0]['msg']})"

    def unclean_end(self, now: _dt.datetime) -> UncleanEnd | None:
        """The unclean end this session must report: the previous session's, or one it carried unacknowledged."""
        prev = self.previous
        if prev is None:
            if self.previous_error is None:
                return None
            return UncleanEnd(pid=0, started_at=now, last_alive_at=now, found_at=now, found_by_pid=os.getpid(),
                              note=f"state file {self.previous_error}: the last session's end is unknown")
        if prev.state == "running":
            return UncleanEnd(pid=prev.pid, started_at=prev.started_at, last_alive_at=prev.last_alive_at,
                              found_at=now, found_by_pid=os.getpid(), recording=prev.recording, ramp=prev.ramp)
        return prev.unclean_end  # an orderly session that never reset the one before it

    def begin(self, started_at: _dt.datetime, sim_bench: BenchRef | None, unclean: UncleanEnd | None) -> None:
        self.current = SessionFile(rig=self.rig, state="running", pid=os.getpid(), started_at=started_at,
                                   last_alive_at=utcnow(), sim_bench=sim_bench, unclean_end=unclean)
        self._write(durable=True)

    def update(self, *, durable: bool = False, **fields: Any) -> None:
        """Change fields of the running session's record and write it (atomically)."""
        with self._mutex:
            if self.current is None:
                return
            self.current = self.current.model_copy(update={**fields, "last_alive_at": utcnow()})
        self._write(durable)

    def heartbeat(self, recording: RecordingRef | None, ramp: str | None) -> None:
        """Refresh last_alive_at (and what the session is doing) every HEARTBEAT_S at most."""
        if time.monotonic() - self._last_write >= HEARTBEAT_S:
            self.update(recording=recording, ramp=ramp)

    def end_clean(self) -> None:
        """Orderly shutdown: mark the session clean (durably) and drop the lock."""
        if self.current is not None:
            self.update(durable=True, state="clean", ended_at=utcnow(), recording=None, ramp=None)
        self.release()

    def release(self) -> None:
        if self._fd is not None:
            try:
                fcntl.flock(self._fd, fcntl.LOCK_UN)
            finally:
                os.close(self._fd)
                self._fd = None

    def _write(self, durable: bool) -> None:
        with self._mutex:
            if self.current is None:
                return
            text = self.current.model_dump_json(indent=1)
            tmp = self.path.with_name(self.path.name + ".tmp")
            with open(tmp, "w") as fh:
                fh.write(text)
                if durable:
                    fh.flush()
                    os.fsync(fh.fileno())
            os.replace(tmp, self.path)
            self._last_write = time.monotonic()


# ----------------------------------------------------------------------------- recordings left behind


def open_session(keeper: SessionKeeper, started_at: _dt.datetime, bench: BenchRef | None, new_bench: bool,
                 regulator: RegulatorReading | None) -> UncleanEnd | None:
    """Mark this session running in ``keeper``'s file; the last session's unclean end, if there is one.

    An end found now (not carried from an earlier start) gets the regulator as read now and what became of
    its recording; ``new_bench``: a new simulated bench was started, so its regulator is not the one that tripped.
    """
    unclean = keeper.unclean_end(utcnow())
    if unclean is not None and unclean.found_by_pid == os.getpid():  # found now, not carried from before
        outcome = previous_recording_outcome(unclean.recording) if unclean.recording else None
        notes = [unclean.note] if unclean.note else []
        if new_bench:
            notes.append("a new simulated bench was started (the last one is gone or simulates something "
                         "else): its regulator is not the one that tripped")
        unclean = unclean.model_copy(update={"regulator": regulator, "recording_outcome": outcome,
                                             "note": "; ".join(notes)})
    keeper.begin(started_at, bench, unclean)
    return unclean


def recover_recording(path: str | Path) -> tuple[bool, str, float]:
    """Make a recording whose writer died openable by plain h5py/MATLAB: (changed, what happened, seconds).

    Only call it once the writer is gone (``recover`` on a file a live writer holds would lie).
    """
    t0 = time.monotonic()
    p = Path(path)
    if not p.exists():
        return False, "no file was written", 0.0
    try:
        if not is_unclean(p):
            return False, "closed cleanly; opens with plain h5py", time.monotonic() - t0
        recover_run(p)  # flags cleared, then the event columns Octave reads
    except (InputError, OSError, RuntimeError, KeyError, ValueError) as exc:
        return False, f"NOT recovered ({exc}); read it with daq.io (read-only view)", time.monotonic() - t0
    dt = time.monotonic() - t0
    return True, f"recovered in {1000 * dt:.0f} ms (open-for-write flags cleared): opens with plain h5py, MATLAB, Octave", dt


def previous_recording_outcome(rec: RecordingRef, wait_s: float = 3.0) -> str:
    """What became of the recording a dead session left: closed by its orphaned recorder, or recovered here."""
    t_end = time.monotonic() + wait_s
    while pid_runs(rec.recorder_pid, "daq.streaming.recorder") and time.monotonic() < t_end:
        time.sleep(0.05)  # the orphaned recorder notices within 0.5 s and drains for up to 2 s
    if pid_runs(rec.recorder_pid, "daq.streaming.recorder"):
        return f"its recorder (pid {rec.recorder_pid}) is still closing it"
    return recover_recording(rec.path)[1]
