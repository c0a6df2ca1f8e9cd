"""CAN sensors (issue 3): frames described by drivers/rig_sensors.dbc, decoded with cantools.

Every message carries one sample: the channel value, the device time (microseconds
modulo 2^24) and a per-message sequence counter (modulo 256); see
docs/protocols/can.md. The driver opens any python-can interface, so it cannot tell
a simulated peer from a real one.

Faults and how they show up:

* error frame received: ``bus_errors`` +1 and a ``bus_error`` event. A real bus
  sees an occasional error frame (a bit error another node flagged) and goes on,
  so does the driver; only ``error_frame_limit`` of them within
  ``error_frame_window_s`` (default 10 in 1 s: the controller heading for
  error-passive / bus-off) count as a lost bus;
* a lost bus, or the transport raises (``can.CanError``/``OSError``): the base
  machinery drops and reopens the bus with back-off (``disconnected``,
  ``connected``, and a ``gap`` event when samples flow again);
* a sequence gap within one message: ``lost_frames`` += the number missed, one
  ``lost_frames`` event per message and read with the count (gaps longer than
  256 frames are resolved with the device time, see ``_missed``);
* silence (no listened frame for ``silence_timeout_s``, e.g. a pulled cable): not
  a bus error; the bus is treated as lost (``disconnected`` ... ``gap``) all the same;
* a frame of a listened id that does not decode (wrong length, ...): ``frame_errors``.
"""

from __future__ import annotations

import collections
import functools
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import can
import cantools
from cantools.database.can import Database, Message
from pydantic import ConfigDict, Field, model_validator

from daq.config import CanBus, CanSettings, RigConfig
from daq.strict import Closed

from .base import BackoffCfg, ClockSync, Sample, SampleSource, Unwrapper

DBC_PATH = Path(__file__).with_name("rig_sensors.dbc")
TIME_SIGNAL = "time_us"
SEQ_SIGNAL = "seq"
TIME_MODULUS = 1 << 24  # time_us wraps every 16.777216 s
TIME_UNIT_S = 1e-6
SEQ_MODULUS = 1 << 8


@functools.lru_cache(maxsize=8)
def load_dbc(path: str | Path = DBC_PATH) -> Database:
    """Parse a DBC once per process: driver and simulator share the same definitions."""
    return cantools.database.load_file(str(path))


def value_signal(msg: Message) -> str:
    """The message's value signal, named after its interchange channel."""
    names = [s.name for s in msg.signals if s.name not in (TIME_SIGNAL, SEQ_SIGNAL)]
    if len(names) != 1:
        raise ValueError(f"{msg.name}: expected one value signal besides time_us and seq, got {names}")
    return names[0]


def message_rig(msg: Message) -> str:
    """The rig a message belongs to (the DBC's ``Rig`` message attribute)."""
    attr = msg.dbc.attributes.get("Rig") if msg.dbc is not None else None
    return str(attr.value) if attr is not None else ""


def wall_minus_monotonic() -> float:
    """time.time() - time.monotonic(), from the tightest of three bracketed readings (a thread switch between
    the two clock reads would otherwise shift every receive time mapped through it)."""
    best_span, best = float("inf"), 0.0
    for _ in range(3):
        m0 = time.monotonic()
        w = time.time()
        m1 = time.monotonic()
        if m1 - m0 < best_span:
            best_span, best = m1 - m0, w - 0.5 * (m0 + m1)
    return best


class CanBusCfg(CanBus):
    """Which python-can bus to open (interface, channel, bitrate: ``CanBus`` in daq/config.py), plus extra
    keyword arguments for ``can.Bus`` that a rig config does not carry."""

    kwargs: dict[str, Any] = Field(default_factory=dict, description="extra keyword arguments for can.Bus")

    @classmethod
    def of(cls, settings: CanBus) -> CanBusCfg:
        """The bus of a CAN instrument's settings (its interface, channel and bitrate)."""
        return cls(**settings.model_dump(include=set(CanBus.model_fields)))

    def open(self, **extra: Any) -> can.BusABC:
        """Open the bus (raises can.CanError or OSError if it is not there)."""
        kw = {**self.kwargs, **extra}
        if self.bitrate is not None:
            kw["bitrate"] = self.bitrate
        return can.Bus(interface=self.interface, channel=self.channel, **kw)


class SensorSelection(Closed):
    """Which DBC messages to use: a rig's, optionally narrowed to sensor nodes and channels."""

    model_config = ConfigDict(frozen=True)
    rig: str
    sensors: list[str] | None = Field(None, description="DBC transmitter nodes, e.g. DRUM_GAUGE_A; None = all")
    channels: list[str] | None = Field(None, description="interchange channels, e.g. phi; None = all")
    dbc: Path = DBC_PATH

    def messages(self) -> list[Message]:
        """The selected messages, in id order; unknown rig/sensor/channel names raise ValueError."""
        db = load_dbc(self.dbc)
        msgs = [m for m in db.messages if message_rig(m) == self.rig]
        if not msgs:
            raise ValueError(f"{self.dbc.name}: no messages for rig {self.rig!r}")
        if self.sensors is not None:
            known = {n for m in msgs for n in m.senders}
            if bad := sorted(set(self.sensors) - known):
                raise ValueError(f"{self.dbc.name}: rig {self.rig} has no sensor {bad} (has {sorted(known)})")
            msgs = [m for m in msgs if set(m.senders) & set(self.sensors)]
        if self.channels is not None:
            known = {value_signal(m) for m in msgs}
            if bad := sorted(set(self.channels) - known):
                raise ValueError(f"{self.dbc.name}: selection has no channel {bad} (has {sorted(known)})")
            msgs = [m for m in msgs if value_signal(m) in self.channels]
        return sorted(msgs, key=lambda m: m.frame_id)


