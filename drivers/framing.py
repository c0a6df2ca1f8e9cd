"""The binary sensor-stream frame, written once for both sides (driver and simulator); no I/O here.

Frame (little-endian, docs/protocols/serial-stream.md)::

    offset  size  field
    0       2     sync      0xA5 0x5A
    2       1     n         number of values (1..MAX_CHANNELS)
    3       2     seq       uint16, +1 per frame, wraps 65535 -> 0
    5       4     t_us      uint32, device clock in microseconds, wraps at 2**32
    9       4*n   values    int32 each, value = raw * scale of that channel
    9+4n    2     crc       CRC-16/CCITT-FALSE over bytes 0 .. 8+4n (sync included)

Frame length is 11 + 4n bytes (19 for two channels).
"""

from __future__ import annotations

import binascii
import math
import struct
from dataclasses import dataclass

from pydantic import ConfigDict, Field

from daq.strict import Closed

SYNC = b"\xa5\x5a"
MAX_CHANNELS = 16
SEQ_MODULUS = 1 << 16
TIME_MODULUS = 1 << 32  # t_us wraps after 4294.967296 s (~71.6 min)
TIME_UNIT_S = 1e-6
CRC_INIT = 0xFFFF
CRC_POLY = 0x1021
HEADER_LEN = 9  # sync + n + seq + t_us
RAW_MIN, RAW_MAX = -(1 << 31), (1 << 31) - 1

_CRC = struct.Struct("<H")


def frame_len(n: int) -> int:
    """Bytes of a frame carrying n values (the decoder needs it before it can check a CRC)."""
    return HEADER_LEN + 4 * n + 2


