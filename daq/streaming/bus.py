"""The ZeroMQ sample bus: PUB/SUB, numpy payloads without pickling, exact loss accounting.

Why PUB/SUB: acquisition must never wait for a consumer. A PUB socket drops a
message for a subscriber whose queue (high-water mark) is full instead of
blocking, so a slow subscriber loses data but never stalls the publisher. Every
block carries a per-stream sequence number, so each subscriber counts exactly
how many blocks it lost (and reports it as an event), and a recorder that must
lose nothing gets a high-water mark deep enough for its write latency.

Decision record: docs/decisions/0007-zeromq-bus-pydantic-headers-raw-buffers.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import zmq
from pydantic import ConfigDict, Field

from daq.io.stream_format import (
    EVENT_PREFIX,
    SAMPLE_PREFIX,
    Block,
    BusEvent,
    StreamMeta,
    decode_block,
    decode_event,
    encode_block,
    encode_event,
    make_block,
)
from daq.strict import Closed

ZERO_COPY_BYTES = 65536  # arrays larger than this are sent without copying


class BusCfg(Closed):
    model_config = ConfigDict(frozen=True)
    endpoint: str = Field("tcp://127.0.0.1:5560", description="where the publisher binds (tcp:// or ipc://)")
    sndhwm: int = Field(10_000, ge=1, description="blocks queued per subscriber before the PUB drops for it")
    rcvhwm: int = Field(10_000, ge=1, description="blocks queued in a subscriber before it drops")


class Publisher:
    """Binds a PUB socket; assigns each stream's block sequence numbers."""

    def __init__(self, endpoint: str = BusCfg().endpoint, sndhwm: int = BusCfg().sndhwm,
                 ctx: zmq.Context | None = None) -> None:
        self.ctx = ctx or zmq.Context.instance()
        self.sock = self.ctx.socket(zmq.PUB)
        self.sock.setsockopt(zmq.SNDHWM, sndhwm)
        self.sock.setsockopt(zmq.LINGER, 1000)
        self.sock.bind(endpoint)
        self.endpoint = self.sock.getsockopt_string(zmq.LAST_ENDPOINT)  # resolves tcp://...:0
        self._seq: dict[str, int] = {}
        self._event_seq: dict[str, int] = {}
        self.blocks_sent = 0
        self.samples_sent = 0

    def publish(self, meta: StreamMeta, t: np.ndarray, data: np.ndarray,
                device_t: np.ndarray | None = None) -> Block:
        """Number and send a block. Arrays above 64 kB go out without copying: do not modify them after."""
        seq = self._seq.get(meta.stream, 0)
        self._seq[meta.stream] = seq + 1
        block = make_block(meta, seq, t, data, device_t, sent_host_time=time.monotonic())
        self.send(block)
        return block

    def send(self, block: Block) -> None:
        """Send an already-numbered block (e.g. one re-published by a bridge)."""
        big = block.data.nbytes > ZERO_COPY_BYTES
        self.sock.send_multipart(encode_block(block), copy=not big)
        self.blocks_sent += 1
        self.samples_sent += block.header.n * len(block.meta.channels)

    def event(self, kind: str, source: str, detail: str = "", **kw) -> BusEvent:
        seq = self._event_seq.get(source, 0)
        self._event_seq[source] = seq + 1
        ev = BusEvent(kind=kind, source=source, host_time=time.monotonic(), detail=detail, seq=seq, **kw)
        self.sock.send_multipart(encode_event(ev))
        return ev

    def close(self) -> None:
        self.sock.close()


@dataclass
class StreamStats:
    """What one subscriber knows about one stream."""

    meta: StreamMeta
    blocks: int = 0
    samples: int = 0
    lost_blocks: int = 0
    last_seq: int = -1
    restarts: int = 0


@dataclass
class SubStats:
    streams: dict[str, StreamStats] = field(default_factory=dict)
    events: int = 0
    malformed: int = 0

    @property
    def lost_blocks(self) -> int:
        return sum(s.lost_blocks for s in self.streams.values())


class Subscriber:
    """Connects a SUB socket; counts every lost block per stream from the sequence numbers.

    ``recv`` returns a Block, a BusEvent, or None on timeout. Losses detected here are
    returned as local ``lost_blocks`` events (source = this subscriber's name) right before
    the block that revealed them, so whoever records events records the drops too.
    """

    def __init__(self, endpoint: str, streams: list[str] | None = None, events: bool = True,
                 rcvhwm: int = BusCfg().rcvhwm, name: str = "subscriber", ctx: zmq.Context | None = None) -> None:
        self.ctx = ctx or zmq.Context.instance()
        self.sock = self.ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.RCVHWM, rcvhwm)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.name = name
        if streams is None:
            self.sock.setsockopt(zmq.SUBSCRIBE, SAMPLE_PREFIX)
        else:
            for s in streams:
                self.sock.setsockopt(zmq.SUBSCRIBE, SAMPLE_PREFIX + s.encode())
        if events:
            self.sock.setsockopt(zmq.SUBSCRIBE, EVENT_PREFIX)
        self.sock.connect(endpoint)
        self.stats = SubStats()
        self._pending: Block | None = None
        self._poller = zmq.Poller()
        self._poller.register(self.sock, zmq.POLLIN)

    def recv(self, timeout: float = 0.1) -> Block | BusEvent | None:
        if self._pending is not None:
            block, self._pending = self._pending, None
            return block
        if not self._poller.poll(int(timeout * 1000)):
            return None
        parts = self.sock.recv_multipart(copy=False)
        prefix = bytes(parts[0].buffer[:2])
        try:
            if prefix == EVENT_PREFIX:
                self.stats.events += 1
                return decode_event([p.buffer for p in parts])
            block = decode_block([p.buffer for p in parts])
        except (ValueError, TypeError) as exc:
            self.stats.malformed += 1
            return BusEvent(kind="malformed", source=self.name, host_time=time.monotonic(), detail=str(exc)[:200])
        lost = self._account(block)
        if lost:
            self._pending = block
            return BusEvent(kind="lost_blocks", source=self.name, host_time=time.monotonic(),
                            detail=f"{block.meta.stream}: {lost} blocks dropped before seq {block.header.seq}",
                            count=lost)
        return block

    def _account(self, block: Block) -> int:
        st = self.stats.streams.get(block.meta.stream)
        if st is None:
            st = self.stats.streams[block.meta.stream] = StreamStats(block.meta)
        seq = block.header.seq
        lost = 0
        if st.last_seq >= 0:
            if seq > st.last_seq:
                lost = seq - st.last_seq - 1
            else:  # the publisher restarted its numbering
                st.restarts += 1
        st.last_seq = seq
        st.meta = block.meta
        st.blocks += 1
        st.samples += block.header.n
        st.lost_blocks += lost
        return lost

    def close(self) -> None:
        self.sock.close()
