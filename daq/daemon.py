"""The operator daemon: one rig's drivers, the bus, the recorder and the estimator, under control.

``daq daemon --rig RIG [--sim]`` assembles what the lab runs: the drivers from the
rig config (or pointed at a simulated bench with ``--sim``), the acquisition pump
onto the sample bus, the online estimator, a recorder that writes the bus to one
HDF5 file per run, and the ramp runner. Operators drive it through the control
socket (``daq ctl``). On SIGTERM/SIGINT it ramps the belt down before it exits;
if it dies instead, the regulator's watchdog stops the belt.
"""

from __future__ import annotations

import datetime as _dt
import signal
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from .acquisition import Acquisition, AcquisitionCfg
from .bus import Subscriber
from .config import load_rig
from .errors import InputError
from .estimation.online import OnlineCfg, OnlineEstimator
from .ramp_runner import RampEvent, RampRunner, RampRunnerCfg
from .recorder import RunWriter
from .sim.effectset import parse_effect
from .stream import Block, BusEvent

STANDSTILL = 1e-3  # [m/s]


class DaemonCfg(BaseModel):
    model_config = ConfigDict(extra="forbid")
    rig: str
    sim: bool = False
    sim_effects: list[str] = Field(default_factory=list, description="hidden effects of the simulated rig")
    sim_time_scale: float = Field(1.0, gt=0)
    workdir: Path | None = Field(None, description="where simulated serial devices appear (default: a temp dir)")
    data_dir: Path = Path("data")
    bus_endpoint: str = "tcp://127.0.0.1:5560"
    estimator_endpoint: str = "tcp://127.0.0.1:5561"
    flush_s: float = Field(0.25, gt=0)
    ramp_down_timeout_s: float = Field(10.0, gt=0)


class RecordingSession:
    """Writes everything on the bus (samples, estimator output, events) into one run file."""

    def __init__(self, path: Path, endpoints: list[str], rig_cfg, flush_s: float, ramp_text: str = "") -> None:
        self.path = path
        self.writer = RunWriter()
        self.writer.open(path, rig_cfg, ramp_text)
        self.sub = Subscriber(endpoints[0], rcvhwm=100_000, name="recorder")
        for ep in endpoints[1:]:
            self.sub.sock.connect(ep)
        self.flush_s = flush_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="recorder", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        last = time.monotonic()
        while not self._stop.is_set():
            m = self.sub.recv(0.05)
            if isinstance(m, Block):
                try:
                    self.writer.append(m)
                except ValueError as exc:  # a block the file cannot hold: keep the rest
                    self.writer.note("rejected", str(exc))
            elif isinstance(m, BusEvent):
                self.writer.event(m)
            if time.monotonic() - last > self.flush_s:
                self.writer.flush()
                last = time.monotonic()

    def note(self, text: str) -> None:
        self.writer.note("note", text, source="operator")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.writer.close()
        self.sub.close()


