"""One background loop: a named daemon thread that calls a step until its stop Event is set.

Why one class: drivers, simulated instruments, the online estimator and the web process each wrote out
the same start / stop / join / loop (docs/decisions/0039-one-background-loop.md). Two kinds of loop exist:

* ``interval=None``: ``step()`` again and again; the step itself waits (a socket or queue timeout, a pty
  read, pacing to the wall clock), so stop() takes effect within one step.
* ``interval=s``: wait ``s`` seconds, then ``step()``, until stopped (``while not stop.wait(s)``):
  a heartbeat, a status poll, a parent watch. stop() takes effect at once, even mid-wait.

The stop Event is the loop's own, cleared by start() so the loop can run again; or one the caller passes,
shared with other loops or a whole process: start() then leaves it as it is, and stop() sets it for all.

A step that raises ends the loop, as an uncaught exception ended the thread before; it is not swallowed:
``on_error(exc)`` is called with it, or, without a callback, it is logged with its traceback.

This module sits in the bottom layer (tests/test_layering.py) and imports nothing of ours.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

log = logging.getLogger(__name__)


class BackgroundLoop:
    """``step()`` in the daemon thread ``name`` until stop(); start() and stop() may be called in any order."""

    def __init__(self, step: Callable[[], object], name: str, *, interval: float | None = None,
                 stop: threading.Event | None = None,
                 on_error: Callable[[Exception], None] | None = None) -> None:
        self.step = step
        self.name = name
        self.interval = interval
        self.on_error = on_error
        self._own_event = stop is None
        self._stop = threading.Event() if stop is None else stop
        self._thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        """True from start() to stop() (also after a step raised and ended the thread)."""
        return self._thread is not None

    def start(self) -> BackgroundLoop:
        """Start the thread; a no-op while it is running."""
        if self._thread is None:
            if self._own_event:
                self._stop.clear()
            self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
            self._thread.start()
        return self

    def stop(self, timeout: float | None = None) -> None:
        """Set the stop Event and wait up to ``timeout`` s for the thread to end (safe before start(), twice)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def _run(self) -> None:
        try:
            if self.interval is None:
                while not self._stop.is_set():
                    self.step()
            else:
                while not self._stop.wait(self.interval):
                    self.step()
        except Exception as exc:  # reported, and the loop ends as the bare thread did
            if self.on_error is not None:
                self.on_error(exc)
            else:
                log.exception("%s: the loop ended on an error", self.name)