class CanSensorCfg(Closed):
    """Configuration of one CanSensorDriver."""

    model_config = ConfigDict(frozen=True)
    name: str = "can-sensors"
    bus: CanBusCfg
    select: SensorSelection
    silence_timeout_s: float = Field(0.5, gt=0, description="no listened frame this long = bus lost")
    error_frame_limit: int = Field(10, ge=1, description="error frames within error_frame_window_s that make "
                                                          "the driver reopen the bus (fewer are counted only)")
    error_frame_window_s: float = Field(1.0, gt=0)
    max_batch: int = Field(4096, gt=0, description="frames decoded per read() at most")
    host_time: Literal["receive", "decode"] = Field(
        "receive", description="Sample.host_time: the interface's receive timestamp (kernel/hardware, "
                               "mapped to time.monotonic) or the moment of decoding")
    backoff: BackoffCfg = Field(default_factory=BackoffCfg)

    @model_validator(mode="after")
    def _selection_valid(self) -> "CanSensorCfg":
        self.select.messages()
        return self


@dataclass(slots=True)
class _Track:
    """Per-message decoding state: channel, node clock, last sequence number and device time."""

    msg: Message
    channel: str
    node: str
    seq: int = -1
    dev_t: float = 0.0
    period: float = 0.0  # device-time spacing of consecutive sequence numbers, 0 until seen


@dataclass(slots=True)
class _NodeClock:
    """One sensor node's clock: unwrapping its time_us and estimating its drift against the host."""

    unwrap: Unwrapper
    sync: ClockSync
    stale: bool = False  # after a loss: re-anchor the wrap count with the host clock
    last_dev: float = 0.0
    last_host: float = 0.0


