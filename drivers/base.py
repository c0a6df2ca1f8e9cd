"""What every instrument driver shares: samples, events, connection state, back-off, clock sync.

A driver never knows whether its peer is real hardware or a simulator: it is
given a pyserial URL or a python-can interface/channel and speaks the protocol
documented in docs/protocols.md. Reconnection is the driver's job: a lost port
or a bus error moves it to RECONNECTING, it retries with exponential back-off,
and when data flows again it reports the gap as an event.
"""

from __future__ import annotations

import collections
import enum
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from daq.signals import BIN_S, clock_line
from daq.strict import Closed


class DriverState(str, enum.Enum):
    CLOSED = "closed"
    CONNECTING = "connecting"
    CONNECTED = "connected"
    RECONNECTING = "reconnecting"


@dataclass(slots=True)
class Sample:
    """One measured value. Plain dataclass, not pydantic: drivers make tens of thousands per second."""

    channel: str
    value: float
    device_time: float  # device clock, unwrapped [s]
    host_time: float  # host monotonic time of reception [s] (time.monotonic() base)
    seq: int = -1  # the frame's sequence counter, -1 if the protocol has none


EventKind = Literal["connected", "disconnected", "gap", "checksum_error", "frame_error", "lost_frames",
                    "bus_error", "watchdog", "note"]


class DriverEvent(BaseModel):
    """Something the operator and the recording should know about (crosses to the bus and the recorder)."""

    model_config = ConfigDict(frozen=True)
    kind: EventKind
    source: str
    host_time: float
    detail: str = ""
    gap_s: float | None = None
    count: int | None = None


class BackoffCfg(Closed):
    model_config = ConfigDict(frozen=True)
    initial_s: float = Field(0.05, gt=0)
    factor: float = Field(2.0, ge=1.0)
    max_s: float = Field(2.0, gt=0)


class Backoff:
    """Exponential back-off between reconnection attempts, reset by a success."""

    def __init__(self, cfg: BackoffCfg | None = None) -> None:
        self.cfg = cfg or BackoffCfg()
        self.delay = self.cfg.initial_s
        self.next_try = 0.0

    def ready(self, now: float) -> bool:
        return now >= self.next_try

    def failed(self, now: float) -> None:
        self.next_try = now + self.delay
        self.delay = min(self.delay * self.cfg.factor, self.cfg.max_s)

    def succeeded(self) -> None:
        self.delay = self.cfg.initial_s
        self.next_try = 0.0


