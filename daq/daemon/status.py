"""What ``daq ctl status`` answers: one JSON-able dict built from the daemon's parts.

:func:`daemon_status` is the whole answer (its keys are what docs/daemon.md documents and the CLI's
``format_status`` prints); :class:`StreamRates` turns the acquisition's sample counters into rates.

Decision record: docs/decisions/0038-daemon-as-a-coordinator.md.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .service import Daemon


class StreamRates:
    """Samples per second of every stream, over the last call's interval; ``counters()`` gives samples so far."""

    def __init__(self, counters: Callable[[], dict[str, Any]]) -> None:
        self._counters = counters
        self.rates: dict[str, float] = {}
        self._prev, self._t_prev = self._samples(), time.monotonic()

    def _samples(self) -> dict[str, int]:
        return {k: v.samples for k, v in self._counters().items()}

    def update(self) -> dict[str, float]:
        now, cur = time.monotonic(), self._samples()
        self.rates = {k: (n - self._prev.get(k, 0)) / (now - self._t_prev) for k, n in cur.items()}
        self._prev, self._t_prev = cur, now
        return self.rates


def daemon_status(d: Daemon) -> dict[str, Any]:
    """The status answer: streams and rates, drops, belt, motion, regulator, session, and each child's part."""
    st = d.acq.status()
    counters = st.pop("streams")
    rates = d.rates.rates if d.rates is not None else {}
    motor = st.get("motor") or {}
    refusal = d.motion.refusal()
    out: dict[str, Any] = {"rig": d.rig.rig, "sim": d.simulated, "pid": os.getpid(),
                           "uptime_s": time.monotonic() - d.t_start, "bus": d.acq.endpoint,
                           "belt": belt(d, motor),
                           "streams": {k: {**v, "rate_hz": rates.get(k, 0.0)} for k, v in counters.items()},
                           "sources": st["sources"], "drops": _drops(st, motor),
                           "recording": None, "ramp": None, "estimator": None,
                           "motion": {"allowed": refusal is None, "refused_because": refusal},
                           **_safety(d)}
    _add_children(d, out)
    if d.runner is not None:
        p = d.runner.progress()
        out["ramp"] = {"state": str(p.state), "t": p.t, "duration": d.runner.duration, "fraction": p.fraction,
                       "segment": p.segment, "commanded": out["belt"]["commanded"],
                       "measured": out["belt"]["measured"], "reason": d.runner.reason, "source": d.runner.source}
    return out


def _drops(st: dict[str, Any], motor: dict[str, Any]) -> dict[str, Any]:
    return {"bus_queue": st["dropped"], "misaligned_reads": st["misaligned_reads"],
            "lost_frames": sum(s["lost_frames"] for s in st["sources"].values()),
            "checksum_errors": sum(s["checksum_errors"] for s in st["sources"].values()),
            "motor_failed_polls": motor.get("failed_polls", 0)}


def _safety(d: Daemon) -> dict[str, Any]:
    """The regulator as last read, the last session's unclean end, a recorder that died, the session file."""
    m, failure = d.motion, d.recording.failure
    return {"regulator": m.regulator.model_dump(mode="json") if m.regulator else None,
            "last_session": m.unclean.model_dump(mode="json") if m.unclean else None,
            "recording_failure": failure.model_dump(mode="json") if failure else None,
            "session": ({"state_file": str(d.session.path), "started_at": d.started_at.isoformat()}
                        if d.session is not None else None)}


def _add_children(d: Daemon, out: dict[str, Any]) -> None:
    """The estimator, the recorder, the web page and the bench, each if there is one (their drops too)."""
    drops = out["drops"]
    if d.estimator is not None:
        est = dict(d.estimator.stats)
        out["estimator"] = {"pid": d.estimator.pid, "alive": d.estimator.alive, "endpoint": d.estimator.endpoint,
                            **est, "last": d.monitor.last if d.monitor else {},
                            "fit": d.monitor.fit if d.monitor else {}}
        drops["estimator_lost_blocks"] = est.get("lost_blocks", 0)
    rec = d.recording.recorder
    if rec is not None:
        out["recording"] = {"path": str(rec.path), "pid": rec.pid, "alive": rec.alive, "progress": rec.progress}
        drops["recorder_lost_blocks"] = rec.lost_blocks() or 0
    if d.web is not None:
        out["web"] = {"url": d.web.url, "pid": d.web.pid, "alive": d.web.alive, "exit": d.web.proc.returncode}
    if d.bench is not None:
        out["sim_bench"] = {"pid": d.bench.pid, "control": d.bench.control, "alive": d.bench.alive(),
                            "attached": d.bench.attached}


def belt(d: Daemon, motor: dict[str, Any]) -> dict[str, Any]:
    """Measured (the latest motor sample, and its age), the regulator's set point, and what we command.

    ``commanded`` is 0 once a stop or e-stop was sent (or a ramp ended in a stop), whatever
    the programme's last value was; None before anything was commanded.
    """
    t = motor.get("host_time")
    if d.motion.halted:
        commanded: float | None = 0.0
    elif d.runner is not None:
        commanded = d.runner.progress().commanded
    else:
        commanded = None
    return {"measured": motor.get("measured"), "age_s": None if t is None else time.monotonic() - t,
            "setpoint": motor.get("setpoint"), "commanded": commanded, "regulator": motor.get("state")}