class CanSensorDriver(SampleSource):
    """Streams samples from the CAN sensors of one rig; reconnects by itself after bus errors or silence."""

    transport_errors = (can.CanError, OSError)

    @classmethod
    def from_settings(cls, name: str, settings: CanSettings, rig: RigConfig) -> CanSensorDriver:
        """The driver for one [instruments] entry (drivers/families.py registers it for can-sensors):
        its bus, and the rig's DBC messages narrowed to the channels it carries."""
        return cls(CanSensorCfg(name=name, bus=CanBusCfg.of(settings),
                                select=SensorSelection(rig=rig.rig, channels=list(settings.channels))))

    def __init__(self, cfg: CanSensorCfg) -> None:
        """Resolve the selected DBC messages into per-message tracks and per-node clocks; the bus opens in open()."""
        super().__init__(cfg.name, cfg.backoff)
        self.cfg = cfg
        self._tracks: dict[int, _Track] = {}
        self.nodes: dict[str, _NodeClock] = {}
        for m in cfg.select.messages():
            node = m.senders[0] if m.senders else m.name
            self.nodes.setdefault(node, _NodeClock(Unwrapper(TIME_MODULUS, TIME_UNIT_S), ClockSync()))
            self._tracks[m.frame_id] = _Track(m, value_signal(m), node)
        self.clock = next(iter(self.nodes.values())).sync  # the first sensor's; all are in self.nodes
        self.channels = [t.channel for t in self._tracks.values()]
        self._bus: can.BusABC | None = None
        self._pending: BaseException | None = None
        self._armed = False  # silence detection starts with the first listened frame after connecting
        self._last_frame_host = 0.0
        self._error_frames: collections.deque[float] = collections.deque()  # host times within the window

    # --- transport
    def _connect(self) -> None:
        """Open the bus; sequence tracking restarts, node clocks re-anchor on their next frame."""
        self._bus = self.cfg.bus.open()
        self._pending = None
        self._armed = False
        for tr in self._tracks.values():
            tr.seq = -1  # what went missing while disconnected is a gap, not lost frames
        for nc in self.nodes.values():
            nc.stale = nc.unwrap.last is not None

    def _disconnect(self) -> None:
        """Shut the bus down, whatever state it is in."""
        bus, self._bus = self._bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except Exception:  # noqa: BLE001 - releasing a broken bus must not raise
                pass

    def clock_for(self, sensor: str) -> ClockSync:
        """The drift/offset estimate of one sensor node's clock."""
        return self.nodes[sensor].sync

    # --- decoding
    def _read_samples(self, timeout: float) -> list[Sample]:
        """Decode what is queued (waiting up to timeout for the first frame); raise on bus error or silence."""
        if self._pending is not None:
            exc, self._pending = self._pending, None
            raise exc
        bus = self._bus
        assert bus is not None
        wall_off = wall_minus_monotonic() if self.cfg.host_time == "receive" else None
        out: list[Sample] = []
        lost: dict[int, int] = {}
        err: BaseException | None = None
        wait = timeout
        for _ in range(self.cfg.max_batch):
            try:
                msg = bus.recv(wait)
            except self.transport_errors as exc:
                self._bus_error(f"{type(exc).__name__}: {exc}")
                err = exc
                break
            if msg is None:
                break
            wait = 0.0
            if msg.is_error_frame:
                self._bus_error(f"error frame, data {bytes(msg.data).hex() or '-'}")
                now = time.monotonic()
                self._error_frames.append(now)
                while self._error_frames and now - self._error_frames[0] > self.cfg.error_frame_window_s:
                    self._error_frames.popleft()
                if len(self._error_frames) >= self.cfg.error_frame_limit:
                    self._error_frames.clear()
                    err = can.CanOperationError(f"{self.cfg.error_frame_limit} error frames within "
                                                f"{self.cfg.error_frame_window_s:g} s")
                    break
                continue
            self._frame(msg, out, lost, wall_off)
        for fid, n in lost.items():
            self.emit("lost_frames", self._tracks[fid].msg.name, count=n)
        if err is not None:
            if not out:
                raise err
            self._pending = err  # hand out what was decoded before the error; raise on the next read
            return out
        if not out and self._armed:
            quiet = time.monotonic() - self._last_frame_host
            if quiet > self.cfg.silence_timeout_s:
                raise TimeoutError(f"no sensor frame for {quiet:.3f} s")
        return out

    def _bus_error(self, detail: str) -> None:
        """Count and report a bus error (the caller then gives the bus up)."""
        self.counters.bus_errors += 1
        self.emit("bus_error", detail)

    def _frame(self, msg: can.Message, out: list[Sample], lost: dict[int, int], wall_off: float | None) -> None:
        """Decode one frame into a Sample: host and device time, sequence check, clock sync."""
        tr = self._tracks.get(msg.arbitration_id)
        if tr is None or msg.is_extended_id != tr.msg.is_extended_frame or msg.is_remote_frame:
            ex = self.counters.extra
            ex["foreign_frames"] = ex.get("foreign_frames", 0) + 1
            return
        now = time.monotonic()
        host_t = now
        if wall_off is not None:  # python-can timestamps are time.time()-based; a stale or future one is not used
            rx = msg.timestamp - wall_off
            if now - 3600.0 < rx <= now:
                host_t = rx
        self.counters.frames += 1
        self._last_frame_host = now
        self._armed = True
        try:
            d = tr.msg.decode(msg.data, decode_choices=False, scaling=True, allow_excess=False)
            raw_t, seq, value = d[TIME_SIGNAL], d[SEQ_SIGNAL], d[tr.channel]
        except (cantools.database.DecodeError, KeyError, ValueError, TypeError) as exc:
            self.counters.frame_errors += 1
            self.emit("frame_error", f"{tr.msg.name}: {exc}")
            return
        dev_t = self._device_time(self.nodes[tr.node], raw_t, host_t)
        if tr.seq >= 0:
            step = (seq - tr.seq) % SEQ_MODULUS
            if step == 0:
                if dev_t == tr.dev_t:  # the same frame again
                    ex = self.counters.extra
                    ex["duplicate_frames"] = ex.get("duplicate_frames", 0) + 1
                    return
                step = SEQ_MODULUS  # 255 missed
            missed = self._missed(tr, step, dev_t)
            if missed:
                self.counters.lost_frames += missed
                lost[msg.arbitration_id] = lost.get(msg.arbitration_id, 0) + missed
            elif step == 1 and dev_t > tr.dev_t:
                tr.period = dev_t - tr.dev_t
        tr.seq, tr.dev_t = seq, dev_t
        out.append(Sample(tr.channel, float(value), dev_t, host_t, seq))

    @staticmethod
    def _missed(tr: _Track, step: int, dev_t: float) -> int:
        """Frames missed between two of one message: the sequence gap, plus whole 256-cycles the device time shows."""
        missed = step - 1
        if tr.period > 0.0:
            extra_cycles = round((((dev_t - tr.dev_t) / tr.period) - step) / SEQ_MODULUS)
            missed += SEQ_MODULUS * max(0, extra_cycles)
        return missed

    def _device_time(self, nc: _NodeClock, raw_t: int, host_t: float) -> float:
        """Unwrap a node's time_us; after a loss, pick the wrap count the host clock makes most likely."""
        uw = nc.unwrap
        if nc.stale:
            nc.stale = False
            expected = nc.last_dev + (host_t - nc.last_host)
            wraps = round((expected / TIME_UNIT_S - raw_t) / TIME_MODULUS)
            uw.wraps, uw.last = max(wraps, 0), raw_t
            dev_t = (uw.wraps * TIME_MODULUS + raw_t) * TIME_UNIT_S
        else:
            dev_t = uw(raw_t)
        nc.last_dev, nc.last_host = dev_t, host_t
        nc.sync.update(dev_t, host_t)
        return dev_t
