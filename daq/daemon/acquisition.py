"""Acquisition: pumps a rig's drivers onto the sample bus (what the operator daemon runs).

Threads:

- one **pump** per streaming source: ``read(timeout)`` in a loop, samples grouped into
  blocks, the driver's events turned into bus events;
- one **motor poller**: ``read_speed()`` at ``motor_hz`` (>= 50 Hz), stream ``motor`` with
  ``vb`` (measured) and ``vb_set`` (set point) in m/s, plus the regulator's events;
- one **sender** that owns the ZeroMQ PUB socket. ZeroMQ sockets are not thread-safe, so the
  pumps never touch it: they put ready blocks and events on a queue, and the sender creates,
  binds, uses and closes the Publisher in its own thread.

Stream layout (one rule, keeps host ``t`` and ``device_t`` of every sample exact):

- a driver whose channels all arrive in one frame (the binary serial stream: every frame
  carries every channel with one device time and one host time), or that has a single
  channel (the thermocouple), publishes **one stream named after the driver** with all its
  channels; each read's samples form rows of one frame each;
- a driver whose channels arrive in separate messages (CAN: one message per channel, from
  different nodes with different clocks, each dropped independently) publishes **one stream
  per channel**, ``<driver>.<channel>`` (e.g. ``can.x1``, ``can.phi``). Pairing such samples
  into rows would need resampling or NaN padding and would give up one of the two times;
  consumers that want them together (the online estimator) already hold slower streams
  by time.

Decision record: docs/decisions/0005-daemon-process-layout.md.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import defaultdict
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import ConfigDict, Field

from daq.config import RigConfig
from daq.io.stream_format import BusEvent, StreamMeta
from daq.streaming.bus import BusCfg, Publisher
from daq.strict import Closed
from drivers.base import ClockSync, DriverEvent, Sample, SampleSource
from drivers.factory import RigDrivers
from drivers.motor import MotorError, MotorUnavailable, SerialMotorRegulator

log = logging.getLogger(__name__)

MOTOR_STREAM = "motor"
MOTOR_CHANNELS = ("vb", "vb_set")


class AcquisitionCfg(Closed):
    """How fast to poll, where to publish; the defaults suit the lab's rigs."""

    model_config = ConfigDict(frozen=True)
    endpoint: str = Field(BusCfg().endpoint, description="where the publisher binds (tcp://host:0 = any port)")
    sndhwm: int = Field(BusCfg().sndhwm, ge=1)
    read_timeout_s: float = Field(0.05, gt=0, le=1.0, description="per read(); bounds block latency and stop time")
    motor_hz: float = Field(100.0, ge=50.0, le=1000.0, description="motor speed polling rate")
    queue_size: int = Field(20_000, ge=10, description="blocks and events waiting for the sender before drops")
    join_timeout_s: float = Field(5.0, gt=0)


@dataclass
class StreamCounters:
    blocks: int = 0
    samples: int = 0


@dataclass
class _Route:
    """Where one driver's samples go: a framed stream, or one stream per channel."""

    framed: StreamMeta | None  # all channels in one stream (rows = frames)
    per_channel: dict[str, StreamMeta]  # channel -> its own stream (filled lazily for unknown channels)


_STOP = object()


