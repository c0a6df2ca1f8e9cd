"""The control socket's operations: each takes the request's args and returns a result dict.

:class:`ControlHandlers` turns a request into calls on the daemon's parts; :meth:`ControlHandlers.table`
is what daq/daemon/control.py's server dispatches on (op name -> handler). An exception is the
operator's answer (the server says what went wrong; MotionRefused and InputError are refusals).

Decision record: docs/decisions/0038-daemon-as-a-coordinator.md.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from .children import RecorderProcess, let_the_bus_reach_the_recorder
from .motion import STANDSTILL
from .ramp_runner import RampRunner
from .recording import run_file_path
from .session_state import MotionRefused, describe_exit, recover_recording
from .status import daemon_status

if TYPE_CHECKING:
    from .service import Daemon


class ControlHandlers:
    """The operations of ``daq ctl`` on one daemon."""

    def __init__(self, daemon: Daemon) -> None:
        self.d = daemon

    def table(self) -> dict[str, Callable[[dict], dict]]:
        return {"status": self.handle_status, "ramp": self.handle_ramp, "stop": self.handle_stop,
                "estop": self.handle_estop, "record_start": self.handle_record_start,
                "record_stop": self.handle_record_stop, "record_rotate": self.handle_record_rotate,
                "note": self.handle_note, "reset": self.handle_reset}

    def handle_status(self, args: dict) -> dict[str, Any]:
        return daemon_status(self.d)

    def handle_ramp(self, args: dict) -> dict:
        path = str(args["file"])
        runner = self.d.start_ramp(lambda m, v, a, **kw: RampRunner.from_file(m, path, v, a, **kw), path,
                                   float(args.get("time_scale", 1.0)))
        return {"started": path, "duration_s": runner.duration}

    def handle_stop(self, args: dict) -> dict:
        self.d.halt("stop", "controlled stop")
        return {"stopping": True}

    def handle_estop(self, args: dict) -> dict:
        self.d.halt("estop", "emergency stop")
        self.d.motion.read_regulator()
        return {"estop": True}

    def handle_reset(self, args: dict) -> dict:
        """Acknowledge an unclean end and clear the regulator's latch (ESTOP/WATCHDOG): only at standstill.

        Why explicit: after a crash someone should look at the rig before it moves again; the
        reset is the operator saying so, and it is logged as an event.
        """
        d, motion = self.d, self.d.motion
        with d.lock:
            if d.runner is not None and d.runner.running:
                raise MotionRefused("a ramp is running: stop it first (reset is for a belt at rest)")
            measured, _ = d.drivers.motor.read_speed()
            if abs(measured) >= 5 * STANDSTILL:
                raise MotionRefused(f"the belt is moving ({measured:.4f} m/s): reset only at standstill")
            before = motion.read_regulator()
            if before.latched:
                d.drivers.motor.reset()  # the regulator refuses (MotorError) unless at standstill
            after = motion.read_regulator()
            cleared, motion.unclean = motion.unclean, None
            if d.session is not None:
                d.session.update(durable=True, unclean_end=None)
        detail = (f"regulator {before.state} -> {after.state}"
                  + (f"; acknowledged: {cleared.summary()}" if cleared is not None else ""))
        d.acq.publish_event("reset", "operator", detail)
        print(f"daq daemon: reset: {detail}", file=sys.stderr, flush=True)
        return {"reset": True, "regulator_before": before.state, "regulator": after.state,
                "acknowledged": cleared.summary() if cleared is not None else None}

    def _endpoints(self) -> list[str]:
        """What a recorder subscribes to: the bus, and the estimator's results when it runs."""
        d = self.d
        return [d.acq.endpoint] + ([d.estimator.endpoint] if d.estimator is not None else [])

    def handle_record_start(self, args: dict) -> dict:
        d = self.d
        with d.lock:  # one path check and one start at a time
            d.recording.refuse_if_busy()
            path = run_file_path(args.get("path"), d.cfg.data_dir, d.rig.rig)
            rec, lost = d.recording.start(path, self._endpoints(), d.rig_arg, d.cfg.flush_s, d.cfg.start_timeout_s)
        d.acq.publish_event("record_start", "operator", str(path))
        if lost is not None:  # the new file keeps the record of the one before it
            d.acq.publish_event("previous_recording_lost", "daemon", lost.summary())
        if d.session is not None:
            d.session.update(recording=d.recording.ref())
        return {"recording": str(path), "pid": rec.pid}

    def handle_record_stop(self, args: dict) -> dict:
        d = self.d
        rec = d.recording.take()
        d.acq.publish_event("record_stop", "operator", str(rec.path))
        try:
            return self._close(rec)
        finally:
            if d.session is not None:
                d.session.update(recording=None)

    def handle_record_rotate(self, args: dict) -> dict:
        """The next file of a long recording, started before the current one closes (make before break): the two
        files overlap by the old recorder's last flush, and no sample falls between them. Stopping first left a
        hole as long as the new recorder's start, 10.7 s once on a loaded machine (an hourly soak's rotation)."""
        d = self.d
        with d.lock:
            path = run_file_path(args.get("path"), d.cfg.data_dir, d.rig.rig)
            rec, old = d.recording.rotate(path, self._endpoints(), d.rig_arg, d.cfg.flush_s, d.cfg.start_timeout_s)
        d.acq.publish_event("record_rotate", "operator", f"{old.path} -> {path}")  # in both files
        if d.session is not None:
            d.session.update(recording=d.recording.ref())
        return {"recording": str(path), "pid": rec.pid, **self._close(old)}

    def _close(self, rec: RecorderProcess) -> dict:
        """Stop a recorder taken out of the slot once the bus has reached it; RuntimeError if it ended badly."""
        let_the_bus_reach_the_recorder(self.d.cfg.flush_s)  # the last event and the last blocks
        rc = rec.stop()
        if rc != 0:
            _, what, _ = recover_recording(rec.path)
            raise RuntimeError(f"recorder {describe_exit(rc)}: {rec.closed_line or rec.progress}; {rec.path}: {what}")
        return {"closed": str(rec.path), "recorder": rec.closed_line}

    def handle_note(self, args: dict) -> dict:
        text = str(args["text"])
        self.d.acq.publish_event("note", "operator", text)
        return {"noted": text}
