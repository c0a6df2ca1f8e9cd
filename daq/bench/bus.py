"""``daq bench bus``: publisher -> durable HDF5 recording, zero loss, with the estimator subscribed.

Three processes, as in the daemon: a publisher sends blocks of 8 float64 channels at a
target rate (default 5 M samples/s, counting every channel value), the recorder
(``python -m daq.streaming.recorder``) writes them to disk, and the online estimator subscribes
to the same stream. A sample counts once it is in the closed file: the benchmark
reads the file back and checks every block's content. Beside it, in the same run,
raw pyzmq PUB/SUB with the same message sizes and no headers (the ceiling).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zmq

from daq.config import load_rig
from daq.estimation.online import OnlineCfg, OnlineEstimator
from daq.io.interchange import open_h5
from daq.io.stream_format import StreamMeta
from daq.streaming.bus import Publisher

CHANNELS = 8
BLOCK_SAMPLES = 6250  # per channel: 50 000 values = 400 kB per block


def _raw_pub(endpoint: str, n_blocks: int, ready: "mp.Event") -> None:
    ctx = zmq.Context()
    s = ctx.socket(zmq.PUB)
    s.setsockopt(zmq.SNDHWM, 100_000)
    s.bind(endpoint)
    ready.wait(10)
    time.sleep(0.3)
    payload = np.zeros((BLOCK_SAMPLES, CHANNELS))
    t = np.zeros(BLOCK_SAMPLES)
    for i in range(n_blocks + 1):
        s.send_multipart([b"S:raw", i.to_bytes(8, "little"), memoryview(t), memoryview(payload).cast("B")],
                         copy=False)
    s.send_multipart([b"S:end", b"", b"", b""])
    time.sleep(1.0)
    s.close(linger=2000)
    ctx.term()


def raw_pyzmq(seconds: float = 3.0, endpoint: str = "tcp://127.0.0.1:5591") -> dict:
    """Flat-out PUB -> SUB of the same frames without headers or decoding: the transport's ceiling."""
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 100_000)
    sub.setsockopt(zmq.SUBSCRIBE, b"S:")
    sub.connect(endpoint)
    ready = mp.get_context("spawn").Event()
    n_blocks = int(seconds * 5e6 * 4 / (BLOCK_SAMPLES * CHANNELS))  # enough for ~seconds at up to 20 M/s
    proc = mp.get_context("spawn").Process(target=_raw_pub, args=(endpoint, n_blocks, ready), daemon=True)
    proc.start()
    ready.set()
    got = 0
    t_first = None
    poller = zmq.Poller()
    poller.register(sub, zmq.POLLIN)
    while poller.poll(5000):
        parts = sub.recv_multipart(copy=False)
        if bytes(parts[0].buffer) == b"S:end":
            break
        if t_first is None:
            t_first = time.perf_counter()
            continue
        got += 1
    el = time.perf_counter() - (t_first or time.perf_counter())
    proc.join(5)
    sub.close()
    ctx.term()
    return {"samples_per_s": got * BLOCK_SAMPLES * CHANNELS / el if el > 0 else 0.0, "blocks": got,
            "seconds": el}


def _paced_pub(endpoint: str, rate: float, seconds: float, go: "mp.Event", done: "mp.Event", out: "mp.Queue") -> None:
    """Publish probe blocks until ``go``, then ``rate`` values/s of the bench stream for ``seconds``."""

    # 500 blocks (200 MB) per subscriber at most: a lagging estimator drops and counts, never hoards memory
    pub = Publisher(endpoint, sndhwm=500)
    names = ("x1", "phi", "vb", "vb_set", "temp", "c5", "c6", "c7")
    probe = StreamMeta(stream="probe", channels=("p",), units=("-",))
    meta = StreamMeta(stream="bench", channels=names, units=("m", "rad", "m/s", "m/s", "degC", "-", "-", "-"),
                      rig="brake-2dof", rate_hz=rate / CHANNELS)
    rig_meta = StreamMeta(stream="can", channels=("x1", "phi", "vb"), units=("m", "rad", "m/s"), rig="brake-2dof",
                          rate_hz=1000.0)  # what the estimator needs, at the rig's real rate
    while not go.wait(0.05):
        pub.publish(probe, np.array([time.monotonic()]), np.zeros((1, 1)))
    period = BLOCK_SAMPLES * CHANNELS / rate
    n_blocks = int(round(seconds / period))
    base = np.random.default_rng(0).normal(size=(BLOCK_SAMPLES, CHANNELS))
    idx = np.arange(BLOCK_SAMPLES, dtype=np.float64)
    t0 = time.monotonic()
    for k in range(n_blocks):
        due = t0 + k * period
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        data = base.copy()  # a fresh buffer per block: large arrays are sent without copying
        data[:, 0] = idx + k * BLOCK_SAMPLES  # the content the benchmark checks on disk
        t = due + idx * (period / BLOCK_SAMPLES)
        pub.publish(meta, t, data)
        n_rig = int(round(period * 1000.0))
        t_rig = due + np.arange(n_rig) / 1000.0
        rig = np.column_stack([1e-3 * np.sin(2 * np.pi * 7.5 * t_rig), np.full(n_rig, -0.09), np.full(n_rig, 0.17)])
        pub.publish(rig_meta, t_rig, rig)
    el = time.monotonic() - t0
    out.put({"blocks": n_blocks, "seconds": el, "behind_s": max(0.0, el - n_blocks * period)})
    done.set()
    time.sleep(1.0)
    pub.close()


