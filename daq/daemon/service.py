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

:class:`Daemon` is a coordinator: it starts its parts in order, stops them in reverse, and starts
ramps. The parts, each in its own module:

* daq/daemon/children.py: the child processes (estimator, recorder), the estimate monitor, and the
  protocol of a bench handed in from outside (the daemon never imports the simulator: ``daq daemon
  --sim`` and :func:`run_sim_ramp` build one with daq/daemon/sim_bench.py and pass its factory in);
* daq/daemon/motion.py: whether the belt may move (regulator, latch watch, unclean end, halted);
* daq/daemon/recording.py: the one recording slot (and a recorder that died on us);
* daq/daemon/handlers.py: the control socket's operations; daq/daemon/status.py: the status answer;
* daq/daemon/session_state.py: the session file that tells the next daemon how this one ended.

After a crash the operator is told (daq/daemon/session_state.py): a recorder that dies
is noticed the moment it exits (its file is recovered, status and an event say so, a
new recording can start); a daemon started after an unclean end of the last session on
its rig says so, with the regulator's state as read at start, and refuses motion until
``daq ctl reset``.

For ``daq demo`` and scripts, :func:`run_sim_ramp` runs the whole thing as a library call.

Decision records: docs/decisions/0005-daemon-process-layout.md, docs/decisions/0017-crash-truth.md,
docs/decisions/0038-daemon-as-a-coordinator.md.
"""

from __future__ import annotations

import os
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import Field

from daq.config import load_rig
from daq.errors import InputError
from daq.ramps import Ramp
from daq.strict import Closed
from drivers.factory import RigDrivers, build_drivers

from .acquisition import Acquisition, AcquisitionCfg
from .children import BenchFactory, BenchHandle, EstimateMonitor, EstimatorProcess, let_the_bus_reach_the_recorder
from .handlers import ControlHandlers
from .motion import STANDSTILL, MotionGuard
from .ramp_runner import RampEvent, RampRunner, RampRunnerCfg
from .recording import RecordingSlot
from .rig_lock import RigLocks, lock_keys
from .session_state import MotionRefused, SessionKeeper, open_session, recover_recording, utcnow
from .status import StreamRates

__all__ = ["BenchProgress", "Daemon", "DaemonCfg", "run_sim_ramp"]


class DaemonCfg(Closed):
    rig: str
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


class Daemon:
    """One rig's daemon: starts its parts in order (bench, drivers, acquisition, estimator, session), stops
    them in reverse, and starts ramps; the parts say the rest (see the module's docstring).

    ``bench``: a factory for the (simulated) bench the instruments are on, called once at start with the rig
    and the previous session's bench (daq/daemon/sim_bench.py makes one); None: the rig's real instruments.
    Every part is an attribute from here on: None until :meth:`start` made it.
    """

    def __init__(self, cfg: DaemonCfg, bench: BenchFactory | None = None) -> None:
        self.cfg = cfg
        self.rig = load_rig(cfg.rig)
        self.rig_arg = cfg.rig  # the child processes' --rig: the bench's wiring of the rig, with a bench
        self.simulated = bench is not None
        self._make_bench = bench
        self.bench: BenchHandle | None = None
        self.drivers: RigDrivers | None = None
        self.acq: Acquisition | None = None
        self.estimator: EstimatorProcess | None = None
        self.monitor: EstimateMonitor | None = None
        self.web = None  # the live page's process (daq.web.process.WebProcess), set by `daq daemon --web`
        self.runner: RampRunner | None = None
        self.rates: StreamRates | None = None
        self.started = False
        self.t_start = time.monotonic()
        self.started_at = utcnow()
        self.lock = threading.RLock()
        self._stop = threading.Event()  # ends the rates and regulator threads
        self.session = SessionKeeper(cfg.state_dir, self.rig.rig) if cfg.state_dir is not None else None
        self.motion = MotionGuard()
        self.recording = RecordingSlot(self.lock, self._publish, self._forget_recording)
        self.control = ControlHandlers(self)
        sockets = [cfg.bus_endpoint] + ([cfg.control_endpoint] if cfg.control_endpoint else [])
        self.locks = RigLocks(lock_keys(self.rig, self.simulated, sockets),
                              holder=f"daemon pid {os.getpid()} for rig {self.rig.rig} "
                                     f"(data dir {Path(cfg.data_dir).absolute()})")

    # --- life cycle
    def start(self) -> Daemon:
        """Start everything; with a state directory, also find out how the last session on this rig ended."""
        try:
            self.locks.acquire()  # RigBusy if a live daemon holds the rig, an instrument or a socket, any data dir
            if self.session is not None:
                self.session.acquire()  # SessionBusy if a live daemon holds the rig
            self._start_parts()
        except BaseException:
            self._release()
            if self.session is not None:
                self.session.release()  # the previous session's file stays as it was
            self.locks.release()
            raise
        self.rates = StreamRates(self.acq.counters)
        threading.Thread(target=self._tick_loop, name="rates", daemon=True).start()
        threading.Thread(target=self.motion.watch, args=(self._stop,), name="regulator-watch", daemon=True).start()
        self.started = True
        return self

    def _start_parts(self) -> None:
        endpoints = None
        if self._make_bench is not None:
            prev = self.session.previous if self.session is not None else None
            self.bench = self._make_bench(self.rig, prev.sim_bench if prev else None)
            self.rig, self.rig_arg, endpoints = self.bench.rig, self.bench.rig_arg, self.bench.endpoints
        self.drivers = build_drivers(self.rig, endpoints)
        self.drivers.open()
        self.acq = Acquisition(self.rig, self.drivers, AcquisitionCfg(endpoint=self.cfg.bus_endpoint))
        self.acq.start()
        if self.cfg.estimator:
            self.estimator = EstimatorProcess(self.rig_arg, self.acq.endpoint, self.cfg.estimator_endpoint,
                                              self.cfg.start_timeout_s)
            self.monitor = EstimateMonitor(self.estimator.endpoint)
        self.motion.attach(self.drivers.motor, self.bench, self._publish)
        self.motion.read_regulator()
        if self.session is not None:
            bench = self.bench
            self.motion.unclean = open_session(self.session, self.started_at, bench.ref() if bench else None,
                                               bench is not None and not bench.attached, self.motion.regulator)
            if self.motion.unclean is not None:
                self._publish("unclean_end", "daemon", self.motion.unclean.summary())

    def _release(self) -> None:
        """Stop the parts in reverse order of their start; one not started is None, one failing stops no other."""
        for part, how in ((self.monitor, "close"), (self.estimator, "stop"), (self.acq, "stop"),
                          (self.drivers, "close"), (self.bench, "stop")):
            if part is None:
                continue
            try:
                getattr(part, how)()
            except Exception:  # noqa: BLE001 - release the rest regardless
                pass

    def shutdown(self) -> None:
        """Controlled stop: ramp the belt down, close the recording, release everything."""
        with self.lock:
            if not self.started:
                return
            self.started = False
            self._stop.set()
            try:
                self.halt("stop", "controlled stop")
                self.wait_standstill(self.cfg.ramp_down_timeout_s)
            except Exception:  # noqa: BLE001 - shutting down regardless; the watchdog is the backstop
                pass
            rec = self.recording.recorder
            if rec is not None:
                let_the_bus_reach_the_recorder(self.cfg.flush_s)  # the ramp-down's last samples
                if rec.stop() != 0:
                    recover_recording(rec.path)
                self.recording.recorder = None
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

    def _tick_loop(self) -> None:
        """Once a second: the streams' rates (for status), the session's heartbeat, an attached bench's keepalive."""
        while not self._stop.wait(1.0):
            self.rates.update()
            try:
                if self.session is not None:
                    r = self.runner
                    self.session.heartbeat(self.recording.ref(), r.source if r is not None and r.running else None)
                if self.bench is not None:
                    self.bench.keepalive()
            except OSError as exc:  # a full disk must not stop the status thread; say it once a second
                print(f"daq daemon: session state: {exc}", file=sys.stderr, flush=True)

    def _publish(self, kind: str, source: str, detail: str) -> None:
        self.acq.publish_event(kind, source, detail)

    def _forget_recording(self) -> None:
        """A recorder died: the session state no longer names its file (a full disk: it tried)."""
        if self.session is not None:
            try:
                self.session.update(recording=None)
            except OSError:
                pass

    # --- motion
    def handlers(self) -> dict[str, Callable[[dict], dict]]:
        """The control socket's operations (daq/daemon/handlers.py): op name -> handler."""
        return self.control.table()

    def start_ramp(self, make: Callable[..., RampRunner], label: str, time_scale: float = 1.0) -> RampRunner:
        """Validate (before any motion) and start a ramp; ``make(motor, vmax, amax, **kw)`` builds the runner."""
        with self.lock:
            if not self.started:
                raise RuntimeError("daemon is not running")
            d = self.rig.drive
            runner = make(self.drivers.motor, d.max_speed_m_per_s, d.max_accel_m_per_s2,
                          cfg=RampRunnerCfg(time_scale=float(time_scale)), on_event=self._on_ramp_event)
            # the latch first: a ramp that runs into a latched regulator has not ended yet, and "stop it first"
            # would send the operator the wrong way (the belt needs a reset, not a stop)
            why = self.motion.refusal(read=True)
            if why is not None:
                self._publish("motion_refused", "daemon", f"{label}: {why}")
                raise MotionRefused(why)
            if self.runner is not None and self.runner.running:
                raise RuntimeError("a ramp is already running; stop it first")
            self.runner = runner.start()
            self.motion.halted = False
        self._publish("ramp_start", "ramp", label)
        if self.session is not None:
            self.session.update(ramp=runner.source)
        return runner

    def _on_ramp_event(self, ev: RampEvent) -> None:
        self._publish("ramp_segment" if ev.kind.startswith("segment") else f"ramp_{ev.kind}", "ramp",
                      f"{ev.kind} {ev.index if ev.index is not None else ''} {ev.segment or ''} {ev.reason}".strip())

    def halt(self, how: str, detail: str) -> None:
        """Stop (``how`` = "stop": a controlled ramp-down) or e-stop the belt, through the ramp if one runs."""
        self.motion.halted = True
        target = self.runner if self.runner is not None and self.runner.running else self.drivers.motor
        getattr(target, how)()
        self._publish(how, "operator", detail)


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


def run_sim_ramp(rig: str, ramp: str | Path | Any, out: str | Path, *, effects: list[str] = (),
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
    # the caller that wants a simulated bench builds it (the Daemon does not know the simulator)
    from daq.sim.effectset import parse_effect

    from .sim_bench import SimBenchCfg, sim_bench_factory

    out = Path(out)
    work = Path(workdir) if workdir is not None else Path(tempfile.mkdtemp(prefix="daq-bench-"))
    bench = sim_bench_factory(SimBenchCfg(rig=rig, effects=list(effects), time_scale=sim_time_scale, seed=seed,
                                          workdir=work / "dev"))
    d = Daemon(DaemonCfg(rig=rig, data_dir=out.parent, bus_endpoint="tcp://127.0.0.1:0"), bench=bench)
    make, label = _ramp_maker(ramp)
    for e in effects:  # bad input: InputError before anything starts
        parse_effect(e, "effects")
    drive = load_rig(rig).drive  # refuse a ramp the rig cannot run before starting anything
    make(None, drive.max_speed_m_per_s, drive.max_accel_m_per_s2, cfg=RampRunnerCfg(time_scale=ramp_time_scale))
    if out.exists():
        raise InputError(str(out), "out", "exists; recordings are never overwritten")
    d.start()
    try:
        d.control.handle_record_start({"path": str(out)})
        runner = d.start_ramp(make, label, ramp_time_scale)
        limit = timeout_s if timeout_s is not None else runner.duration / max(sim_time_scale, 1e-9) * 3 + 60
        _follow(d, runner, limit, progress, progress_s)
        d.wait_standstill(d.cfg.ramp_down_timeout_s)
        let_the_bus_reach_the_recorder(d.cfg.flush_s)  # the last estimates reach the file
        if runner.state != "finished":
            raise RuntimeError(f"ramp {runner.state}: {runner.reason}")
        d.control.handle_record_stop({})
        return out
    finally:
        d.shutdown()


def _ramp_maker(ramp: str | Path | Ramp) -> tuple[Callable[..., RampRunner], str]:
    """``make(motor, vmax, amax, **kw)`` for :meth:`Daemon.start_ramp`, and the ramp's label."""
    if isinstance(ramp, Ramp):
        def make(m, v, a, **kw):
            return RampRunner.from_ramp(m, ramp, v, a, source=ramp.name, **kw)
        return make, ramp.name
    path = str(ramp)

    def make_from_file(m, v, a, **kw):
        return RampRunner.from_file(m, path, v, a, **kw)
    return make_from_file, path


def _follow(d: Daemon, runner: RampRunner, limit: float, progress: Callable[[BenchProgress], None] | None,
            progress_s: float) -> None:
    """Until the ramp ends, tell ``progress`` every ``progress_s``; stop it and RuntimeError after ``limit`` s."""
    t0 = time.monotonic()
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
            return
        if time.monotonic() - t0 > limit:
            runner.stop()
            raise RuntimeError(f"ramp did not finish within {limit:.0f} s")
