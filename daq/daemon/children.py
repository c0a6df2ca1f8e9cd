"""The daemon's child processes, and what it needs of a bench handed in from outside.

* :class:`EstimatorProcess`: ``python -m daq.daemon.estimator_process`` on the daemon's bus; its stats for status.
* :class:`RecorderProcess`: ``python -m daq.streaming.recorder``, one per recording.
* :class:`EstimateMonitor`: the latest estimate and law fit from the estimator's stream (a socket, not a process).
* :class:`BenchHandle` / :data:`BenchFactory`: the simulated bench, as the caller builds it (daq/daemon/sim_bench.py
  for ``--sim``); the daemon only calls what the protocol names, so it never imports the simulator.

Decision records: docs/decisions/0005-daemon-process-layout.md, docs/decisions/0038-daemon-as-a-coordinator.md.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from daq.config import RigConfig
from daq.io.stream_format import Block
from daq.streaming.bus import Subscriber
from daq.streaming.child_process import terminate

from .session_state import BenchRef, utcnow

ROOT = Path(__file__).resolve().parents[2]  # the repository: where `python -m daq...` finds the packages


def popen(args: list[str], **kw: Any) -> subprocess.Popen:
    """``python -m ARGS`` from the repository (the interpreter that runs us)."""
    return subprocess.Popen([sys.executable, "-m", *args], cwd=str(ROOT), **kw)


def first_line(proc: subprocess.Popen, timeout: float, what: str) -> str:
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


def let_the_bus_reach_the_recorder(flush_s: float) -> None:
    """Wait two flush periods before a recorder is stopped, so that the last samples and events reach its file.

    Why a wait and not a condition: what is still in flight cannot be observed from the daemon. The
    acquisition is still batching samples taken before the stop into a block, the estimator lags the bus
    by its own block, both travel on their own sockets, and the recorder acknowledges nothing it receives
    (its stdout names a stream once, when the stream's datasets exist). Once stopped it drains what has
    reached its queue; two of its flush periods cover a block of each publisher.
    """
    time.sleep(2 * flush_s)


class BenchHandle(Protocol):
    """A (simulated) bench the caller started for the daemon: its instruments' endpoints and its regulator's
    trip counter. :class:`daq.daemon.sim_bench.SimBench` is the one there is."""

    pid: int
    control: str
    endpoints: dict[str, dict[str, Any]]
    rig: RigConfig  # the rig as the bench wires it (what the drivers open and the recordings store)
    rig_arg: str  # ... as the child processes' --rig argument
    attached: bool  # the previous session's bench (its regulator is the one that may have tripped)

    def ref(self) -> BenchRef: ...
    def watchdog_trips(self) -> int | None: ...
    def keepalive(self) -> None: ...
    def alive(self) -> bool: ...
    def stop(self) -> None: ...


# (the rig, the previous session's bench or None) -> the bench to drive
BenchFactory = Callable[[RigConfig, "BenchRef | None"], BenchHandle]


class EstimatorProcess:
    """``python -m daq.daemon.estimator_process`` on the daemon's bus; its stats lines are kept for status."""

    def __init__(self, rig: str, sub_endpoint: str, pub_endpoint: str, timeout: float) -> None:
        self.proc = popen(["daq.daemon.estimator_process", "--rig", rig, "--sub", sub_endpoint, "--pub", pub_endpoint,
                           "--parent-pid", str(os.getpid())], stdout=subprocess.PIPE, text=True)
        self.pid = self.proc.pid
        info = json.loads(first_line(self.proc, timeout, "the estimator process"))
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
        terminate(self.proc, 15)
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
        self.proc = popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.pid = self.proc.pid
        self.streams: list[str] = []
        self.progress = ""
        self.closed_line = ""
        self.stopping = False  # set before the daemon itself ends it: any other exit is a failure
        self.ended_at: _dt.datetime | None = None
        self._stream_seen = threading.Condition()
        line = first_line(self.proc, timeout, "the recorder process")
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
        return terminate(self.proc, timeout)


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
