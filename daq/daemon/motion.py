"""Whether the belt may move: the regulator as last read, a latch the moment it happens, an unclean end not reset.

:class:`MotionGuard` holds the daemon's safety state (``unclean``, ``regulator``, ``halted``) and answers
:meth:`MotionGuard.refusal` before any ramp starts. Its :meth:`MotionGuard.watch` runs on the daemon's
regulator thread.

Decision records: docs/decisions/0017-crash-truth.md, docs/decisions/0038-daemon-as-a-coordinator.md.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable

from drivers.motor import MotorDrive

from .children import BenchHandle
from .session_state import LATCHED, RegulatorReading, UncleanEnd, utcnow

STANDSTILL = 1e-3  # [m/s]: the belt is at rest below 5 times this
REGULATOR_POLL_S = 0.2  # STAT? while running: a watchdog trip reaches status, stderr and the events within 1 s

Publish = Callable[[str, str, str], None]  # (kind, source, detail): an event on the bus


class MotionGuard:
    """The regulator's state as last read, the last session's unclean end until ``daq ctl reset``, and whether
    a stop or e-stop was sent since the last ramp started (then nothing is commanded)."""

    def __init__(self) -> None:
        self.unclean: UncleanEnd | None = None
        self.regulator: RegulatorReading | None = None
        self.halted = False
        self._motor: MotorDrive | None = None
        self._bench: BenchHandle | None = None
        self._publish: Publish | None = None
        # one read of the regulator at a time, kept whole: without it the watch thread can read RUNNING, an
        # e-stop's handler then read and keep ESTOP, and the watch keep its older RUNNING over it until its next
        # poll (status unlatched with the regulator latched). Reentrant: a poll that sees a latch reads again.
        self._reading = threading.RLock()

    def attach(self, motor: MotorDrive, bench: BenchHandle | None, publish: Publish) -> None:
        """The regulator to read (and the bench that counts its watchdog trips); where latch events go."""
        self._motor, self._bench, self._publish = motor, bench, publish

    def read_regulator(self) -> RegulatorReading:
        """STAT? from the regulator (and the bench's watchdog trip counter); kept for status."""
        with self._reading:
            return self._read_regulator()

    def _read_regulator(self) -> RegulatorReading:
        now = utcnow()
        try:
            st = self._motor.status()
        except Exception as exc:  # noqa: BLE001 - unreadable is itself the answer
            reading = RegulatorReading(error=f"{type(exc).__name__}: {exc}", read_at=now)
        else:
            trips = self._bench.watchdog_trips() if self._bench is not None else None
            reading = RegulatorReading(state=st.state, latched=st.state in LATCHED, measured=st.measured,
                                       watchdog_trips=trips, read_at=now)
        self.regulator = reading
        return reading

    def refusal(self, read: bool = False) -> str | None:
        """Why no ramp may start now (None: it may): an unclean end not yet reset, or a latched regulator
        (as last read, or ``read`` now)."""
        if self.unclean is not None:
            return f"motion refused until `daq ctl reset`: {self.unclean.summary()}"
        reg = self.read_regulator() if read else self.regulator
        if reg is not None and reg.latched:
            return f"motion refused: the regulator is latched in {reg.state}; with the belt at rest, `daq ctl reset`"
        return None

    def watch(self, stop: threading.Event) -> None:
        """Poll the regulator until ``stop``, and report the moment it latches.

        Why: the state was read only at start and on explicit commands, so after a watchdog trip
        with the daemon alive (a 0.46 s stall from a 300 MB web request, issue 29) status said
        DISABLED, 0 trips, motion allowed, nothing reached stderr, and the ``watchdog`` event was
        written 19 s later at ``reset``. Every REGULATOR_POLL_S the state is read; a change into a
        latched state (WATCHDOG, ESTOP) updates status (motion refused), prints one stderr line and
        publishes an event.
        """
        while not stop.wait(REGULATOR_POLL_S):
            self.poll()

    def poll(self) -> None:
        """One look at the regulator (see :meth:`watch`)."""
        with self._reading:
            self._poll()

    def _poll(self) -> None:
        try:
            st = self._motor.status()
        except Exception:  # noqa: BLE001 - unreachable regulator: the motor stream's counters say so
            return
        before = self.regulator
        if before is not None and before.state == st.state:
            return
        if st.state not in LATCHED:
            self.regulator = RegulatorReading(state=st.state, latched=False, measured=st.measured,
                                              watchdog_trips=before.watchdog_trips if before else None,
                                              read_at=utcnow())
            return
        reading = self.read_regulator()  # with the bench's trip counter
        if reading.latched and not (before is not None and before.latched):
            self._report_latch(reading)

    def _report_latch(self, reading: RegulatorReading) -> None:
        """One stderr line and one event for a regulator that latched while the daemon ran (not our own e-stop)."""
        if reading.state == "ESTOP" and self.halted:
            return
        trips = f", {reading.watchdog_trips} watchdog trip(s)" if reading.watchdog_trips is not None else ""
        why = ("its watchdog stopped the belt (no command within its timeout)" if reading.state == "WATCHDOG"
               else f"it latched in {reading.state}")
        detail = f"regulator {reading.state} (latched){trips}: {why}; motion refused until `daq ctl reset`"
        self._publish("watchdog" if reading.state == "WATCHDOG" else "regulator_latched", "daemon", detail)
        print(f"daq daemon: {detail}", file=sys.stderr, flush=True)
