"""A serial device as a host sees it: a real pseudo-terminal behind a stable path.

Real USB-serial adapters appear under a stable name (/dev/serial/by-id/...) that
vanishes on unplug and comes back on replug. We do the same with a symlink to
the pty's slave: ``unplug()`` closes the pty (the host's open port reads EIO, as
with a pulled cable) and removes the link; ``replug()`` makes a fresh pty behind
the same link. The simulated instrument talks through the master side.
"""

from __future__ import annotations

import errno
import os
import select
import threading
import tty
from pathlib import Path


class PtyPort:
    def __init__(self, link: str | Path) -> None:
        self.link = Path(link)
        self._master: int | None = None
        self._slave: int | None = None
        self._lock = threading.Lock()
        self.dropped_bytes = 0  # written while nobody could take them (buffer full / unplugged)
        self.plug()

    @property
    def plugged(self) -> bool:
        return self._master is not None

    def plug(self) -> None:
        with self._lock:
            if self._master is not None:
                return
            master, slave = os.openpty()
            tty.setraw(slave)  # binary-clean: no echo, no CR/LF translation
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            self.link.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.link.with_name(self.link.name + ".new")
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(os.ttyname(slave))
            os.replace(tmp, self.link)

    def unplug(self) -> None:
        with self._lock:
            if self._master is None:
                return
            self.link.unlink(missing_ok=True)
            for fd in (self._master, self._slave):
                try:
                    os.close(fd)
                except OSError:
                    pass
            self._master = self._slave = None

    replug = plug

    def close(self) -> None:
        self.unplug()

    def write(self, data: bytes) -> int:
        """Send bytes to the host; what the pty cannot take is dropped (a UART does not wait)."""
        with self._lock:
            if self._master is None:
                self.dropped_bytes += len(data)
                return 0
            try:
                n = os.write(self._master, data)
            except BlockingIOError:
                n = 0
            except OSError as exc:
                if exc.errno != errno.EIO:
                    raise
                n = 0
            self.dropped_bytes += len(data) - n
            return n

    def write_all(self, data: bytes, timeout: float = 1.0) -> int:
        """Send bytes, waiting (up to timeout) for the host to drain the pty; returns bytes sent."""
        sent = 0
        view = memoryview(data)
        while sent < len(data):
            with self._lock:
                fd = self._master
            if fd is None:
                break
            try:
                _, w, _ = select.select([], [fd], [], timeout)
            except (OSError, ValueError):
                break
            if not w:
                break
            with self._lock:
                if self._master is None:
                    break
                try:
                    sent += os.write(self._master, view[sent:])
                except BlockingIOError:
                    continue
                except OSError:
                    break
        self.dropped_bytes += len(data) - sent
        return sent

    def read(self, timeout: float = 0.05, n: int = 4096) -> bytes:
        """Bytes the host wrote (commands), or b'' after timeout."""
        with self._lock:
            fd = self._master
        if fd is None:
            return b""
        try:
            r, _, _ = select.select([fd], [], [], timeout)
        except (OSError, ValueError):
            return b""
        if not r:
            return b""
        with self._lock:
            if self._master is None:
                return b""
            try:
                return os.read(self._master, n)
            except (BlockingIOError, OSError):
                return b""
