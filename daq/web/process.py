"""The daemon's side of ``--web``: start ``python -m daq.web.server`` and answer its control requests.

Why a pipe and not the control socket: the web process must command with the role it
established (operator token or not), and the daemon's own ``ControlServer.handle`` applies
the same rules as for ``daq ctl`` (observers may only read status). Over the child's stdin
and stdout only the daemon can answer, so no key or extra socket is needed, and the
web process never holds anything that could command the rig by itself.

Each request runs on a small thread pool: an e-stop must not wait behind a
``record_stop`` that is closing a file, nor behind the status poll.

Decision record: docs/decisions/0020-live-web-page.md.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

from pydantic import ValidationError

from daq.daemon.children import ROOT, first_line
from daq.daemon.control import Reply
from daq.streaming.child_process import terminate

from .messages import PipeCommand, PipeReply, Role, WebCfg

Command = Callable[[bytes, Role], Reply]  # ControlServer.handle


class WebProcess:
    """``python -m daq.web.server`` with ``cfg``; its control requests go to ``command``."""

    def __init__(self, cfg: WebCfg, command: Command, timeout: float,
                 on_exit: Callable[[int], None] | None = None) -> None:
        self.command = command
        self.on_exit = on_exit  # called with the exit code when the process ends without stop()
        self._stopping = False
        self.proc = subprocess.Popen([sys.executable, "-m", "daq.web.server"], cwd=str(ROOT), text=True,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self.pid = self.proc.pid
        self._lock = threading.Lock()
        self._pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="web-command")
        self.proc.stdin.write(cfg.model_dump_json() + "\n")
        self.proc.stdin.flush()
        info = json.loads(first_line(self.proc, timeout, "the web process"))
        self.url: str = info["url"]
        self._reader = threading.Thread(target=self._read, name="web-commands", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            try:
                cmd = PipeCommand.model_validate_json(line)
            except ValidationError:
                continue
            self._pool.submit(self._run, cmd)
        # its stdout closed: the process ended; if nobody asked it to, the daemon must say so (the page is gone)
        code = self.proc.wait()
        if not self._stopping and self.on_exit is not None:
            self.on_exit(code)

    def _run(self, cmd: PipeCommand) -> None:
        reply = self.command(cmd.request.encode(), cmd.role)
        line = PipeReply(id=cmd.id, reply=reply).model_dump_json() + "\n"
        with self._lock:
            try:
                self.proc.stdin.write(line)
                self.proc.stdin.flush()
            except (BrokenPipeError, ValueError, OSError):
                pass  # the web process is gone

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self) -> None:
        self._stopping = True
        terminate(self.proc, 10)
        with self._lock:
            try:
                self.proc.stdin.close()
            except OSError:
                pass
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._reader.join(2)

