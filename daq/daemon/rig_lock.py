"""One daemon per rig, whatever its data directory: machine-wide locks on what two daemons cannot share.

Why: the session lock (``RIG.lock``, decision record 17) lives in the state directory, which defaults
to ``DATA_DIR/.daq-daemon``, so a second daemon for the same rig with another ``--data-dir`` was not
refused: it started a bench of its own and died with a 17-line ``ZMQError: Address already in use``
traceback, and on real hardware both would have opened the same instruments (issue 29).

Each key is an ``flock`` on a file in one machine-wide directory (``DAQ_LOCK_DIR``, default
``/tmp/daq-locks``, mode 1777 so every user's daemons see each other): the kernel drops it however
its holder dies, so no pid is trusted. Keys: with real instruments the rig's id and every instrument
endpoint (a serial device by its real path, a CAN bus by interface and channel), so two configs naming
the same port are refused too; always the control socket and the sample bus when their port is fixed
(port 0 is never shared). A ``--sim`` daemon's instruments are its own bench's ptys, so two simulated
daemons on their own ports are two simulated rigs, and may run side by side (as the tests do).
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import re
from pathlib import Path

from daq.config import RigConfig
from daq.errors import DaqError

LOCK_DIR_ENV = "DAQ_LOCK_DIR"
DEFAULT_LOCK_DIR = Path("/tmp/daq-locks")


class RigBusy(DaqError, RuntimeError):
    """Another live daemon holds one of this daemon's rig, instruments or sockets; the message names which."""


def lock_dir() -> Path:
    return Path(os.environ.get(LOCK_DIR_ENV) or DEFAULT_LOCK_DIR)


def _fixed_port(endpoint: str) -> bool:
    """True for an endpoint only one process can bind (tcp with a port other than 0, ipc)."""
    if endpoint.startswith("ipc://"):
        return True
    m = re.match(r"tcp://.*:(\d+)$", endpoint)
    return bool(m) and int(m.group(1)) != 0


def instrument_keys(rig: RigConfig) -> list[str]:
    """What identifies each physical instrument of a rig: a serial device's real path, a CAN bus."""
    keys = []
    for inst in rig.instruments.values():
        if inst.transport == "can":
            keys.append(f"can {inst.interface} {inst.channel}")
        else:
            url = str(inst.url)
            keys.append(f"serial {os.path.realpath(url) if '://' not in url else url}")
    return keys


def lock_keys(rig: RigConfig, sim: bool, endpoints: list[str]) -> list[str]:
    """Every key one daemon for ``rig`` must hold alone (see the module's docstring)."""
    keys = [] if sim else [f"rig {rig.rig}", *instrument_keys(rig)]
    return keys + [f"socket {ep}" for ep in endpoints if _fixed_port(ep)]


class RigLocks:
    """Holds the machine-wide locks of one daemon until release() (or its death)."""

    def __init__(self, keys: list[str], holder: str) -> None:
        self.keys = sorted(set(keys))
        self.holder = holder  # written into each lock file: who to name to a refused second daemon
        self._fds: list[int] = []

    def acquire(self) -> RigLocks:
        """Take every key or none; RigBusy naming the first one held by another live daemon."""
        if not self.keys:
            return self
        d = lock_dir()
        try:
            d.mkdir(parents=True, exist_ok=True)
            if d == DEFAULT_LOCK_DIR:
                os.chmod(d, 0o1777)
        except OSError:
            pass  # made by another user: it is theirs to set; open() below says if it is unusable
        try:
            for key in self.keys:
                self._take(d, key)
        except BaseException:
            self.release()
            raise
        return self

    def _take(self, d: Path, key: str) -> None:
        path = d / (hashlib.sha1(key.encode()).hexdigest()[:16] + ".lock")
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise RigBusy(f"cannot use the lock directory {d} ({exc.strerror or exc}); set {LOCK_DIR_ENV}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            other = os.pread(fd, 4096, 0).decode(errors="replace").strip() or "another daemon"
            os.close(fd)
            raise RigBusy(f"{key} is in use by {other}: one daemon per rig; stop that one first") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{self.holder}\n".encode(), 0)
        self._fds.append(fd)

    def release(self) -> None:
        for fd in self._fds:
            try:
                fcntl.flock(fd, fcntl.LOCK_UN)
            finally:
                os.close(fd)
        self._fds = []
