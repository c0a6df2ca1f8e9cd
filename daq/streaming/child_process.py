"""Ending and watching child processes: the one copy for the daemon's children and the simulated bench's clients.

Here, in a low layer, because both the daemon (daq.daemon) and the simulated bench's helpers
(sim_backends.process) use it, and sim_backends may not import the daemon nor the daemon the simulator.
"""

from __future__ import annotations

import os
import signal
import subprocess


def terminate(proc: subprocess.Popen, wait_s: float, kill_wait_s: float | None = 10.0) -> int | None:
    """SIGTERM ``proc`` (a child that closes its files on it), SIGKILL it if it has not ended within ``wait_s``;
    its exit status (None if even the SIGKILL was not reaped within ``kill_wait_s``; None waits for ever)."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(kill_wait_s)
    return proc.returncode


def pid_alive(pid: int | None) -> bool:
    """True if process ``pid`` runs: a zombie (dead, not yet reaped by its parent) counts as gone, as does no pid.

    The one copy for the daemon's session state, the campaign's supervision and the simulated bench's owner check.
    """
    if not pid:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: it exists
        return True
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return True