class Acquisition:
    """Reads every source and the motor of one rig and publishes blocks and events on the bus."""

    def __init__(self, rig: RigConfig, drivers: RigDrivers, cfg: AcquisitionCfg | None = None) -> None:
        self.rig = rig
        self.drivers = drivers
        self.cfg = cfg or AcquisitionCfg()
        self.endpoint: str | None = None  # the bound endpoint (port resolved), known after start()
        self._q: queue.Queue[Any] = queue.Queue(maxsize=self.cfg.queue_size)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._sender: threading.Thread | None = None
        self._started: list[threading.Thread] = []  # every thread this acquisition ran, for threads_alive()
        self._bound = threading.Event()
        self._bind_error: BaseException | None = None
        self._lock = threading.Lock()
        self._counters: dict[str, StreamCounters] = defaultdict(StreamCounters)
        self.events_sent = 0
        self.dropped = 0  # blocks/events lost because the sender's queue was full
        self.misaligned_reads = 0  # framed reads whose samples did not form whole frames (dropped)
        self.errors: dict[str, str] = {}  # last unexpected error per thread
        self._last_t: dict[str, float] = {}  # last published t per framed stream (kept non-decreasing)
        self._motor_last: tuple[float, float, float] | None = None  # (host t, measured, setpoint)
        self._motor_fail = 0
        self._routes = {name: self._route(name, src) for name, src in drivers.sources.items()}
        self.motor_meta = StreamMeta(stream=MOTOR_STREAM, channels=MOTOR_CHANNELS, units=("m/s", "m/s"),
                                     rig=rig.rig, source=drivers.motor.name if drivers.motor else "motor",
                                     rate_hz=self.cfg.motor_hz)

    # --- stream metadata
    def _unit(self, channel: str) -> str:
        ch = self.rig.channels.get(channel)
        return ch.unit if ch is not None else ""

    def _rate(self, name: str) -> float | None:
        inst = self.rig.instruments.get(name)
        return inst.rate_hz(self.rig.sensors.rate_Hz) if inst is not None else None

    def _meta(self, stream: str, source: str, channels: tuple[str, ...]) -> StreamMeta:
        return StreamMeta(stream=stream, channels=channels, units=tuple(self._unit(c) for c in channels),
                          rig=self.rig.rig, source=source, rate_hz=self._rate(source))

    def _channels(self, name: str, src: SampleSource) -> tuple[str, ...]:
        if src.framed:
            return tuple(src.names)
        inst = self.rig.instruments.get(name)
        chans = getattr(inst, "channels", None)
        if chans:
            return tuple(chans)
        one = getattr(getattr(src, "cfg", None), "channel", None)  # thermocouple-like: one channel
        return (one,) if one else ()

    def _route(self, name: str, src: SampleSource) -> _Route:
        chans = self._channels(name, src)
        if chans and (len(chans) == 1 or src.framed):
            return _Route(self._meta(name, name, chans), {})
        return _Route(None, {c: self._meta(f"{name}.{c}", name, (c,)) for c in chans})

    def streams(self) -> dict[str, StreamMeta]:
        """Every stream this acquisition publishes (per-channel streams of unknown channels appear later)."""
        out = {MOTOR_STREAM: self.motor_meta} if self.drivers.motor is not None else {}
        for r in self._routes.values():
            if r.framed is not None:
                out[r.framed.stream] = r.framed
            out.update({m.stream: m for m in r.per_channel.values()})
        return out

    # --- lifecycle
    def start(self) -> None:
        """Bind the publisher (in the sender thread), then start the pumps and the motor poller."""
        if self._sender is not None:
            raise RuntimeError("acquisition already started")
        self._stop.clear()
        self._sender = threading.Thread(target=self._send_loop, name="acq-sender", daemon=True)
        self._sender.start()
        if not self._bound.wait(10.0) or self._bind_error is not None:
            self._sender.join(1.0)
            self._sender = None
            raise RuntimeError(f"cannot bind {self.cfg.endpoint}: {self._bind_error}")
        for name, src in self.drivers.sources.items():
            th = threading.Thread(target=self._pump, args=(name, src), name=f"acq-{name}", daemon=True)
            self._threads.append(th)
        if self.drivers.motor is not None:
            self._threads.append(threading.Thread(target=self._poll_motor, args=(self.drivers.motor,),
                                                  name="acq-motor", daemon=True))
        self._started = [self._sender, *self._threads]
        for th in self._threads:
            th.start()

    def stop(self) -> None:
        """Stop the pumps, let the sender flush what is queued, close the socket; drivers stay open."""
        self._stop.set()
        for th in self._threads:
            th.join(self.cfg.join_timeout_s)
            if th.is_alive():
                log.warning("%s did not stop within %.1f s", th.name, self.cfg.join_timeout_s)
        self._threads.clear()
        if self._sender is not None:
            self._q.put(_STOP)  # blocks only while the sender drains a full queue
            self._sender.join(self.cfg.join_timeout_s)
            self._sender = None
        self._bound.clear()

    @property
    def running(self) -> bool:
        return self._sender is not None

    def threads_alive(self) -> list[str]:
        """Names of acquisition threads still running (empty after a clean stop)."""
        return [th.name for th in self._started if th.is_alive()]

    def __enter__(self) -> "Acquisition":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def publish_event(self, kind: str, source: str, detail: str = "", **kw: Any) -> None:
        """Put a daemon-level event (ramp segment, operator note, recording) on the bus, via the sender."""
        self._enqueue(("event", BusEvent(kind=kind, source=source, host_time=time.monotonic(), detail=detail,
                                         **kw)))

    # --- the sender: the only thread that touches the socket
    def _enqueue(self, item: tuple) -> None:
        try:
            self._q.put_nowait(item)
        except queue.Full:
            with self._lock:
                self.dropped += 1

    def _send_loop(self) -> None:
        try:
            pub = Publisher(self.cfg.endpoint, sndhwm=self.cfg.sndhwm)
        except Exception as exc:  # noqa: BLE001 - reported by start()
            self._bind_error = exc
            self._bound.set()
            return
        self.endpoint = pub.endpoint
        self._bound.set()
        try:
            while True:
                item = self._q.get()
                if item is _STOP:
                    break
                try:
                    if item[0] == "block":
                        _, meta, t, data, dev = item
                        pub.publish(meta, t, data, dev)
                        with self._lock:
                            c = self._counters[meta.stream]
                            c.blocks += 1
                            c.samples += t.size
                    else:
                        _, ev = item
                        pub.event(ev.kind, ev.source, ev.detail, gap_s=ev.gap_s, count=ev.count)
                        with self._lock:
                            self.events_sent += 1
                except Exception as exc:  # noqa: BLE001 - one bad block must not end publishing
                    log.exception("sender: %s", exc)
                    self.errors["sender"] = f"{type(exc).__name__}: {exc}"
        finally:
            pub.close()

    # --- the pumps
    def _forward_events(self, events: list[DriverEvent]) -> None:
        for ev in events:
            self._enqueue(("event", ev))

    def _pump(self, name: str, src: SampleSource) -> None:
        route = self._routes[name]
        timeout = self.cfg.read_timeout_s
        while not self._stop.is_set():
            try:
                samples = src.read(timeout)
            except Exception as exc:  # noqa: BLE001 - a closed driver or a bug: report, keep the thread
                self.errors[name] = f"{type(exc).__name__}: {exc}"
                self._stop.wait(timeout)
                samples = []
            self._forward_events(src.events())
            if samples:
                self._publish_samples(name, route, samples)
        self._forward_events(src.events())

    def _publish_samples(self, name: str, route: _Route, samples: list[Sample]) -> None:
        if route.framed is not None:
            self._publish_framed(route.framed, samples, getattr(self.drivers.sources[name], "clock", None))
            return
        by_ch: dict[str, list[Sample]] = defaultdict(list)
        for s in samples:
            by_ch[s.channel].append(s)
        for ch, ss in by_ch.items():
            meta = route.per_channel.get(ch)
            if meta is None:  # a channel the config did not list: still published, on its own stream
                meta = route.per_channel[ch] = self._meta(f"{name}.{ch}", name, (ch,))
            t = np.fromiter((s.host_time for s in ss), np.float64, len(ss))
            dev = np.fromiter((s.device_time for s in ss), np.float64, len(ss))
            data = np.fromiter((s.value for s in ss), np.float64, len(ss))
            self._enqueue(("block", meta, t, data, dev))

    def _publish_framed(self, meta: StreamMeta, samples: list[Sample], clock: ClockSync | None = None) -> None:
        """Rows of whole frames: the samples come as frame after frame, channels in stream order.

        ``t``: a serial read returns many frames stamped with one host reception time, which
        would give the stream runs of equal times (the estimator's differentiator sees every
        block as a time gap). So, once the driver's clock fit exists, ``t`` is each frame's
        device time mapped to the host clock (the line under the quickest receptions: when it
        was sampled, plus the link's minimum latency), kept non-decreasing; ``device_t`` stays
        the raw device clock.
        """
        nch = len(meta.channels)
        n = len(samples) // nch
        ok = n * nch == len(samples)
        if ok:
            names = [s.channel for s in samples]
            ok = all(names[i::nch] == [c] * n for i, c in enumerate(meta.channels))
        if ok and nch > 1:
            ok = all(s.host_time == samples[k - k % nch].host_time and
                     s.device_time == samples[k - k % nch].device_time for k, s in enumerate(samples))
        if not ok:
            with self._lock:
                self.misaligned_reads += 1
            self._enqueue(("event", DriverEvent(kind="note", source=meta.source, host_time=time.monotonic(),
                                                detail=f"{meta.stream}: read of {len(samples)} samples is not "
                                                       f"whole frames of {meta.channels}; dropped",
                                                count=len(samples))))
            return
        first = samples[::nch]
        t = np.fromiter((s.host_time for s in first), np.float64, n)
        dev = np.fromiter((s.device_time for s in first), np.float64, n)
        est = clock.estimate() if clock is not None and n > 1 else None
        if est is not None:
            offset, drift = est
            mapped = offset + dev / (1.0 + drift)
            if np.all(np.isfinite(mapped)) and abs(mapped[-1] - t[-1]) < 1.0:  # a sane fit only
                t = np.maximum.accumulate(np.maximum(mapped, self._last_t.get(meta.stream, -np.inf)))
        self._last_t[meta.stream] = float(t[-1])
        data = np.fromiter((s.value for s in samples), np.float64, n * nch).reshape(n, nch)
        self._enqueue(("block", meta, t, data, dev))

    # --- the motor poller
    def _poll_motor(self, motor: SerialMotorRegulator) -> None:
        period = 1.0 / self.cfg.motor_hz
        nxt = time.monotonic()
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                measured, setpoint = motor.read_speed()
            except (MotorUnavailable, MotorError, RuntimeError) as exc:  # reconnecting, or closed
                with self._lock:
                    self._motor_fail += 1
                self.errors[MOTOR_STREAM] = f"{type(exc).__name__}: {exc}"
            else:
                t = 0.5 * (t0 + time.monotonic())  # the regulator sampled somewhere within the exchange
                with self._lock:
                    self._motor_last = (t, measured, setpoint)
                self._enqueue(("block", self.motor_meta, np.array([t]), np.array([[measured, setpoint]]), None))
            self._forward_events(motor.log.events())
            nxt += period
            now = time.monotonic()
            if nxt < now - period:  # fell behind (loaded machine, reconnecting): do not burst to catch up
                nxt = now
            self._stop.wait(max(0.0, nxt - now))
        self._forward_events(motor.log.events())

    # --- reporting
    def counters(self) -> dict[str, StreamCounters]:
        """Blocks and samples (rows) published so far, per stream."""
        with self._lock:
            return {k: StreamCounters(v.blocks, v.samples) for k, v in self._counters.items()}

    def status(self) -> dict[str, Any]:
        """Per source: connection state and driver counters; motor: last reading; bus: what was sent."""
        out: dict[str, Any] = {"sources": {}, "running": self.running, "endpoint": self.endpoint}
        for name, src in self.drivers.sources.items():
            c = src.counters
            out["sources"][name] = {"state": src.state.value, "samples": c.samples, "lost_frames": c.lost_frames,
                                    "checksum_errors": c.checksum_errors, "reconnects": c.reconnects,
                                    "error": self.errors.get(name)}
        with self._lock:
            last, fails = self._motor_last, self._motor_fail
            out["streams"] = {k: {"blocks": v.blocks, "samples": v.samples} for k, v in self._counters.items()}
            out["events_sent"] = self.events_sent
            out["dropped"] = self.dropped
            out["misaligned_reads"] = self.misaligned_reads
        m = self.drivers.motor
        if m is not None:
            out["motor"] = {"state": m.state.value, "measured": last[1] if last else None,
                            "setpoint": last[2] if last else None, "host_time": last[0] if last else None,
                            "failed_polls": fails, "reconnects": m.reconnects, "frame_errors": m.frame_errors}
        return out