class ClockSync:
    """Estimates offset and drift of a device clock against the host's monotonic clock, live.

    Host receive times carry a positive, jittery delay. In each bin of device time we keep
    only the pair with the smallest delay, and fit the line under them
    (:func:`daq.signals.clock_line`, the same line the file reader fits offline, its drift
    bounded to what clocks do): host = offset + device / (1 + drift), so ``drift`` is the
    device clock's rate error (+300e-6 = the device runs 300 ppm fast). Memory is bounded by
    ``max_bins``; the line is refitted once a second (every 4th new bin; every bin for the first 5 s), not
    per read: a refit over 2 400 bins (ten minutes) takes 2.7 ms here.
    """

    def __init__(self, bin_s: float = BIN_S, max_bins: int = 2400) -> None:
        self.bin_s = bin_s
        self.max_bins = max_bins
        self._bins: collections.OrderedDict[int, tuple[float, float]] = collections.OrderedDict()
        self._added = 0  # bins made so far
        self._fitted: tuple[int, tuple[float, float] | None] = (-1, None)  # (bins made at the fit, its result)

    def update(self, device_t: float, host_t: float) -> None:
        k = int(device_t // self.bin_s)
        best = self._bins.get(k)
        if best is None or host_t - device_t < best[1] - best[0]:
            self._bins[k] = (device_t, host_t)
            if best is None:
                self._added += 1
                if len(self._bins) > self.max_bins:
                    self._bins.popitem(last=False)

    def estimate(self) -> tuple[float, float] | None:
        """(offset [s], drift [-]) or None until two bins have data."""
        if len(self._bins) < 2:
            return None
        made = self._fitted[0]
        if made != self._added and (len(self._bins) < 20 or self._added - made >= 4):
            d, h = np.array(list(self._bins.values())).T
            line = clock_line(d, h, bin_s=None)  # already the quickest of each bin
            self._fitted = (self._added, (line.offset, 1.0 / line.slope - 1.0))
        return self._fitted[1]

    def to_host(self, device_t: float) -> float | None:
        est = self.estimate()
        if est is None:
            return None
        offset, drift = est
        return offset + device_t / (1.0 + drift)


class Unwrapper:
    """Turns a wrapping device counter (e.g. a 24-bit microsecond timer) into monotonic seconds."""

    def __init__(self, modulus: int, unit_s: float) -> None:
        self.modulus = modulus
        self.unit_s = unit_s
        self.last: int | None = None
        self.wraps = 0

    def __call__(self, raw: int) -> float:
        if self.last is not None and raw < self.last and self.last - raw > self.modulus // 2:
            self.wraps += 1
        self.last = raw
        return (self.wraps * self.modulus + raw) * self.unit_s

    def reset(self) -> None:
        self.last = None
        self.wraps = 0


def close_quietly(port: object | None) -> None:
    """Close a transport that may already be dead; a vanished device fails to close in many ways."""
    if port is None:
        return
    try:
        port.close()  # type: ignore[attr-defined]
    except Exception:  # noqa: BLE001
        pass


class EventLog:
    """A bounded, thread-safe list of DriverEvents that the owner drains with ``events()``."""

    def __init__(self, source: str, maxlen: int = 10_000) -> None:
        self.source = source
        self._events: collections.deque[DriverEvent] = collections.deque(maxlen=maxlen)
        self._lock = threading.Lock()

    def emit(self, kind: EventKind, detail: str = "", **kw) -> None:
        ev = DriverEvent(kind=kind, source=self.source, host_time=time.monotonic(), detail=detail, **kw)
        with self._lock:
            self._events.append(ev)

    def events(self) -> list[DriverEvent]:
        """Events since the last call."""
        with self._lock:
            out = list(self._events)
            self._events.clear()
        return out


@dataclass
class Counters:
    frames: int = 0
    samples: int = 0
    checksum_errors: int = 0
    frame_errors: int = 0
    lost_frames: int = 0
    garbage_bytes: int = 0
    reconnects: int = 0
    bus_errors: int = 0
    extra: dict[str, int] = field(default_factory=dict)


class SampleSource(ABC):
    """The interface of every streaming instrument family (CAN sensors, serial streams, slow meters).

    ``read`` returns the samples that arrived within ``timeout`` and does the reconnecting:
    it never raises for a lost device, it reports it as events and keeps trying.
    """

    name: str

    def __init__(self, name: str, backoff: BackoffCfg | None = None) -> None:
        self.name = name
        self.state = DriverState.CLOSED
        self.counters = Counters()
        self.clock = ClockSync()
        self._log = EventLog(name)
        self._backoff = Backoff(backoff)
        self._lost_at: float | None = None
        self._last_sample_host: float | None = None

    # --- what a concrete driver implements
    @abstractmethod
    def _connect(self) -> None:
        """Open the transport; raise OSError (or the transport's error) if the device is absent."""

    @abstractmethod
    def _disconnect(self) -> None:
        """Release the transport; must not raise."""

    @abstractmethod
    def _read_samples(self, timeout: float) -> list[Sample]:
        """Decode what arrives within timeout; raise on a lost device or bus error."""

    #: exception types that mean "the device went away" for this driver's transport
    transport_errors: tuple[type[BaseException], ...] = (OSError,)
    #: every frame carries every channel (``names``) with one device time, as the binary serial
    #: stream's do: the acquisition publishes such a source as one stream whose rows are frames
    framed: ClassVar[bool] = False

    # --- the shared machinery
    def open(self) -> None:
        self.state = DriverState.CONNECTING
        self._try_connect(time.monotonic())

    def close(self) -> None:
        self._disconnect()
        self.state = DriverState.CLOSED

    def events(self) -> list[DriverEvent]:
        """Events since the last call (connected, gaps, checksum errors, ...)."""
        return self._log.events()

    def emit(self, kind: EventKind, detail: str = "", **kw) -> None:
        self._log.emit(kind, detail, **kw)

    def _try_connect(self, now: float) -> bool:
        if not self._backoff.ready(now):
            return False
        try:
            self._connect()
        except self.transport_errors as exc:
            self._backoff.failed(now)
            if self.state != DriverState.RECONNECTING:
                self.state = DriverState.RECONNECTING
                self._lost_at = now
                self.emit("disconnected", f"cannot open: {exc}")
            return False
        self._backoff.succeeded()
        reconnect = self._lost_at is not None
        if reconnect:
            self.counters.reconnects += 1
        self.emit("connected", "reconnected" if reconnect else "opened")
        self.state = DriverState.CONNECTED  # last: whoever sees CONNECTED also sees the event
        return True

    def _lost(self, exc: BaseException) -> None:
        now = time.monotonic()
        self._disconnect()
        self.state = DriverState.RECONNECTING
        self._lost_at = self._last_sample_host or now
        self._backoff.failed(now)
        self.emit("disconnected", f"{type(exc).__name__}: {exc}")

    def read(self, timeout: float = 0.1) -> list[Sample]:
        if self.state == DriverState.CLOSED:
            raise RuntimeError(f"{self.name}: read on a closed driver; call open() first")
        if self.state != DriverState.CONNECTED:
            if not self._try_connect(time.monotonic()):
                time.sleep(min(timeout, max(0.0, self._backoff.next_try - time.monotonic())))
                return []
        try:
            samples = self._read_samples(timeout)
        except self.transport_errors as exc:
            self._lost(exc)
            return []
        if samples:
            first = samples[0].host_time
            if self._lost_at is not None:
                self.emit("gap", "no data while reconnecting", gap_s=first - self._lost_at)
                self._lost_at = None
            self._last_sample_host = samples[-1].host_time
            self.counters.samples += len(samples)
        return samples