class Daemon:
    def __init__(self, cfg: DaemonCfg) -> None:
        self.cfg = cfg
        self.rig = load_rig(cfg.rig)
        self.hw = None
        self.runner: RampRunner | None = None
        self.session: RecordingSession | None = None
        self.started = False
        self._lock = threading.RLock()

    # --- life cycle
    def start(self) -> "Daemon":
        from drivers.factory import build_drivers

        endpoints = None
        if self.cfg.sim:
            from sim_backends.hardware import SimulatedHardware

            workdir = self.cfg.workdir or Path(tempfile.mkdtemp(prefix=f"daq-sim-{self.rig.rig}-"))
            effects = [parse_effect(x, "--effect") for x in self.cfg.sim_effects]
            self.hw = SimulatedHardware(self.rig, workdir, effects=effects,
                                        time_scale=self.cfg.sim_time_scale).start()
            endpoints = self.hw.endpoints()
        self.drivers = build_drivers(self.rig, endpoints)
        self.drivers.open()
        self.acq = Acquisition(self.rig, self.drivers, AcquisitionCfg(endpoint=self.cfg.bus_endpoint))
        self.acq.start()
        self.estimator = OnlineEstimator(self.rig, OnlineCfg(sub_endpoint=self.acq.endpoint,
                                                             pub_endpoint=self.cfg.estimator_endpoint,
                                                             fit="thread"))
        self.estimator.start()
        self.estimator_endpoint = self.estimator.endpoint
        self.started = True
        return self

    def shutdown(self) -> None:
        """Controlled stop: ramp the belt down, close the recording, release everything."""
        with self._lock:
            if not self.started:
                return
            self.started = False
            try:
                self.handle_stop({})
                self.wait_standstill(self.cfg.ramp_down_timeout_s)
            except Exception:  # noqa: BLE001 - shutting down regardless; the watchdog is the backstop
                pass
            if self.session is not None:
                self.session.close()
                self.session = None
            self.estimator.stop()
            self.acq.stop()
            self.drivers.close()
            if self.hw is not None:
                self.hw.stop()

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

    # --- control handlers (each takes the request's args, returns a result dict)
    def handlers(self) -> dict[str, Any]:
        return {"status": self.handle_status, "ramp": self.handle_ramp, "stop": self.handle_stop,
                "estop": self.handle_estop, "record_start": self.handle_record_start,
                "record_stop": self.handle_record_stop, "note": self.handle_note}

    def handle_status(self, args: dict) -> dict:
        st = self.acq.status()
        out: dict[str, Any] = {"rig": self.rig.rig, "sim": self.cfg.sim, "acquisition": st,
                               "estimator": self.estimator.stats.model_dump(),
                               "recording": str(self.session.path) if self.session else None}
        if self.runner is not None:
            p = self.runner.progress()
            out["ramp"] = {"state": str(p.state), "t": p.t, "fraction": p.fraction, "segment": p.segment,
                           "commanded": p.commanded, "measured": p.measured}
        return out

    def _on_ramp_event(self, ev: RampEvent) -> None:
        self.acq.publish_event("ramp_segment" if ev.kind.startswith("segment") else f"ramp_{ev.kind}", "ramp",
                               f"{ev.kind} {ev.index if ev.index is not None else ''} {ev.segment or ''} "
                               f"{ev.reason}".strip())

    def handle_ramp(self, args: dict) -> dict:
        with self._lock:
            if self.runner is not None and self.runner.running:
                raise RuntimeError("a ramp is already running; stop it first")
            d = self.rig.drive
            runner = RampRunner.from_file(self.drivers.motor, args["file"], d.max_speed_m_per_s, d.max_accel_m_per_s2,
                                          cfg=RampRunnerCfg(time_scale=float(args.get("time_scale", 1.0))),
                                          on_event=self._on_ramp_event)
            self.runner = runner.start()
        self.acq.publish_event("ramp_start", "ramp", str(args["file"]))
        return {"started": str(args["file"])}

    def handle_stop(self, args: dict) -> dict:
        if self.runner is not None and self.runner.running:
            self.runner.stop()
        else:
            self.drivers.motor.stop()
        self.acq.publish_event("stop", "operator", "controlled stop")
        return {"stopping": True}

    def handle_estop(self, args: dict) -> dict:
        if self.runner is not None and self.runner.running:
            self.runner.estop()
        else:
            self.drivers.motor.estop()
        self.acq.publish_event("estop", "operator", "emergency stop")
        return {"estop": True}

    def handle_record_start(self, args: dict) -> dict:
        with self._lock:
            if self.session is not None:
                raise RuntimeError(f"already recording to {self.session.path}")
            stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
            path = Path(args.get("path") or self.cfg.data_dir / f"{self.rig.rig}-{stamp}.h5")
            if path.exists():
                raise InputError(str(path), "path", "exists; recordings are never overwritten")
            path.parent.mkdir(parents=True, exist_ok=True)
            self.session = RecordingSession(path, [self.acq.endpoint, self.estimator_endpoint], self.rig,
                                            self.cfg.flush_s)
        return {"recording": str(path)}

    def handle_record_stop(self, args: dict) -> dict:
        with self._lock:
            if self.session is None:
                raise RuntimeError("not recording")
            path = self.session.path
            self.session.close()
            self.session = None
        return {"closed": str(path)}

    def handle_note(self, args: dict) -> dict:
        text = str(args["text"])
        self.acq.publish_event("note", "operator", text)
        return {"noted": text}