def crc16(data: bytes | bytearray | memoryview, crc: int = CRC_INIT) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor) in C via binascii."""
    return binascii.crc_hqx(data, crc)


def _crc_table() -> tuple[int, ...]:
    """The 256-entry table of the MSB-first CRC-16 with polynomial 0x1021 (for the reference implementation)."""
    table = []
    for b in range(256):
        c = b << 8
        for _ in range(8):
            c = ((c << 1) ^ CRC_POLY) & 0xFFFF if c & 0x8000 else (c << 1) & 0xFFFF
        table.append(c)
    return tuple(table)


CRC_TABLE = _crc_table()


def crc16_table(data: bytes | bytearray, crc: int = CRC_INIT) -> int:
    """Table-driven reference of crc16, byte by byte, for firmware authors and the tests; same result."""
    for b in data:
        crc = ((crc << 8) & 0xFFFF) ^ CRC_TABLE[((crc >> 8) ^ b) & 0xFF]
    return crc


class StreamChannel(Closed):
    """One value slot of the frame: which channel it carries and the fixed-point scale of its int32."""

    model_config = ConfigDict(frozen=True)
    name: str = Field(min_length=1)
    scale: float = Field(gt=0, description="channel units per count; finer than the channel's lsb")
    unit: str = ""


def scale_for_lsb(lsb: float, default: float = 1e-6) -> float:
    """A power of ten at least ten times finer than lsb, so fixed point never adds visible quantisation."""
    if lsb <= 0:
        return default
    return 10.0 ** math.floor(math.log10(lsb / 10.0) + 1e-9)


def to_raw(value: float, scale: float) -> int:
    """Fixed-point count of a value (rounded to nearest, clipped to int32 as a real ADC would saturate)."""
    if not math.isfinite(value):
        return RAW_MAX if value > 0 else RAW_MIN
    return max(RAW_MIN, min(RAW_MAX, round(value / scale)))


class FrameCodec:
    """Encodes frames of a fixed channel count; the sim uses it, the decoder shares its structs."""

    def __init__(self, n: int) -> None:
        if not 1 <= n <= MAX_CHANNELS:
            raise ValueError(f"n must be 1..{MAX_CHANNELS}, got {n}")
        self.n = n
        self.length = frame_len(n)
        self.head = struct.Struct(f"<2sBHI{n}i")  # everything the CRC covers
        self.body = struct.Struct(f"<BHI{n}iH")  # from byte 2 to the end, for unpack_from

    def encode(self, seq: int, t_us: int, raw: tuple[int, ...] | list[int]) -> bytes:
        """One complete frame; seq and t_us are reduced modulo their field width."""
        head = self.head.pack(SYNC, self.n, seq % SEQ_MODULUS, t_us % TIME_MODULUS, *raw)
        return head + _CRC.pack(binascii.crc_hqx(head, CRC_INIT))


RawFrame = tuple[int, int, tuple[int, ...]]  # (seq, t_us, raw values)


class FrameDecoder:
    """Finds, checks and unpacks frames in a byte stream fed in arbitrary chunks.

    Rule: search the sync; a candidate is accepted only if its n byte matches and its CRC
    holds, otherwise the decoder steps ONE byte past the candidate's sync and searches again,
    so a fake sync inside garbage can never swallow the real frame behind it (resync within
    one frame). Every byte not part of an accepted frame counts as garbage. The result does
    not depend on how the stream is chunked.
    """

    def __init__(self, n: int) -> None:
        self.codec = FrameCodec(n)
        self.n = n
        self._buf = bytearray()
        self.checksum_errors = 0  # candidates with the right n whose CRC failed
        self.garbage_bytes = 0  # bytes skipped outside accepted frames
        self.frame_errors = 0  # CRC-valid frames with another channel count (misconfiguration)
        self.frames = 0

    def reset(self) -> None:
        """Forget buffered bytes (after a reconnect the stream restarts mid-frame)."""
        self._buf.clear()

    @property
    def pending(self) -> int:
        """Bytes waiting for the rest of a frame."""
        return len(self._buf)

    def take_counts(self) -> tuple[int, int, int]:
        """(checksum_errors, garbage_bytes, frame_errors) since the last call, for the driver's counters."""
        out = (self.checksum_errors, self.garbage_bytes, self.frame_errors)
        self.checksum_errors = self.garbage_bytes = self.frame_errors = 0
        return out

    def feed(self, data: bytes | bytearray) -> list[RawFrame]:
        """Append data and return every complete, valid frame in stream order."""
        buf = self._buf
        buf += data
        out: list[RawFrame] = []
        end = len(buf)
        pos = 0
        n = self.n
        length = self.codec.length
        unpack = self.codec.body.unpack_from
        crc = binascii.crc_hqx
        find = buf.find
        garbage = 0
        while True:
            i = find(SYNC, pos)
            if i < 0:
                keep = end - 1 if end > pos and buf[end - 1] == 0xA5 else end  # a sync may be split
                garbage += keep - pos
                pos = keep
                break
            garbage += i - pos
            pos = i
            if end - i < 3:
                break
            if buf[i + 2] != n:
                other = buf[i + 2]
                if 1 <= other <= MAX_CHANNELS:
                    olen = frame_len(other)
                    if end - i < olen:
                        break
                    if crc(buf[i:i + olen - 2], CRC_INIT) == _CRC.unpack_from(buf, i + olen - 2)[0]:
                        self.frame_errors += 1
                        pos = i + olen
                        continue
                garbage += 1
                pos = i + 1
                continue
            if end - i < length:
                break
            f = unpack(buf, i + 2)
            if crc(buf[i:i + length - 2], CRC_INIT) != f[-1]:
                self.checksum_errors += 1
                garbage += 1
                pos = i + 1
                continue
            out.append((f[1], f[2], f[3:-1]))
            pos = i + length
        del buf[:pos]
        self.garbage_bytes += garbage
        self.frames += len(out)
        return out


@dataclass
class SeqTracker:
    """Counts frames lost from gaps in the wrapping sequence counter; a backward step resynchronises."""

    modulus: int = SEQ_MODULUS
    last: int | None = None
    lost: int = 0
    restarts: int = 0

    def __call__(self, seq: int) -> int:
        """Frames missing just before this one (0 if it follows the last)."""
        last, self.last = self.last, seq
        if last is None:
            return 0
        gap = (seq - last - 1) % self.modulus
        if gap >= self.modulus // 2:  # duplicate or device restart: not a loss we can count
            self.restarts += 1
            return 0
        self.lost += gap
        return gap

    def reset(self) -> None:
        """Forget the last sequence number (a new connection restarts the count)."""
        self.last = None
