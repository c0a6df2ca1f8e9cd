"""The per-row daemon of a simulated campaign: started, watched, ended — also after the campaign was killed.

Thrust on the simulated rig (``--sim``): each thrust row gets a copy of the rig config with
``mechanics.thrust_N = P`` and its own ``daq daemon --rig COPY.toml --sim`` (``DaemonRow``), on free
loopback ports, its output in ``OUT/logs/``. The child gets the kernel's parent-death signal, so a
campaign killed even by SIGKILL takes its daemon with it (controlled ramp-down, recording closed);
the ids of every daemon and simulated bench are kept in the state, and a resume ends what a killed
run left (``end_stale``, only processes that are recognisably ours).
"""

from __future__ import annotations

import ctypes
import os
import re
import signal
import subprocess
import sys
import time
import zlib
from pathlib import Path
from typing import Callable

from sim_backends.bench_client import end_bench, pid_alive, stop_daemon, wait_gone

from .state import DaemonInfo

START_TIMEOUT_S = 180.0  # daemon start (numba caches on a cold machine)
POLL_S = 0.1  # how often a wait for a process to end looks
ROOT = Path(__file__).resolve().parents[3]  # the repository: where `python -m daq.cli` finds the packages


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM when the campaign dies (even by kill -9), so the daemon
    ramps the drum down and closes its recording instead of running on as an orphan (Linux)."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode("utf-8", "replace")
    except OSError:
        return ""


def end_stale(info: DaemonInfo | None, say: Callable[[str], None]) -> None:
    """End the daemon and bench a killed campaign left (by their recorded ids, only if they are ours)."""
    if info is None:
        return

    if pid_alive(info.pid) and "daemon" in _cmdline(info.pid):
        say(f"campaign: waiting for the daemon of the interrupted run (pid {info.pid}) to ramp down and exit")
        if not wait_gone(info.pid, 2.0, POLL_S):  # it got SIGTERM from the kernel when we died; give it time
            os.kill(info.pid, signal.SIGTERM)
            if not wait_gone(info.pid, 30.0, POLL_S):
                os.kill(info.pid, signal.SIGKILL)
                wait_gone(info.pid, 5.0, POLL_S)
    bench = info.sim_bench_pid
    if bench and pid_alive(bench) and "sim_backends" in _cmdline(bench) and not wait_gone(bench, 5.0, POLL_S):
        end_bench(bench, info.sim_control, ask_s=1.0, wait_s=5.0)


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

        stop_daemon(self.proc)
        # the daemon ends its bench as it shuts down; ask it ourselves only if it is still there
        if self.sim_pid and not wait_gone(self.sim_pid, 5.0, POLL_S):
            end_bench(self.sim_pid, self.sim_control, ask_s=1.0, wait_s=5.0)
