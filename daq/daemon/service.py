"""The operator daemon: one rig's drivers, the bus, the recorder and the estimator, under control.

``daq daemon --rig RIG [--sim]`` assembles what the lab runs. Process layout (one
interpreter lock each, so nothing starves the acquisition or the estimator)::

    sim bench (python -m sim_backends.process, --sim only; own session, OUTLIVES the daemon)
        |  ptys: motor regulator, serial sensor stream, thermocouple
    daemon (this process): drivers -> acquisition -> PUB bus; ramp runner; control socket; motor heartbeat
        |-- estimator (python -m daq.daemon.estimator_process): SUB bus -> PUB estimates
        '-- recorder  (python -m daq.streaming.recorder, one per recording): SUB bus + estimates -> HDF5

Operators drive it through the control socket (``daq ctl``). On SIGTERM/SIGINT it
ramps the belt down before it exits; if it dies instead, the regulator's watchdog
stops the belt (the daemon's heartbeat thread dies with it), and the estimator and
recorder notice that their parent is gone (the recorder closes its file cleanly).

After a crash the operator is told (daq/daemon/session_state.py): a recorder that dies
is noticed the moment it exits (its file is recovered, status and an event say so, a
new recording can start); a daemon started after an unclean end of the last session on
its rig says so, with the regulator's state as read at start, and refuses motion until
``daq ctl reset``.

For ``daq demo`` and scripts, :func:`run_sim_ramp` runs the whole thing as a library call.

Decision records: docs/decisions/0005-daemon-process-layout.md, docs/decisions/0017-crash-truth.md.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import Field

from daq.config import config_text, load_rig
from daq.errors import InputError
from daq.io.stream_format import Block
from daq.ramps import Ramp
from daq.sim.effectset import parse_effect
from daq.streaming.bus import Subscriber
from daq.streaming.recorder import MIN_FREE_BYTES, free_space_refusal
from daq.strict import Closed
from drivers.factory import build_drivers
from sim_backends.process import SimBenchProcess, cross_process_wiring

from .acquisition import Acquisition, AcquisitionCfg
from .ramp_runner import RampEvent, RampRunner, RampRunnerCfg
from .rig_lock import RigLocks, lock_keys
from .session_state import (
    LATCHED,
    AttachedSimBench,
    BenchRef,
    MotionRefused,
    RecordingEnd,
    RecordingRef,
    RegulatorReading,
    SessionKeeper,
    UncleanEnd,
    describe_exit,
    previous_recording_outcome,
    recover_recording,
    utcnow,
)

STANDSTILL = 1e-3  # [m/s]
REGULATOR_POLL_S = 0.2  # STAT? while running: a watchdog trip reaches status, stderr and the events within 1 s
ROOT = Path(__file__).resolve().parents[2]  # the repository: where `python -m daq...` finds the packages


class DaemonCfg(Closed):
    rig: str
    sim: bool = False
    sim_effects: list[str] = Field(default_factory=list, description="hidden effects of the simulated rig")
    sim_time_scale: float = Field(1.0, gt=0)
    sim_seed: int = 0
    workdir: Path | None = Field(None, description="where simulated serial devices appear (default: a temp dir)")
    data_dir: Path = Path("data")
    bus_endpoint: str = "tcp://127.0.0.1:5560"
    estimator_endpoint: str = "tcp://127.0.0.1:0"
    estimator: bool = True
    flush_s: float = Field(0.25, gt=0, le=1.0)
    ramp_down_timeout_s: float = Field(10.0, gt=0)
    start_timeout_s: float = Field(180.0, gt=0, description="for the child processes to come up (numba caches)")
    state_dir: Path | None = Field(None, description="where RIG.session.json and RIG.lock live (the CLI: "
                                                     "DATA_DIR/.daq-daemon); None: no session state (library use)")
    control_endpoint: str | None = Field(None, description="the control socket the CLI binds: locked machine-wide "
                                                           "with the bus (daq/daemon/rig_lock.py) if its port is fixed")


def _popen(args: list[str], **kw: Any) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", *args], cwd=str(ROOT), **kw)


def _first_line(proc: subprocess.Popen, timeout: float, what: str) -> str:
    """The child's first stdout line (its 'ready' line), or RuntimeError if it does not come."""
    box: list[str] = []
    th = threading.Thread(target=lambda: box.append(proc.stdout.readline()), daemon=True)
    th.start()
    th.join(timeout)
    line = box[0] if box else ""
    if not line.strip():
        proc.kill()
        raise RuntimeError(f"{what} did not start within {timeout:g} s (exit status {proc.poll()})")
    return line.strip()


