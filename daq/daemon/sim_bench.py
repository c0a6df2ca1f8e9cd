"""The simulated bench, as the caller that wants ``--sim`` hands it to the daemon.

The daemon (daq/daemon/service.py) does not know the simulator exists: it takes a *bench factory*
(:data:`daq.daemon.children.BenchFactory`) and calls it once at start with the rig and the previous
session's bench reference. ``daq daemon --sim`` and :func:`daq.daemon.service.run_sim_ramp` build
the factory here, with :func:`sim_bench_factory`.

Why reattach (daq/daemon/session_state.py says more): on a real rig the regulator outlives the
daemon and its latched watchdog trip is there to be read; a fresh simulated bench would have forgotten
it. So the previous session's bench, if it still runs the same simulation, is attached to
(:class:`AttachedSimBench`), else a new one is started (``sim_backends.process.SimBenchProcess``).

Decision record: docs/decisions/0038-daemon-as-a-coordinator.md.
"""

from __future__ import annotations

import json
import os
import signal
import tempfile
import time
from pathlib import Path
from typing import Any

from pydantic import Field

from daq.config import RigConfig, config_text
from daq.streaming.child_process import pid_alive
from daq.strict import Closed
from sim_backends.bench_client import SimBenchProcess, cross_process_wiring
from sim_backends.bench_client import request as bench_request

from .children import BenchFactory
from .session_state import BenchRef, pid_runs


class SimBenchCfg(Closed):
    """What to simulate: ``daq daemon --sim``'s options."""

    rig: str
    effects: list[str] = Field(default_factory=list, description="hidden effects of the simulated rig")
    time_scale: float = Field(1.0, gt=0)
    seed: int = 0
    workdir: Path | None = Field(None, description="where simulated serial devices appear (default: a temp dir)")
    start_timeout_s: float = Field(180.0, gt=0, description="for the bench process to come up")


class SimBench:
    """The daemon's handle on a simulated bench (a :class:`daq.daemon.children.BenchHandle`): the process
    (started now, or the last session's, attached) and the rig as wired across processes."""

    def __init__(self, process: SimBenchProcess | AttachedSimBench, rig: RigConfig, cfg: SimBenchCfg) -> None:
        self.process = process
        self.cfg = cfg
        self.rig = rig  # CAN channels moved to serial streams: a pty crosses processes
        self.attached = isinstance(process, AttachedSimBench)
        self.pid: int = process.pid
        self.control: str = process.control
        self.endpoints: dict[str, dict[str, Any]] = process.endpoints
        self.workdir = Path(process.workdir)
        wired = self.workdir / f"{rig.rig}.toml"  # what the recordings store: the wiring in use
        wired.write_text(config_text(rig))
        self.rig_arg = str(wired)

    def ref(self) -> BenchRef:
        """What the session state keeps, so that the next daemon can attach to this bench."""
        return BenchRef(pid=self.pid, control=self.control, workdir=str(self.workdir.resolve()),
                        endpoints=self.endpoints, rig=self.cfg.rig, effects=list(self.cfg.effects),
                        time_scale=self.cfg.time_scale, seed=self.cfg.seed)

    def watchdog_trips(self) -> int | None:
        """The regulator's watchdog trip counter, as the bench tells it (None: it does not answer)."""
        try:
            return int(self.process.status().get("watchdog_trips"))
        except (TimeoutError, OSError, TypeError, ValueError):
            return None

    def keepalive(self) -> None:
        """An attached bench exits once nobody asks for its status for its linger time: ask (a started one
        has us as its owner)."""
        if isinstance(self.process, AttachedSimBench):
            self.process.keepalive()

    def alive(self) -> bool:
        return self.process.alive()

    def stop(self) -> None:
        self.process.stop()


def sim_bench_factory(cfg: SimBenchCfg) -> BenchFactory:
    """The factory the daemon calls at start: the previous session's bench if it still runs the same
    simulation, else a new one (owned by this process, so it exits a linger time after we are gone)."""

    def start(rig: RigConfig, previous: BenchRef | None) -> SimBench:
        wired = cross_process_wiring(rig)
        attached = AttachedSimBench.find(previous, cfg.rig, cfg.workdir, cfg.effects, cfg.time_scale, cfg.seed)
        if attached is not None:
            return SimBench(attached, wired, cfg)
        workdir = cfg.workdir or Path(tempfile.mkdtemp(prefix=f"daq-sim-{rig.rig}-"))
        process = SimBenchProcess(cfg.rig, workdir, effects=cfg.effects, time_scale=cfg.time_scale, seed=cfg.seed,
                                  owner_pid=os.getpid(), start_timeout_s=cfg.start_timeout_s)
        return SimBench(process, wired, cfg)

    return start


class AttachedSimBench:
    """The previous session's simulated bench, still running: what SimBenchProcess offers the daemon.

    Not our child: liveness is by pid, and the bench (whose owner died) exits once nobody has
    asked for its status for its linger time, so ``keepalive`` asks every few seconds.
    """

    KEEPALIVE_S = 5.0

    def __init__(self, ref: BenchRef) -> None:
        self.ref = ref
        self.pid = ref.pid
        self.control = ref.control
        self.endpoints = ref.endpoints
        self.workdir = Path(ref.workdir)
        self._last_ping = time.monotonic()

    @classmethod
    def find(cls, ref: BenchRef | None, rig: str, workdir: Path | None, effects: list[str], time_scale: float,
             seed: int) -> AttachedSimBench | None:
        """The bench of ``ref`` if it runs the same simulation and answers; else None (start a new one)."""
        if ref is None or ref.rig != rig or ref.effects != list(effects) or ref.time_scale != time_scale \
                or ref.seed != seed:
            return None
        if workdir is not None and Path(workdir).resolve() != Path(ref.workdir).resolve():
            return None
        try:
            info = json.loads((Path(ref.workdir) / "sim.json").read_text())
        except (OSError, ValueError):
            return None
        if info.get("pid") != ref.pid or not pid_runs(ref.pid, "sim_backends.process"):
            return None
        try:
            bench_request(ref.control, "status", timeout_s=2.0)
        except (TimeoutError, OSError):
            return None
        return cls(ref)

    def request(self, op: str, timeout_s: float = 5.0) -> dict[str, Any]:
        self._last_ping = time.monotonic()
        return bench_request(self.control, op, timeout_s)

    def status(self) -> dict[str, Any]:
        return self.request("status")

    def keepalive(self) -> None:
        if time.monotonic() - self._last_ping >= self.KEEPALIVE_S:
            try:
                self.request("status", timeout_s=1.0)
            except (TimeoutError, OSError):
                pass

    def alive(self) -> bool:
        return pid_alive(self.pid)

    def stop(self, timeout: float = 10.0) -> None:
        """Ask the bench to exit (as the daemon that started it would); SIGTERM if it does not."""
        if not self.alive():
            return
        try:
            self.request("exit", timeout_s=2.0)
        except (TimeoutError, OSError):
            try:
                os.kill(self.pid, signal.SIGTERM)
            except ProcessLookupError:
                return
        t_end = time.monotonic() + timeout
        while self.alive() and time.monotonic() < t_end:
            time.sleep(0.05)
        if self.alive():
            os.kill(self.pid, signal.SIGKILL)
