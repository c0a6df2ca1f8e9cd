"""A simulated high-rate binary sensor (laser, Hall, ...) streaming frames over a pty at a UART's line rate."""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass

import numpy as np

from daq.config import StreamSettings
from drivers.framing import RAW_MAX, RAW_MIN, SYNC, TIME_MODULUS, FrameCodec, StreamChannel, scale_for_lsb

from .instrument import DeviceClock, Faults, SimInstrument
from .pty_port import PtyPort
from .realtime import RealtimeRig, Tick


def line_rate_bytes_per_s(baudrate: int, bits_per_byte: int = 10) -> float:
    """Bytes per second a UART carries: 8N1 costs 10 bit times per byte (start, 8 data, stop)."""
    return baudrate / bits_per_byte


class TokenBucket:
    """Paces a writer to a byte rate; ``burst`` is what may leave back to back (a UART FIFO's worth)."""

    def __init__(self, rate: float, burst: float = 256.0) -> None:
        self.rate = float(rate)
        self.burst = float(burst)
        self.tokens = self.burst
        self.t = time.monotonic()

    def take(self, n: int) -> None:
        """Spend n bytes of credit, sleeping off any debt (average rate stays exact despite coarse sleeps)."""
        now = time.monotonic()
        self.tokens = min(self.burst, self.tokens + (now - self.t) * self.rate)
        self.t = now
        self.tokens -= n
        if self.tokens < 0:
            time.sleep(-self.tokens / self.rate)


@dataclass(slots=True)
class SentFrame:
    """What the simulated device did with one frame: the test oracle for the driver."""

    seq: int  # full (unwrapped) sequence number; the wire carries seq % 65536
    t_us: int  # as on the wire (already reduced modulo 2**32)
    device_time: float  # the device clock [s], before wrapping
    raw: tuple[int, ...]
    values: tuple[float, ...]  # measured values before fixed-point conversion
    dropped: bool
    after_garbage: bool  # a garbage burst went out just before this frame


class SimSerialStream(SimInstrument):
    """Encodes each tick's measured values as frames and writes them to a PtyPort at the line rate.

    Faults: ``garbage_prob`` puts a burst of random bytes (sometimes containing a fake
    sync with a plausible channel count) before a frame; ``drop_prob`` skips a frame
    while its sequence number is still used up, as a device with a full buffer would.
    """

    @classmethod
    def from_settings(cls, rig: RealtimeRig, name: str, settings: StreamSettings, *, port: PtyPort | None,
                      clock: DeviceClock, seed: int) -> SimSerialStream:
        """The stream for one [instruments] entry (sim_backends/families.py registers it): its channels at its
        baud rate on ``port``."""
        return cls(rig, port, names=tuple(settings.channels), baudrate=settings.baudrate, name=name, clock=clock,
                   seed=seed)

    def __init__(self, rig: RealtimeRig, port: PtyPort, names: tuple[str, ...] = ("x1", "phi"),
                 channels: list[StreamChannel] | None = None, baudrate: int = 921_600, name: str = "laser",
                 clock: DeviceClock | None = None, faults: Faults | None = None, seed: int = 0,
                 max_garbage: int = 48, log_frames: int = 200_000, chunk_bytes: int = 256) -> None:
        if channels is None:
            channels = [StreamChannel(name=n, scale=scale_for_lsb(rig.cfg.channels[n].lsb),
                                      unit=rig.cfg.channels[n].unit) for n in names]
        super().__init__(rig, name, {c.name: rig.cfg.channels[c.name] for c in channels}, clock, faults, seed)
        self.port = port
        self.stream_channels = list(channels)
        self.scales = np.array([c.scale for c in channels])
        self.codec = FrameCodec(len(channels))
        self.baudrate = baudrate
        self.bucket = TokenBucket(line_rate_bytes_per_s(baudrate), burst=chunk_bytes)
        self.chunk_bytes = chunk_bytes
        self.max_garbage = max_garbage
        self.seq = 0
        self.log: collections.deque[SentFrame] = collections.deque(maxlen=log_frames)
        self.log_lock = threading.Lock()
        self.frames_sent = 0
        self.frames_dropped = 0
        self.garbage_bytes = 0
        self.fake_syncs = 0  # fake syncs with the right channel count: each costs the decoder one CRC check
        self.bytes_written = 0

    def _garbage(self) -> bytes:
        """A burst of random bytes; half the time with a fake sync and channel-count byte inside."""
        n = int(self.rng.integers(1, self.max_garbage + 1))
        burst = bytearray(self.rng.integers(0, 256, n, dtype=np.uint8).tobytes())
        if n >= 3 and self.rng.random() < 0.5:
            k = int(self.rng.integers(0, n - 2))
            burst[k:k + 3] = SYNC + bytes([self.codec.n])
        self.fake_syncs += burst.count(SYNC + bytes([self.codec.n]))
        return bytes(burst)

    def emit(self, tick: Tick) -> None:
        """Encode the tick's samples (with the configured faults) and send them paced at the line rate."""
        measured = self.measured(tick)
        values = np.column_stack([measured[c.name] for c in self.stream_channels])
        raw = np.clip(np.rint(values / self.scales), RAW_MIN, RAW_MAX).astype(np.int64)
        dev = self.device_times(tick)
        t_us = np.rint(dev * 1e6).astype(np.int64) % TIME_MODULUS
        faults = self.faults
        out = bytearray()
        records = []
        for i in range(len(dev)):
            after_garbage = faults.garbage_prob > 0 and self.rng.random() < faults.garbage_prob
            if after_garbage:
                g = self._garbage()
                self.garbage_bytes += len(g)
                out += g
            dropped = faults.drop_prob > 0 and self.rng.random() < faults.drop_prob
            r = tuple(int(x) for x in raw[i])
            if dropped:
                self.frames_dropped += 1
            else:
                out += self.codec.encode(self.seq, int(t_us[i]), r)
                self.frames_sent += 1
            records.append(SentFrame(self.seq, int(t_us[i]), float(dev[i]), r, tuple(values[i].tolist()),
                                     dropped, after_garbage))
            self.seq += 1
        with self.log_lock:
            self.log.extend(records)
        self._send(bytes(out))

    def _send(self, data: bytes) -> None:
        """Write in UART-FIFO-sized chunks, each after its line time; what the pty cannot take is lost."""
        step = self.chunk_bytes
        for k in range(0, len(data), step):
            piece = data[k:k + step]
            self.bucket.take(len(piece))
            self.bytes_written += self.port.write(piece)

    def sent_frames(self) -> list[SentFrame]:
        """A copy of the log of frames so far (thread-safe)."""
        with self.log_lock:
            return list(self.log)

    def close(self) -> None:
        """The port belongs to the caller (it is the 'cable'); nothing to release here."""
