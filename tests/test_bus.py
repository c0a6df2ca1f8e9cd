"""The sample bus over real ZeroMQ sockets: exact loss accounting, late joiners, no blocking."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import zmq

from daq.io.stream_format import Block, BusEvent, StreamMeta, decode_block, encode_block, make_block
from daq.streaming.bus import Publisher, Subscriber

META = StreamMeta(stream="can", channels=("x1", "phi"), units=("m", "rad"), rig="brake-2dof", rate_hz=1000.0)


def drain(sub, quiet=0.3):
    out = []
    while True:
        m = sub.recv(quiet)
        if m is None:
            return out
        out.append(m)


def wait_connected(pub, sub, meta=META):
    """Publish probe blocks until the subscriber sees one (ZeroMQ's slow-joiner period)."""
    for _ in range(200):
        pub.publish(meta, np.zeros(1), np.zeros((1, len(meta.channels))))
        if sub.recv(0.02) is not None:
            drain(sub, 0.05)
            return
    raise AssertionError("subscriber never connected")


def test_block_codec_round_trip_without_pickle():
    t = np.linspace(0, 1, 7)
    data = np.arange(14.0).reshape(7, 2)
    b = make_block(META, 3, t, data, device_t=t + 100.0)
    parts = [bytes(p) for p in encode_block(b)]
    assert parts[0] == b"S:can"
    assert b"pickle" not in parts[1] and parts[2] == t.tobytes()
    back = decode_block(parts)
    assert back.header == b.header
    np.testing.assert_array_equal(back.data, data)
    np.testing.assert_array_equal(back.device_t, t + 100.0)
    with pytest.raises(ValueError):
        make_block(META, 0, t, np.zeros((6, 2)))
    with pytest.raises(ValueError):
        decode_block(parts[:3])


def test_every_block_arrives_in_order_with_metadata():
    pub = Publisher("tcp://127.0.0.1:0")
    sub = Subscriber(pub.endpoint)
    wait_connected(pub, sub)
    base = sub.stats.streams["can"].last_seq
    for i in range(50):
        pub.publish(META, np.arange(10) + 10 * i, np.full((10, 2), i))
    pub.event("note", "operator", "start of ramp")
    got = drain(sub)
    blocks = [m for m in got if isinstance(m, Block)]
    assert [b.header.seq for b in blocks] == list(range(base + 1, base + 51))
    assert all(b.meta == META for b in blocks)
    assert [m.kind for m in got if isinstance(m, BusEvent)] == ["note"]
    assert sub.stats.lost_blocks == 0
    np.testing.assert_array_equal(blocks[7].data, 7.0)
    pub.close()
    sub.close()


@pytest.mark.slow
def test_slow_subscriber_loses_blocks_counted_exactly_and_never_stalls_publisher():
    """received + counted losses == published, exactly, for a fast and a stalled subscriber."""
    pub = Publisher("tcp://127.0.0.1:0", sndhwm=2000)  # per-subscriber queue in the publisher
    fast = Subscriber(pub.endpoint, rcvhwm=100_000, name="fast")
    slow = Subscriber(pub.endpoint, rcvhwm=10, name="slow")
    wait_connected(pub, fast)
    wait_connected(pub, slow)
    for sub in (fast, slow):
        drain(sub, 0.2)  # probes published for one subscriber reached the other too
    lost0 = {sub.name: sub.stats.lost_blocks for sub in (fast, slow)}
    seq0 = {sub.name: sub.stats.streams[META.stream].last_seq for sub in (fast, slow)}
    n = 6000
    payload = np.random.default_rng(0).normal(size=(1000, 2))
    msgs: dict[str, list] = {"fast": [], "slow": []}
    done = threading.Event()

    def keep_up():  # the fast subscriber reads while the burst goes on
        while not done.is_set():
            m = fast.recv(0.05)
            if m is not None:
                msgs["fast"].append(m)

    reader = threading.Thread(target=keep_up, daemon=True)
    reader.start()
    t0 = time.monotonic()
    for i in range(n):  # the slow subscriber reads nothing meanwhile: its queues fill up
        pub.publish(META, np.arange(1000.0), payload)
        if i % 10 == 0:  # a realistic publisher, not a tight loop: <= 20 M values/s, 4x the bus bar;
            time.sleep(0.001)  # every 100 blocks (200 M values/s) starved the fast reader on a busy 2-core host
    assert time.monotonic() - t0 < 20.0  # the publisher never waited for the stalled subscriber
    time.sleep(0.3)
    done.set()
    reader.join()
    msgs["fast"] += drain(fast)
    msgs["slow"] += drain(slow)
    pub.publish(META, np.arange(1000.0), payload)  # a sentinel reveals losses at the tail of the burst
    for sub in (fast, slow):  # read until it is in (on a loaded host it can take longer than one quiet period)
        t_end = time.monotonic() + 30.0
        while True:
            msgs[sub.name] += drain(sub)
            if sub.stats.streams[META.stream].last_seq >= seq0[sub.name] + n + 1 or time.monotonic() > t_end:
                break
    for sub in (fast, slow):
        blocks = [m for m in msgs[sub.name] if isinstance(m, Block)]
        lost = sub.stats.lost_blocks - lost0[sub.name]
        assert len(blocks) + lost == n + 1, sub.name
        reported = sum(m.count for m in msgs[sub.name] if isinstance(m, BusEvent) and m.kind == "lost_blocks")
        assert reported == lost  # every loss is also reported as an event
        seqs = [b.header.seq for b in blocks]
        assert seqs == sorted(seqs)
    assert fast.stats.lost_blocks == lost0["fast"]
    assert slow.stats.lost_blocks - lost0["slow"] > 1000  # the stalled one lost a good part of the burst
    pub.close()
    fast.close()
    slow.close()


def test_late_joiner_gets_metadata_from_its_first_block():
    pub = Publisher("tcp://127.0.0.1:0")
    stop = threading.Event()

    def run():
        i = 0
        while not stop.is_set():
            pub.publish(META, np.arange(5.0), np.zeros((5, 2)))
            i += 1
            time.sleep(0.002)

    th = threading.Thread(target=run, daemon=True)
    th.start()
    time.sleep(0.3)  # the stream has been running for a while
    late = Subscriber(pub.endpoint, streams=["can"], events=False)
    first = None
    t_end = time.monotonic() + 5
    while first is None and time.monotonic() < t_end:
        m = late.recv(0.1)
        if isinstance(m, Block):
            first = m
    stop.set()
    th.join()
    assert first is not None and first.header.seq > 10
    assert first.meta.channels == ("x1", "phi") and first.meta.units == ("m", "rad")
    assert late.stats.lost_blocks == 0  # joining late is not a loss
    pub.close()
    late.close()


def test_malformed_message_is_counted_not_fatal():
    pub = Publisher("tcp://127.0.0.1:0")
    sub = Subscriber(pub.endpoint)
    wait_connected(pub, sub)
    pub.sock.send_multipart([b"S:can", b"{not json", b"", b""])
    pub.publish(META, np.arange(3.0), np.ones((3, 2)))
    got = drain(sub)
    assert sub.stats.malformed == 1
    assert any(isinstance(m, BusEvent) and m.kind == "malformed" for m in got)
    assert isinstance(got[-1], Block)
    pub.close()
    sub.close()
    assert zmq.Context.instance() is not None
