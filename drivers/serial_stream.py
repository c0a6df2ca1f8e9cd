"""Driver for high-rate binary sensor streams over serial (laser x1, Hall phi, ... at 1 kHz).

Protocol: drivers/framing.py and docs/protocols/serial-stream.md. The port is any
pyserial URL (a device path, a pty link, ``socket://host:port``, ``loop://``).
"""

from __future__ import annotations

import time
from typing import Iterable

import serial
from pydantic import Field, field_validator

from daq.config import RigConfig, StreamPort, StreamSettings

from .base import BackoffCfg, Sample, SampleSource, Unwrapper, close_quietly
from .framing import MAX_CHANNELS, TIME_MODULUS, TIME_UNIT_S, FrameDecoder, SeqTracker, StreamChannel, scale_for_lsb


class BinaryStreamCfg(StreamPort):
    """Where the stream is (url, baudrate: ``StreamPort`` in daq/config.py) and what its frames carry; must match
    the device's configuration."""

    channels: list[StreamChannel] = Field(min_length=1, max_length=MAX_CHANNELS)
    max_read_bytes: int = Field(1 << 16, ge=64, description="cap on one read, bounds the latency of a call")

    @field_validator("channels")
    @classmethod
    def _unique(cls, v: list[StreamChannel]) -> list[StreamChannel]:
        """Two slots with one name would silently interleave two signals in one channel."""
        names = [c.name for c in v]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"channel names repeat: {dup}")
        return v


def stream_channels(cfg: RigConfig, names: Iterable[str]) -> list[StreamChannel]:
    """Frame slots for rig channels with a scale ten times finer than each channel's lsb."""
    out = []
    for name in names:
        ch = cfg.channels[name]
        out.append(StreamChannel(name=name, scale=scale_for_lsb(ch.lsb), unit=ch.unit))
    return out


class BinaryStreamDriver(SampleSource):
    """Reads, checks and decodes the frame stream; counts garbage, bad CRCs and lost frames; reconnects."""

    transport_errors = (serial.SerialException, OSError)
    framed = True

    @classmethod
    def from_settings(cls, name: str, settings: StreamSettings, rig: RigConfig) -> BinaryStreamDriver:
        """The driver for one [instruments] entry (drivers/families.py registers it for serial-stream):
        its port, and frame slots for the rig channels it carries."""
        port = settings.model_dump(include=set(StreamPort.model_fields))
        return cls(BinaryStreamCfg(**port, channels=stream_channels(rig, settings.channels)), name=name)

    def __init__(self, cfg: BinaryStreamCfg, name: str = "serial-stream", backoff: BackoffCfg | None = None) -> None:
        super().__init__(name, backoff)
        self.cfg = cfg
        self.names = tuple(c.name for c in cfg.channels)
        self.scales = tuple(c.scale for c in cfg.channels)
        self.decoder = FrameDecoder(len(cfg.channels))
        self.seq = SeqTracker()
        # kept across reconnects: a replugged cable does not reset the device's clock
        self.unwrap = Unwrapper(TIME_MODULUS, TIME_UNIT_S)
        self.bytes_in = 0
        self._port: serial.SerialBase | None = None

    def _connect(self) -> None:
        """Open the port and start from a clean decoder: the first bytes may be mid-frame."""
        self._port = serial.serial_for_url(self.cfg.url, baudrate=self.cfg.baudrate, timeout=0.1)
        self.decoder.reset()
        self.seq.reset()

    def _disconnect(self) -> None:
        """Close the port, swallowing errors of an already dead device."""
        port, self._port = self._port, None
        close_quietly(port)

    def _read_samples(self, timeout: float) -> list[Sample]:
        """Take what is buffered now, or wait up to timeout for the first byte, then decode."""
        port = self._port
        if port is None:
            raise serial.SerialException("port not open")
        if port.timeout != timeout:
            port.timeout = timeout
        cap = self.cfg.max_read_bytes
        if isinstance(port, serial.Serial):  # a tty: in_waiting is the exact byte count
            n = port.in_waiting
            data = port.read(min(n, cap) if n else 1)
            if data and not n:
                n = port.in_waiting
                if n:
                    data += port.read(min(n, cap))
        else:  # URL handlers (socket://, ...): in_waiting may only say "something"; drain non-blocking
            data = port.read(1)
            if data:
                port.timeout = 0
                data += port.read(cap)
                port.timeout = timeout
        if not data:
            return []
        return self.decode(data, time.monotonic())

    def decode(self, data: bytes, host_time: float) -> list[Sample]:
        """Decode bytes received at host_time into samples, updating counters, events and the clock fit."""
        self.bytes_in += len(data)
        dec = self.decoder
        frames = dec.feed(data)
        c = self.counters
        cs, garbage, ferr = dec.take_counts()
        if cs:
            c.checksum_errors += cs
            self.emit("checksum_error", "frame CRC failed", count=cs)
        if ferr:
            c.frame_errors += ferr
            self.emit("frame_error", f"valid frame with a channel count other than {dec.n}", count=ferr)
        c.garbage_bytes += garbage
        if not frames:
            return []
        c.frames += len(frames)
        out: list[Sample] = []
        append = out.append
        names, scales = self.names, self.scales
        seq_track, unwrap = self.seq, self.unwrap
        dev = 0.0
        for seq, t_us, raw in frames:
            lost = seq_track(seq)
            if lost:
                c.lost_frames += lost
                self.emit("lost_frames", f"sequence jumped to {seq}", count=lost)
            dev = unwrap(t_us)
            for name, scale, r in zip(names, scales, raw):
                append(Sample(name, r * scale, dev, host_time, seq))
        # all frames of one read share host_time, so the newest has the smallest delay: the only one
        # that can sit on the clock fit's lower envelope
        self.clock.update(dev, host_time)
        return out