def _terminate(proc: subprocess.Popen, timeout: float) -> int | None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
    return proc.returncode


class EstimatorProcess:
    """``python -m daq.daemon.estimator_process`` on the daemon's bus; its stats lines are kept for status."""

    def __init__(self, rig: str, sub_endpoint: str, pub_endpoint: str, timeout: float) -> None:
        self.proc = _popen(["daq.daemon.estimator_process", "--rig", rig, "--sub", sub_endpoint, "--pub", pub_endpoint,
                            "--parent-pid", str(os.getpid())], stdout=subprocess.PIPE, text=True)
        self.pid = self.proc.pid
        info = json.loads(_first_line(self.proc, timeout, "the estimator process"))
        self.endpoint: str = info["endpoint"]
        self.stats: dict[str, Any] = {}
        self._reader = threading.Thread(target=self._read, name="estimator-stats", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            if line.startswith("stats "):
                try:
                    self.stats = json.loads(line[6:])
                except ValueError:
                    pass

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self) -> None:
        _terminate(self.proc, 15)
        self._reader.join(2)


class RecorderProcess:
    """``python -m daq.streaming.recorder`` for one run file; started by record_start, SIGTERM'd by record_stop."""

    def __init__(self, path: Path, rig_arg: str, endpoints: list[str], flush_s: float, timeout: float,
                 wait_stream: str | None = "motor") -> None:
        self.path = path
        cmd = ["daq.streaming.recorder", "--endpoint", endpoints[0], "--rig", rig_arg, "-o", str(path), "--flush-s",
               repr(flush_s), "--parent-pid", str(os.getpid())]
        for ep in endpoints[1:]:
            cmd += ["--also", ep]
        self.proc = _popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.pid = self.proc.pid
        self.streams: list[str] = []
        self.progress = ""
        self.closed_line = ""
        self.stopping = False  # set before the daemon itself ends it: any other exit is a failure
        self.ended_at: _dt.datetime | None = None
        self._stream_seen = threading.Condition()
        line = _first_line(self.proc, timeout, "the recorder process")
        if not line.startswith("ready"):
            raise RuntimeError(f"recorder: {line}")
        threading.Thread(target=self._read_out, name="recorder-out", daemon=True).start()
        threading.Thread(target=self._read_err, name="recorder-err", daemon=True).start()
        if wait_stream is not None:  # its subscription is live once a stream of ours reached the file
            with self._stream_seen:
                self._stream_seen.wait_for(lambda: wait_stream in self.streams or not self.alive, timeout=timeout)

    def _read_out(self) -> None:
        for line in self.proc.stdout:
            if line.startswith("stream "):
                with self._stream_seen:
                    self.streams.append(line.split(None, 1)[1].strip())
                    self._stream_seen.notify_all()

    def _read_err(self) -> None:
        for line in self.proc.stderr:
            if line.startswith("recorder:"):
                self.progress = line.strip()
            elif line.startswith("closed "):
                self.closed_line = line.strip()
            else:
                sys.stderr.write(line)

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def lost_blocks(self) -> int | None:
        """From the recorder's last progress line ('lost blocks N')."""
        parts = self.progress.split("lost blocks")
        try:
            return int(parts[1].split()[0]) if len(parts) > 1 else None
        except (ValueError, IndexError):
            return None

    def watch(self, on_exit: Callable[[RecorderProcess], None]) -> None:
        """Call ``on_exit(self)`` the moment the process ends, so a dead recorder is noticed at once."""
        def wait() -> None:
            self.proc.wait()
            self.ended_at = utcnow()
            on_exit(self)
        threading.Thread(target=wait, name=f"recorder-watch-{self.pid}", daemon=True).start()

    def stop(self, timeout: float = 60.0) -> int | None:
        self.stopping = True
        rc = _terminate(self.proc, timeout)
        return rc


class EstimateMonitor:
    """Keeps the latest estimate and law fit (for status and progress), from the estimator's stream."""

    def __init__(self, endpoint: str) -> None:
        self.sub = Subscriber(endpoint, streams=["estimator", "friction_fit"], events=False, rcvhwm=1000,
                              name="daemon-monitor")
        self.last: dict[str, float] = {}
        self.fit: dict[str, float] = {}
        self.blocks = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="estimate-monitor", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.is_set():
            m = self.sub.recv(0.1)
            if isinstance(m, Block) and m.header.n:
                row = {c: float(v) for c, v in zip(m.meta.channels, m.data[-1])}
                row["t"] = float(m.t[-1])
                if m.meta.stream == "estimator":
                    self.blocks += 1
                    self.last = row
                else:
                    self.fit = row

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sub.close()


