"""Starting, asking and stopping a simulated bench (``python -m sim_backends.process``) from another process: the
daemon with ``--sim``, the soak, the campaign's supervision, the tests.

Why apart from the bench itself (process.py): a process that only starts or asks a bench must not import the
simulator (numba, scipy, the rigs): with both in one module every ``daq daemon --sim`` imported them for a class
and a request, 1.5 s of CPU each on a 2-core machine (``python -X importtime``, 2026-11-28).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import zmq

from daq.config import CanSettings, RigConfig, StreamSettings, parse_rig
from daq.streaming.child_process import pid_alive, terminate

__all__ = ["SimBenchProcess", "cross_process_wiring", "end_bench", "pid_alive", "read_ready", "request", "stop_daemon",
           "wait_gone"]


def cross_process_wiring(cfg: RigConfig) -> RigConfig:
    """The rig with its CAN-carried channels on a serial stream (usable from another process).

    A disabled serial-stream instrument that carries exactly those channels is enabled (the
    rig configs' ``laser_serial``); otherwise one named ``<can>_serial`` is made for them.
    """
    cans = {n: i for n, i in cfg.instruments.items() if isinstance(i, CanSettings) and i.enabled}
    if not cans:
        return cfg
    data = cfg.model_dump(mode="json", exclude_none=True)
    insts = data["instruments"]
    n_masses = getattr(cfg.mechanics, "n_masses", None)  # belt-ndof: x2, x3 exist only with more masses
    for name, can in cans.items():
        insts[name]["enabled"] = False
        chans = [c for c in can.channels
                 if not (n_masses and c[:1] == "x" and c[1:].isdigit() and int(c[1:]) > n_masses)]
        alt = next((n for n, i in cfg.instruments.items()
                    if isinstance(i, StreamSettings) and not i.enabled and set(i.channels) == set(chans)), None)
        if alt is not None:
            insts[alt]["enabled"] = True
        else:
            insts[f"{name}_serial"] = {"family": "serial-stream", "url": f"/dev/null/{name}_serial",
                                       "baudrate": 921600, "channels": chans}
    return parse_rig(data, f"{cfg.rig} (cross-process wiring)")


def wait_gone(pid: int | None, timeout: float, poll_s: float = 0.05) -> bool:
    """True once process ``pid`` has ended (within ``timeout``)."""
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if not pid_alive(pid):
            return True
        time.sleep(poll_s)
    return not pid_alive(pid)


def read_ready(proc: subprocess.Popen, timeout_s: float, hint: str = "") -> dict[str, str]:
    """The fields (``key=value``) of a ``daq daemon`` child's ready line, its first line on stdout, waited for at
    most ``timeout_s``. If another line comes, or none, the child is killed and RuntimeError says what came
    (``hint`` appended: where its stderr is). The rest of its stdout is the caller's to read. The one copy for the
    tests' daemons, the soak and the web benchmark."""
    box: list[str] = []
    reader = threading.Thread(target=lambda: box.append(proc.stdout.readline()), name="daemon-ready", daemon=True)
    reader.start()
    reader.join(timeout_s)
    line = box[0] if box else ""
    if "ready" not in line:
        proc.kill()
        raise RuntimeError(f"the daemon did not start within {timeout_s:g} s: {line.strip()!r}{hint}")
    return dict(re.findall(r"(\w+)=(\S+)", line))


def stop_daemon(proc: subprocess.Popen, wait_s: float = 60.0) -> None:
    """SIGTERM a ``daq daemon`` child (it ramps down and closes any recording), SIGKILL it after ``wait_s``."""
    terminate(proc, wait_s, kill_wait_s=None)


def end_bench(pid: int | None, control: str | None, ask_s: float, wait_s: float) -> None:
    """End a simulated bench, which outlives its daemon by design: asked to exit over ``control`` (waiting ``ask_s``
    for its answer), then SIGKILLed if it has not gone within ``wait_s``. The one copy for the tests' daemons, the
    soak and the campaign's supervision."""
    if not pid_alive(pid):
        return
    if control:
        try:
            request(control, "exit", timeout_s=ask_s)
        except TimeoutError:
            pass
    if not wait_gone(pid, wait_s):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


class SimBenchProcess:
    """Starts ``python -m sim_backends.process`` in its own session and talks to its control socket."""

    def __init__(self, rig: str, workdir: str | Path, effects: list[str] = (), time_scale: float = 1.0,
                 seed: int = 0, owner_pid: int | None = None, linger_s: float = 30.0,
                 start_timeout_s: float = 120.0) -> None:
        self.rig = rig
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-m", "sim_backends.process", "--rig", str(rig), "--workdir", str(self.workdir),
               "--time-scale", repr(float(time_scale)), "--seed", str(seed), "--linger-s", repr(float(linger_s))]
        for e in effects:
            cmd += ["--effect", e]
        if owner_pid:
            cmd += ["--owner-pid", str(owner_pid)]
        self._log = open(self.workdir / "sim.log", "ab")
        # its own session: a signal to the daemon's process group (Ctrl-C, systemd) must not reach the bench
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self._log, start_new_session=True,
                                     cwd=str(Path(__file__).resolve().parent.parent))
        self.pid = self.proc.pid
        self.info = self._wait_ready(start_timeout_s)
        self.endpoints: dict[str, dict[str, Any]] = self.info["endpoints"]
        self.control: str = self.info["control"]

    def _wait_ready(self, timeout: float) -> dict[str, Any]:
        box: list[str] = []
        th = threading.Thread(target=lambda: box.append(self.proc.stdout.readline().decode()), daemon=True)
        th.start()
        th.join(timeout)
        line = box[0] if box else ""
        if not line.strip():
            self.kill()
            tail = (self.workdir / "sim.log").read_text(errors="replace").strip().splitlines()[-1:]
            raise RuntimeError(f"simulated bench did not start within {timeout:g} s: {' '.join(tail)}")
        return json.loads(line)

    def request(self, op: str, timeout_s: float = 5.0) -> dict[str, Any]:
        return request(self.control, op, timeout_s)

    def status(self) -> dict[str, Any]:
        return self.request("status")

    def belt_speed(self) -> float:
        return float(self.status()["belt_speed"])

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout: float = 10.0) -> None:
        """Ask the bench to exit; SIGTERM, then SIGKILL, if it does not."""
        if self.proc.poll() is None:
            try:
                self.request("exit", timeout_s=2.0)
            except (TimeoutError, OSError):
                self.proc.terminate()
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.kill()
        self._close_files()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
        self._close_files()

    def _close_files(self) -> None:
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        self._log.close()


def request(control: str, op: str, timeout_s: float = 5.0) -> dict[str, Any]:
    """One request to a bench's control socket (from any process: tests, the daemon's status)."""

    ctx = zmq.Context.instance()
    s = ctx.socket(zmq.REQ)
    s.setsockopt(zmq.LINGER, 0)
    try:
        s.connect(control)
        s.send_string(json.dumps({"op": op}))
        if not s.poll(int(timeout_s * 1000)):
            raise TimeoutError(f"simulated bench at {control}: no reply to {op!r}")
        return json.loads(s.recv())
    finally:
        s.close()