def _estimator_proc(endpoint: str, stop: "mp.Event", out: "mp.Queue") -> None:
    """The online estimator as its own, lower-priority process: a consumer that may drop, never stall."""

    os.nice(10)
    est = OnlineEstimator(load_rig("brake-2dof"), OnlineCfg(sub_endpoint=endpoint, streams=("can",), fit="thread"))
    est.start()
    stop.wait()
    out.put({k: getattr(est.stats, k) for k in ("blocks_in", "lost_blocks", "blocks_out", "samples_out")})
    est.stop()


def bench_bus(seconds: float = 60.0, rate: float = 5e6, endpoint: str = "tcp://127.0.0.1:5592") -> dict:
    """Paced publisher -> recorder (own process) -> HDF5 file, with the online estimator subscribed."""

    ctx = mp.get_context("spawn")
    go, done = ctx.Event(), ctx.Event()
    out = ctx.Queue()
    est_out = ctx.Queue()
    pub = ctx.Process(target=_paced_pub, args=(endpoint, rate, seconds, go, done, out), daemon=True)
    pub.start()
    work = Path(tempfile.mkdtemp(prefix="daq-bench-bus-"))
    path = work / "run.h5"
    rec = subprocess.Popen([sys.executable, "-m", "daq.streaming.recorder", "--endpoint", endpoint, "--rig", "brake-2dof",
                            "-o", str(path), "--stream", "bench", "--stream", "probe"],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    est_stop = ctx.Event()
    est = ctx.Process(target=_estimator_proc, args=(endpoint, est_stop, est_out), daemon=True)
    est.start()
    try:
        for line in rec.stdout:  # wait until the recorder's subscription is live
            if line.startswith("stream probe"):
                break
        go.set()
        result = out.get(timeout=seconds * 3 + 60)
        done.wait(10)
        time.sleep(0.5)
        rec.send_signal(signal.SIGTERM)
        rec.wait(timeout=120)
        est_stop.set()
        est_stats = est_out.get(timeout=60)
    finally:
        if rec.poll() is None:
            rec.kill()
        pub.join(5)
        est.join(5)
    with open_h5(path) as f:
        col = f["streams/bench/x1"][()]
        events = f["events"][()] if "events" in f else []
    expected = result["blocks"] * BLOCK_SAMPLES
    intact = col.size == expected and bool(np.array_equal(col, np.arange(expected, dtype=np.float64)))
    if not intact:
        print(f"bench bus: file holds {col.size} of {expected} samples; first mismatch at "
              f"{int(np.argmax(col[:expected] != np.arange(min(expected, col.size))))}", file=sys.stderr)
    lost_events = sum(int(e["count"]) for e in events if e["kind"] in (b"lost_blocks", "lost_blocks"))
    size = path.stat().st_size
    for p in work.iterdir():
        p.unlink()
    work.rmdir()
    raw = raw_pyzmq(3.0)
    values = expected * CHANNELS
    achieved = values / result["seconds"]
    return {
        "benchmark": "bus",
        "case": f"{CHANNELS} float64 channels, blocks of {BLOCK_SAMPLES} samples, {seconds:g} s, paced at "
                f"{rate / 1e6:g} M values/s, plus the rig's 1 kHz stream; recorder in its own process; "
                "estimator (own process) subscribed to the rig stream",
        "samples_per_s": achieved,
        "seconds": result["seconds"],
        "values_recorded": int(col.size) * CHANNELS,
        "values_published": values,
        "file_bytes": size,
        "lost": int(expected - col.size) // BLOCK_SAMPLES + lost_events,
        "content_verified": intact,
        "publisher_behind_s": result["behind_s"],
        "estimator": est_stats,
        "raw_pyzmq_samples_per_s": raw["samples_per_s"],
        "ratio_to_raw": achieved / raw["samples_per_s"] if raw["samples_per_s"] else None,
        "target": {"samples_per_s_min": 5e6, "seconds": 60, "lost": 0},
    }


def format_bus(r: dict) -> str:
    return "\n".join([
        f"benchmark bus: {r['case']}",
        f"  recorded    {r['samples_per_s'] / 1e6:8.2f} M values/s for {r['seconds']:.1f} s, "
        f"lost {r['lost']}, every value checked on disk: {r['content_verified']}",
        f"  raw pyzmq   {r['raw_pyzmq_samples_per_s'] / 1e6:8.2f} M values/s (same frame sizes, no headers, "
        f"no disk)",
        f"  estimator   {r['estimator']}",
    ])


if __name__ == "__main__":
    res = bench_bus(float(os.environ.get("BENCH_BUS_SECONDS", "60")))
    print(json.dumps(res, indent=2))