class Daemon:
    def __init__(self, cfg: DaemonCfg) -> None:
        self.cfg = cfg
        self.rig = load_rig(cfg.rig)
        self.sim = None  # SimBenchProcess with --sim
        self.estimator: EstimatorProcess | None = None
        self.web = None  # the live page's process (daq.web.process.WebProcess), set by `daq daemon --web`
        self.monitor: EstimateMonitor | None = None
        self.runner: RampRunner | None = None
        self.recorder: RecorderProcess | None = None
        self.started = False
        self.t_start = time.monotonic()
        self.started_at = utcnow()
        self._lock = threading.RLock()
        self._rates: dict[str, float] = {}
        self._rate_stop = threading.Event()
        self._rig_arg = cfg.rig
        self.session = SessionKeeper(cfg.state_dir, self.rig.rig) if cfg.state_dir is not None else None
        self.unclean: UncleanEnd | None = None  # the last session's unclean end, until `daq ctl reset`
        self.regulator: RegulatorReading | None = None  # the regulator's state, as last read
        self.recording_failure: RecordingEnd | None = None  # a recorder that died on us, until the next start
        self._halted = False  # a stop/estop was sent since the last ramp started: nothing is commanded
        sockets = [cfg.bus_endpoint] + ([cfg.control_endpoint] if cfg.control_endpoint else [])
        self.locks = RigLocks(lock_keys(self.rig, cfg.sim, sockets),
                              holder=f"daemon pid {os.getpid()} for rig {self.rig.rig} "
                                     f"(data dir {Path(cfg.data_dir).absolute()})")

    # --- life cycle
    def start(self) -> "Daemon":
        """Start everything; with a state directory, also find out how the last session on this rig ended."""
        endpoints = None
        try:
            self.locks.acquire()  # RigBusy if a live daemon holds the rig, an instrument or a socket, any data dir
            if self.session is not None:
                self.session.acquire()  # SessionBusy if a live daemon holds the rig
            if self.cfg.sim:
                endpoints = self._start_bench()
            self.drivers = build_drivers(self.rig, endpoints)
            self.drivers.open()
            self.acq = Acquisition(self.rig, self.drivers, AcquisitionCfg(endpoint=self.cfg.bus_endpoint))
            self.acq.start()
            if self.cfg.estimator:
                self.estimator = EstimatorProcess(self._rig_arg, self.acq.endpoint, self.cfg.estimator_endpoint,
                                                  self.cfg.start_timeout_s)
                self.monitor = EstimateMonitor(self.estimator.endpoint)
            self._read_regulator()
            if self.session is not None:
                self._begin_session()
        except BaseException:
            self._release()
            if self.session is not None:
                self.session.release()  # the previous session's file stays as it was
            self.locks.release()
            raise
        threading.Thread(target=self._rate_loop, name="rates", daemon=True).start()
        threading.Thread(target=self._regulator_loop, name="regulator-watch", daemon=True).start()
        self.started = True
        return self

    def _start_bench(self) -> dict[str, dict[str, Any]]:
        """The simulated bench: the last session's, if it still runs the same simulation, else a new one."""
        self.rig = cross_process_wiring(self.rig)
        prev = self.session.previous if self.session is not None else None
        attached = AttachedSimBench.find(prev.sim_bench if prev else None, self.cfg.rig, self.cfg.workdir,
                                         self.cfg.sim_effects, self.cfg.sim_time_scale, self.cfg.sim_seed)
        if attached is not None:
            self.sim, workdir = attached, attached.workdir
        else:
            workdir = self.cfg.workdir or Path(tempfile.mkdtemp(prefix=f"daq-sim-{self.rig.rig}-"))
            self.sim = SimBenchProcess(self.cfg.rig, workdir, effects=self.cfg.sim_effects,
                                       time_scale=self.cfg.sim_time_scale, seed=self.cfg.sim_seed,
                                       owner_pid=os.getpid(), start_timeout_s=self.cfg.start_timeout_s)
        wired = Path(workdir) / f"{self.rig.rig}.toml"  # what the recordings store: the wiring in use
        wired.write_text(config_text(self.rig))
        self._rig_arg = str(wired)
        return self.sim.endpoints

    def _bench_ref(self) -> BenchRef | None:
        if self.sim is None:
            return None
        return BenchRef(pid=self.sim.pid, control=self.sim.control, workdir=str(Path(self.sim.workdir).resolve()),
                        endpoints=self.sim.endpoints, rig=self.cfg.rig, effects=list(self.cfg.sim_effects),
                        time_scale=self.cfg.sim_time_scale, seed=self.cfg.sim_seed)

    def _begin_session(self) -> None:
        """Report an unclean end of the last session (with the regulator as read now) and mark this one running."""
        assert self.session is not None
        unclean = self.session.unclean_end(utcnow())
        if unclean is not None and unclean.found_by_pid == os.getpid():  # found now, not carried from before
            outcome = previous_recording_outcome(unclean.recording) if unclean.recording else None
            notes = [unclean.note] if unclean.note else []
            if self.sim is not None and not isinstance(self.sim, AttachedSimBench):
                notes.append("a new simulated bench was started (the last one is gone or simulates something "
                             "else): its regulator is not the one that tripped")
            unclean = unclean.model_copy(update={"regulator": self.regulator, "recording_outcome": outcome,
                                                 "note": "; ".join(notes)})
        self.unclean = unclean
        self.session.begin(self.started_at, self._bench_ref(), unclean)
        if unclean is not None:
            self.acq.publish_event("unclean_end", "daemon", unclean.summary())

    def _read_regulator(self) -> RegulatorReading:
        """STAT? from the regulator (and the simulated bench's watchdog trip counter); kept for status."""
        now = utcnow()
        try:
            st = self.drivers.motor.status()
        except Exception as exc:  # noqa: BLE001 - unreadable is itself the answer
            reading = RegulatorReading(error=f"{type(exc).__name__}: {exc}", read_at=now)
        else:
            trips = None
            if self.sim is not None:
                try:
                    trips = int(self.sim.status().get("watchdog_trips"))
                except (TimeoutError, OSError, TypeError, ValueError):
                    pass
            reading = RegulatorReading(state=st.state, latched=st.state in LATCHED, measured=st.measured,
                                       watchdog_trips=trips, read_at=now)
        self.regulator = reading
        return reading

    def _regulator_loop(self) -> None:
        """Poll the regulator while the daemon runs, and report the moment it latches.

        Why: the state was read only at start and on explicit commands, so after a watchdog trip
        with the daemon alive (a 0.46 s stall from a 300 MB web request, issue 29) status said
        DISABLED, 0 trips, motion allowed, nothing reached stderr, and the ``watchdog`` event was
        written 19 s later at ``reset``. Every REGULATOR_POLL_S the state is read; a change into a
        latched state (WATCHDOG, ESTOP) updates status (motion refused), prints one stderr line and
        publishes an event.
        """
        while not self._rate_stop.wait(REGULATOR_POLL_S):
            try:
                st = self.drivers.motor.status()
            except Exception:  # noqa: BLE001, S112 - unreachable regulator: the motor stream's counters say so
                continue
            before = self.regulator
            if before is not None and before.state == st.state:
                continue
            if st.state not in LATCHED:
                self.regulator = RegulatorReading(state=st.state, latched=False, measured=st.measured,
                                                  watchdog_trips=before.watchdog_trips if before else None,
                                                  read_at=utcnow())
                continue
            reading = self._read_regulator()  # with the bench's trip counter
            if not reading.latched or (before is not None and before.latched):
                continue
            self._report_latch(reading)

    def _report_latch(self, reading: RegulatorReading) -> None:
        """One stderr line and one event for a regulator that latched while the daemon ran (not our own e-stop)."""
        if reading.state == "ESTOP" and self._halted:
            return
        trips = f", {reading.watchdog_trips} watchdog trip(s)" if reading.watchdog_trips is not None else ""
        why = ("its watchdog stopped the belt (no command within its timeout)" if reading.state == "WATCHDOG"
               else f"it latched in {reading.state}")
        detail = f"regulator {reading.state} (latched){trips}: {why}; motion refused until `daq ctl reset`"
        self.acq.publish_event("watchdog" if reading.state == "WATCHDOG" else "regulator_latched", "daemon", detail)
        print(f"daq daemon: {detail}", file=sys.stderr, flush=True)

    def motion_refusal(self, read: bool = False) -> str | None:
        """Why no ramp may start now (None: it may): an unclean end not yet reset, or a latched regulator
        (as last read, or ``read`` now)."""
        if self.unclean is not None:
            return f"motion refused until `daq ctl reset`: {self.unclean.summary()}"
        reg = self._read_regulator() if read else self.regulator
        if reg is not None and reg.latched:
            return f"motion refused: the regulator is latched in {reg.state}; with the belt at rest, `daq ctl reset`"
        return None

    def _release(self) -> None:
        for step in (lambda: self.monitor and self.monitor.close(),
                     lambda: self.estimator and self.estimator.stop(),
                     lambda: hasattr(self, "acq") and self.acq.stop(),
                     lambda: hasattr(self, "drivers") and self.drivers.close(),
                     lambda: self.sim and self.sim.stop()):
            try:
                step()
            except Exception:  # noqa: BLE001 - release the rest regardless
                pass

    def shutdown(self) -> None:
        """Controlled stop: ramp the belt down, close the recording, release everything."""
        with self._lock:
            if not self.started:
                return
            self.started = False
            self._rate_stop.set()
            try:
                self.handle_stop({})
                self.wait_standstill(self.cfg.ramp_down_timeout_s)
            except Exception:  # noqa: BLE001 - shutting down regardless; the watchdog is the backstop
                pass
            if self.recorder is not None:
                time.sleep(2 * self.cfg.flush_s)  # the ramp-down's last samples reach the file
                if self.recorder.stop() != 0:
                    recover_recording(self.recorder.path)
                self.recorder = None
            self._release()
            if self.session is not None:
                self.session.end_clean()
            self.locks.release()

    def wait_standstill(self, timeout: float) -> bool:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            measured, _ = self.drivers.motor.read_speed()
            if abs(measured) < 5 * STANDSTILL:
                return True
            time.sleep(0.05)
        return False

    def install_signal_handlers(self) -> threading.Event:
        """SIGTERM/SIGINT -> controlled ramp-down and exit (set the returned event)."""
        done = threading.Event()

        def handler(signum, frame):  # noqa: ARG001
            done.set()

        signal.signal(signal.SIGTERM, handler)
        signal.signal(signal.SIGINT, handler)
        return done

    def _rate_loop(self) -> None:
        """Samples per second of every stream, over the last second (for status); the session's heartbeat."""
        prev, t_prev = {k: v.samples for k, v in self.acq.counters().items()}, time.monotonic()
        while not self._rate_stop.wait(1.0):
            now, cur = time.monotonic(), {k: v.samples for k, v in self.acq.counters().items()}
            self._rates = {k: (n - prev.get(k, 0)) / (now - t_prev) for k, n in cur.items()}
            prev, t_prev = cur, now
            try:
                if self.session is not None:
                    self.session.heartbeat(self._recording_ref(), self._ramp_source())
                if isinstance(self.sim, AttachedSimBench):
                    self.sim.keepalive()
            except OSError as exc:  # a full disk must not stop the status thread; say it once a second
                print(f"daq daemon: session state: {exc}", file=sys.stderr, flush=True)

    def _recording_ref(self) -> RecordingRef | None:
        rec = self.recorder
        return RecordingRef(path=str(rec.path), recorder_pid=rec.pid) if rec is not None else None

    def _ramp_source(self) -> str | None:
        r = self.runner
        return r.source if r is not None and r.running else None

    def _on_recorder_exit(self, rec: RecorderProcess) -> None:
        """A recorder ended: if the daemon did not end it, report it, recover its file, free the slot."""
        if rec.stopping:
            return
        with self._lock:
            if rec.stopping:  # shutdown holds the lock while it stops the recorder
                return
            if self.recorder is rec:
                self.recorder = None
            rc = rec.proc.returncode
            failure = RecordingEnd(path=str(rec.path), pid=rec.pid, exit=describe_exit(rc), returncode=rc,
                                   ended_at=rec.ended_at or utcnow(), last_progress=rec.progress,
                                   recovery="recovering the file")
            self.recording_failure = failure
        changed, what, dt = recover_recording(rec.path)
        failure = failure.model_copy(update={"recovered": changed, "recovery": what, "recovery_s": dt})
        with self._lock:
            if self.recording_failure is not None and self.recording_failure.pid == rec.pid:
                self.recording_failure = failure
        self.acq.publish_event("recorder_died", "daemon", failure.summary())
        print(f"daq daemon: {failure.summary()}", file=sys.stderr, flush=True)
        if self.session is not None:
            try:
                self.session.update(recording=None)
            except OSError:
                pass

    # --- control handlers (each takes the request's args, returns a result dict)
    def handlers(self) -> dict[str, Any]:
        return {"status": self.handle_status, "ramp": self.handle_ramp, "stop": self.handle_stop,
                "estop": self.handle_estop, "record_start": self.handle_record_start,
                "record_stop": self.handle_record_stop, "note": self.handle_note, "reset": self.handle_reset}

    def handle_status(self, args: dict) -> dict:
        st = self.acq.status()
        counters = st.pop("streams")
        streams = {k: {**v, "rate_hz": self._rates.get(k, 0.0)} for k, v in counters.items()}
        motor = st.get("motor") or {}
        drops = {"bus_queue": st["dropped"], "misaligned_reads": st["misaligned_reads"],
                 "lost_frames": sum(s["lost_frames"] for s in st["sources"].values()),
                 "checksum_errors": sum(s["checksum_errors"] for s in st["sources"].values()),
                 "motor_failed_polls": motor.get("failed_polls", 0)}
        refusal = self.motion_refusal()
        out: dict[str, Any] = {"rig": self.rig.rig, "sim": self.cfg.sim, "pid": os.getpid(),
                               "uptime_s": time.monotonic() - self.t_start, "bus": self.acq.endpoint,
                               "belt": self._belt(motor),
                               "streams": streams, "sources": st["sources"], "drops": drops,
                               "recording": None, "ramp": None, "estimator": None,
                               "motion": {"allowed": refusal is None, "refused_because": refusal},
                               "regulator": self.regulator.model_dump(mode="json") if self.regulator else None,
                               "last_session": self.unclean.model_dump(mode="json") if self.unclean else None,
                               "recording_failure": (self.recording_failure.model_dump(mode="json")
                                                     if self.recording_failure else None),
                               "session": ({"state_file": str(self.session.path),
                                            "started_at": self.started_at.isoformat()}
                                           if self.session is not None else None)}
        if self.estimator is not None:
            est = dict(self.estimator.stats)
            out["estimator"] = {"pid": self.estimator.pid, "alive": self.estimator.alive,
                                "endpoint": self.estimator.endpoint, **est,
                                "last": self.monitor.last if self.monitor else {},
                                "fit": self.monitor.fit if self.monitor else {}}
            drops["estimator_lost_blocks"] = est.get("lost_blocks", 0)
        rec = self.recorder
        if rec is not None:
            out["recording"] = {"path": str(rec.path), "pid": rec.pid, "alive": rec.alive, "progress": rec.progress}
            drops["recorder_lost_blocks"] = rec.lost_blocks() or 0
        if self.web is not None:
            out["web"] = {"url": self.web.url, "pid": self.web.pid, "alive": self.web.alive,
                          "exit": self.web.proc.returncode}
        if self.sim is not None:
            out["sim_bench"] = {"pid": self.sim.pid, "control": self.sim.control, "alive": self.sim.alive(),
                                "attached": isinstance(self.sim, AttachedSimBench)}
        if self.runner is not None:
            p = self.runner.progress()
            out["ramp"] = {"state": str(p.state), "t": p.t, "duration": self.runner.duration, "fraction": p.fraction,
                           "segment": p.segment, "commanded": out["belt"]["commanded"],
                           "measured": out["belt"]["measured"],
                           "reason": self.runner.reason, "source": self.runner.source}
        return out

    def _belt(self, motor: dict[str, Any]) -> dict[str, Any]:
        """Measured (the latest motor sample, and its age), the regulator's set point, and what we command.

        ``commanded`` is 0 once a stop or e-stop was sent (or a ramp ended in a stop), whatever
        the programme's last value was; None before anything was commanded.
        """
        t = motor.get("host_time")
        if self._halted:
            commanded: float | None = 0.0
        elif self.runner is not None:
            commanded = self.runner.progress().commanded
        else:
            commanded = None
        return {"measured": motor.get("measured"), "age_s": None if t is None else time.monotonic() - t,
                "setpoint": motor.get("setpoint"), "commanded": commanded, "regulator": motor.get("state")}

    def _on_ramp_event(self, ev: RampEvent) -> None:
        self.acq.publish_event("ramp_segment" if ev.kind.startswith("segment") else f"ramp_{ev.kind}", "ramp",
                               f"{ev.kind} {ev.index if ev.index is not None else ''} {ev.segment or ''} "
                               f"{ev.reason}".strip())

    def start_ramp(self, make: Callable[..., RampRunner], label: str, time_scale: float = 1.0) -> RampRunner:
        """Validate (before any motion) and start a ramp; ``make(motor, vmax, amax, **kw)`` builds the runner."""
        with self._lock:
            if not self.started:
                raise RuntimeError("daemon is not running")
            if self.runner is not None and self.runner.running:
                raise RuntimeError("a ramp is already running; stop it first")
            d = self.rig.drive
            runner = make(self.drivers.motor, d.max_speed_m_per_s, d.max_accel_m_per_s2,
                          cfg=RampRunnerCfg(time_scale=float(time_scale)), on_event=self._on_ramp_event)
            why = self.motion_refusal(read=True)
            if why is not None:
                self.acq.publish_event("motion_refused", "daemon", f"{label}: {why}")
                raise MotionRefused(why)
            self.runner = runner.start()
            self._halted = False
        self.acq.publish_event("ramp_start", "ramp", label)
        if self.session is not None:
            self.session.update(ramp=runner.source)
        return runner

    def handle_ramp(self, args: dict) -> dict:
        path = str(args["file"])
        self.start_ramp(lambda m, v, a, **kw: RampRunner.from_file(m, path, v, a, **kw), path,
                        float(args.get("time_scale", 1.0)))
        return {"started": path, "duration_s": self.runner.duration}

    def _halt(self, how: str, detail: str) -> None:
        """Stop (``how`` = "stop": a controlled ramp-down) or e-stop the belt, through the ramp if one runs."""
        self._halted = True
        target = self.runner if self.runner is not None and self.runner.running else self.drivers.motor
        getattr(target, how)()
        self.acq.publish_event(how, "operator", detail)

    def handle_stop(self, args: dict) -> dict:
        self._halt("stop", "controlled stop")
        return {"stopping": True}

    def handle_estop(self, args: dict) -> dict:
        self._halt("estop", "emergency stop")
        self._read_regulator()
        return {"estop": True}

    def handle_reset(self, args: dict) -> dict:
        """Acknowledge an unclean end and clear the regulator's latch (ESTOP/WATCHDOG): only at standstill.

        Why explicit: after a crash someone should look at the rig before it moves again; the
        reset is the operator saying so, and it is logged as an event.
        """
        with self._lock:
            if self.runner is not None and self.runner.running:
                raise MotionRefused("a ramp is running: stop it first (reset is for a belt at rest)")
            measured, _ = self.drivers.motor.read_speed()
            if abs(measured) >= 5 * STANDSTILL:
                raise MotionRefused(f"the belt is moving ({measured:.4f} m/s): reset only at standstill")
            before = self._read_regulator()
            if before.latched:
                self.drivers.motor.reset()  # the regulator refuses (MotorError) unless at standstill
            after = self._read_regulator()
            cleared, self.unclean = self.unclean, None
            if self.session is not None:
                self.session.update(durable=True, unclean_end=None)
        detail = (f"regulator {before.state} -> {after.state}"
                  + (f"; acknowledged: {cleared.summary()}" if cleared is not None else ""))
        self.acq.publish_event("reset", "operator", detail)
        print(f"daq daemon: reset: {detail}", file=sys.stderr, flush=True)
        return {"reset": True, "regulator_before": before.state, "regulator": after.state,
                "acknowledged": cleared.summary() if cleared is not None else None}

    def handle_record_start(self, args: dict) -> dict:
        with self._lock:
            if self.recorder is not None and self.recorder.alive:
                raise RuntimeError(f"already recording to {self.recorder.path}")
            stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
            path = Path(args.get("path") or self.cfg.data_dir / f"{self.rig.rig}-{stamp}.h5").absolute()
            if path.exists():
                raise InputError(str(path), "path", "exists; recordings are never overwritten")
            if path.suffix.lower() not in (".h5", ".hdf5"):
                raise InputError(str(path), "path", "must end in .h5 or .hdf5")
            try:  # here, not in the recorder process: a bad folder is the operator's input, answered at once
                path.parent.mkdir(parents=True, exist_ok=True)
                with tempfile.TemporaryFile(dir=path.parent):
                    pass
            except OSError as exc:
                raise InputError(str(path), "path", f"cannot write in {path.parent}: "
                                                    f"{exc.strerror or exc}") from None
            low = free_space_refusal(path.parent, MIN_FREE_BYTES)  # the recorder's own margin, answered at once
            if low is not None:
                raise InputError(str(path), "path", f"cannot record: {low}")
            eps = [self.acq.endpoint] + ([self.estimator.endpoint] if self.estimator is not None else [])
            rec = self.recorder = RecorderProcess(path, self._rig_arg, eps, self.cfg.flush_s,
                                                  self.cfg.start_timeout_s)
            lost, self.recording_failure = self.recording_failure, None
            rec.watch(self._on_recorder_exit)
        self.acq.publish_event("record_start", "operator", str(path))
        if lost is not None:  # the new file keeps the record of the one before it
            self.acq.publish_event("previous_recording_lost", "daemon", lost.summary())
        if self.session is not None:
            self.session.update(recording=self._recording_ref())
        return {"recording": str(path), "pid": rec.pid}

    def handle_record_stop(self, args: dict) -> dict:
        with self._lock:
            if self.recorder is None:
                raise RuntimeError("not recording")
            rec, self.recorder = self.recorder, None
        self.acq.publish_event("record_stop", "operator", str(rec.path))
        time.sleep(2 * self.cfg.flush_s)  # the stop event and the last blocks reach the recorder
        rc = rec.stop()
        if self.session is not None:
            self.session.update(recording=None)
        if rc != 0:
            _, what, _ = recover_recording(rec.path)
            raise RuntimeError(f"recorder {describe_exit(rc)}: {rec.closed_line or rec.progress}; {rec.path}: {what}")
        return {"closed": str(rec.path), "recorder": rec.closed_line}

    def handle_note(self, args: dict) -> dict:
        text = str(args["text"])
        self.acq.publish_event("note", "operator", text)
        return {"noted": text}


