"""What travels on the sample bus: blocks of samples with a pydantic header, and events.

A block is one stream's samples over a short interval: ``t`` (host monotonic time,
the common time base of a run), optionally ``device_t``, and ``data`` with one
column per channel. The header repeats the stream's metadata (channel names,
units, dtype) in every block, so a subscriber that joins late knows what it
receives from its first message, without waiting for a restart.

Wire format (ZeroMQ multipart, no pickling):
    [topic, header JSON, t bytes, data bytes(, device_t bytes)]
topic = b"S:" + stream name for samples, b"E:" + source for events.

Decision records: docs/decisions/0007-zeromq-bus-pydantic-headers-raw-buffers.md, docs/decisions/0012-layout-by-layer.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field

from daq.strict import Closed

SAMPLE_PREFIX = b"S:"
EVENT_PREFIX = b"E:"


class StreamMeta(Closed):
    """Everything a subscriber needs to interpret a stream's blocks."""

    model_config = ConfigDict(frozen=True)
    stream: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.\-]+$")
    channels: tuple[str, ...] = Field(min_length=1)
    units: tuple[str, ...]
    dtype: Literal["float64", "float32"] = "float64"
    rig: str | None = None
    source: str = ""  # instrument or process that produces it
    rate_hz: float | None = None  # nominal sample rate, if regular


class BlockHeader(Closed):
    model_config = ConfigDict(frozen=True)
    meta: StreamMeta
    seq: int = Field(ge=0, description="per-stream block counter; a gap means blocks were dropped")
    n: int = Field(ge=0, description="samples in the block")
    has_device_t: bool = False
    sent_host_time: float = 0.0  # publisher's monotonic clock when sent (latency measurement)


@dataclass
class Block:
    header: BlockHeader
    t: np.ndarray  # (n,) float64 host monotonic time [s]
    data: np.ndarray  # (n, n_channels) meta.dtype
    device_t: np.ndarray | None = None  # (n,) float64 device time [s]

    @property
    def meta(self) -> StreamMeta:
        return self.header.meta

    def column(self, channel: str) -> np.ndarray:
        return self.data[:, self.meta.channels.index(channel)]


def make_block(meta: StreamMeta, seq: int, t: np.ndarray, data: np.ndarray,
               device_t: np.ndarray | None = None, sent_host_time: float = 0.0) -> Block:
    """Validate shapes once at the edge; everything downstream trusts them."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    data = np.ascontiguousarray(data, dtype=meta.dtype)
    if data.ndim == 1:
        data = data.reshape(-1, 1)
    if data.shape != (t.size, len(meta.channels)):
        raise ValueError(f"{meta.stream}: data shape {data.shape}, expected ({t.size}, {len(meta.channels)})")
    if device_t is not None:
        device_t = np.ascontiguousarray(device_t, dtype=np.float64)
        if device_t.shape != t.shape:
            raise ValueError(f"{meta.stream}: device_t shape {device_t.shape} != t shape {t.shape}")
    hdr = BlockHeader(meta=meta, seq=seq, n=t.size, has_device_t=device_t is not None,
                      sent_host_time=sent_host_time)
    return Block(hdr, t, data, device_t)


def encode_block(block: Block) -> list[bytes | memoryview]:
    """Multipart frames for ZeroMQ; arrays go as raw buffers (zero-copy with send_multipart(copy=False))."""
    parts: list[bytes | memoryview] = [SAMPLE_PREFIX + block.meta.stream.encode(),
                                       block.header.model_dump_json().encode(),
                                       memoryview(block.t), memoryview(block.data).cast("B")]
    if block.device_t is not None:
        parts.append(memoryview(block.device_t))
    return parts


def decode_block(parts: list) -> Block:
    """Inverse of encode_block; raises ValueError on a malformed message."""
    if len(parts) not in (4, 5):
        raise ValueError(f"sample message with {len(parts)} parts")
    hdr = BlockHeader.model_validate_json(bytes(parts[1]))
    t = np.frombuffer(parts[2], dtype=np.float64)
    data = np.frombuffer(parts[3], dtype=hdr.meta.dtype)
    nc = len(hdr.meta.channels)
    if t.size != hdr.n or data.size != hdr.n * nc:
        raise ValueError(f"{hdr.meta.stream}: payload sizes do not match header n={hdr.n}")
    dev = np.frombuffer(parts[4], dtype=np.float64) if hdr.has_device_t and len(parts) == 5 else None
    return Block(hdr, t, data.reshape(hdr.n, nc), dev)


class BusEvent(Closed):
    """An event on the bus: driver events, recorder and estimator notices, operator notes, ramp segments."""

    model_config = ConfigDict(frozen=True)
    kind: str = Field(min_length=1)
    source: str
    host_time: float
    detail: str = ""
    gap_s: float | None = None
    count: int | None = None
    seq: int = 0  # per-source event counter


def encode_event(ev: BusEvent) -> list[bytes]:
    return [EVENT_PREFIX + ev.source.encode(), ev.model_dump_json().encode()]


def decode_event(parts: list) -> BusEvent:
    if len(parts) != 2:
        raise ValueError(f"event message with {len(parts)} parts")
    return BusEvent.model_validate_json(bytes(parts[1]))