# ----------------------------------------------------------------------------- library use (daq demo)


@dataclass(frozen=True)
class BenchProgress:
    """What a caller of :func:`run_sim_ramp` sees a few times a second."""

    elapsed_s: float  # wall time since the ramp started [s]
    state: str  # lead-in, running, finished, stopped, estopped, aborted
    fraction: float  # of the programme done
    belt_speed: float | None  # measured by the regulator's tachometer [m/s]
    commanded: float  # the set point [m/s]
    friction_N: float | None  # the online estimator's latest friction force F_est [N]
    mu: float | None  # ... and friction coefficient mu_est


def run_sim_ramp(rig: str, ramp: "str | Path | Any", out: str | Path, *, effects: list[str] = (),
                 ramp_time_scale: float = 1.0, sim_time_scale: float = 1.0, seed: int = 0,
                 progress: Callable[[BenchProgress], None] | None = None, progress_s: float = 0.2,
                 workdir: str | Path | None = None, timeout_s: float | None = None) -> Path:
    """Start a simulated bench and the daemon, run one ramp while recording, shut down; the run file's path.

    ``ramp``: a ramp file (.toml/.csv) or a ``daq.ramps.Ramp``; ``effects``: hidden effects of the
    simulated rig (``NAME[:k=v,...]``); ``ramp_time_scale`` compresses the programme (e.g. 3/45 runs
    the 45 s seed ramp in 3 s, if the drive's acceleration limit allows); ``progress`` is called every
    ``progress_s`` with a :class:`BenchProgress`. Raises InputError for a ramp the rig cannot run
    (before any motion), RuntimeError if the ramp does not finish.
    """

    out = Path(out)
    work = Path(workdir) if workdir is not None else Path(tempfile.mkdtemp(prefix="daq-bench-"))
    d = Daemon(DaemonCfg(rig=rig, sim=True, sim_effects=list(effects), sim_time_scale=sim_time_scale,
                         sim_seed=seed, workdir=work / "dev", data_dir=out.parent,
                         bus_endpoint="tcp://127.0.0.1:0"))
    if isinstance(ramp, Ramp):
        def make(m, v, a, **kw):
            return RampRunner.from_ramp(m, ramp, v, a, source=ramp.name, **kw)
        label = ramp.name
    else:
        path = str(ramp)

        def make(m, v, a, **kw):
            return RampRunner.from_file(m, path, v, a, **kw)
        label = path

    for e in effects:  # bad input: InputError before anything starts
        parse_effect(e, "effects")
    drive = load_rig(rig).drive  # refuse a ramp the rig cannot run before starting anything
    make(None, drive.max_speed_m_per_s, drive.max_accel_m_per_s2, cfg=RampRunnerCfg(time_scale=ramp_time_scale))
    if out.exists():
        raise InputError(str(out), "out", "exists; recordings are never overwritten")
    d.start()
    try:
        d.handle_record_start({"path": str(out)})
        runner = d.start_ramp(make, label, ramp_time_scale)
        t0 = time.monotonic()
        limit = timeout_s if timeout_s is not None else runner.duration / max(sim_time_scale, 1e-9) * 3 + 60
        while True:
            ended = runner.join(progress_s)
            if progress is not None:
                p = runner.progress()
                last = d.monitor.last if d.monitor is not None else {}
                try:
                    progress(BenchProgress(time.monotonic() - t0, str(runner.state), p.fraction, p.measured,
                                           p.commanded, last.get("F_est"), last.get("mu_est")))
                except Exception:  # noqa: BLE001 - a display problem must not stop the belt programme
                    pass
            if ended:
                break
            if time.monotonic() - t0 > limit:
                runner.stop()
                raise RuntimeError(f"ramp did not finish within {limit:.0f} s")
        d.wait_standstill(d.cfg.ramp_down_timeout_s)
        time.sleep(0.5)  # the last estimates reach the file
        if runner.state != "finished":
            raise RuntimeError(f"ramp {runner.state}: {runner.reason}")
        d.handle_record_stop({})
        return out
    finally:
        d.shutdown()
