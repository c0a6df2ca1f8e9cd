"""Benchmark ``estimator``: the online friction estimator on 8 channels x 10 kHz over real sockets.

A publisher process sends a simulated brake-2dof run (x1, phi, vb, vb_set, temp and
three spare channels) in real time, 100-sample blocks (10 ms), on a real ZeroMQ
PUB socket. Two phases, one after the other on the same machine:

* baseline: a plain Subscriber that only receives and decodes the blocks; its
  latency (block sent -> decoded) is the floor the bus itself sets;
* estimator: the OnlineEstimator (running law fit in its worker process) processes
  the same stream and publishes its estimates; latency = input block sent -> estimate
  block published (its ``latency`` channel). A sink process subscribes to the
  estimates and measures input sent -> estimate received (one more hop).

All latencies use time.monotonic(), which is one clock for every process on a host.
``keeps_up``: no lost block, every sample estimated by the end, and no backlog growth
(the latency of the last quarter of the run is not above the first quarter's).
"""

from __future__ import annotations

import math
import multiprocessing as mp
import time

import numpy as np

from daq.config import load_rig
from daq.estimation.online import OnlineCfg, OnlineEstimator
from daq.io.stream_format import Block, StreamMeta
from daq.sim.run import simulate
from daq.streaming.bus import Publisher, Subscriber

RATE_HZ = 10_000.0
BLOCK = 100
CHANNELS = ("x1", "phi", "vb", "vb_set", "temp", "spare1", "spare2", "spare3")
TARGET_P99_MS = 10.0


def _signals(seconds: float) -> np.ndarray:
    """(n, 8) samples: a noisy simulated brake-2dof run at 10 kHz plus three spare channels."""

    rec = simulate(load_rig("brake-2dof"), duration=seconds, rate=RATE_HZ, seed=11)
    n = rec.t.size
    spare = np.random.default_rng(0).normal(0.0, 1e-3, size=(n, 3))
    return np.column_stack([rec.channels[c] for c in CHANNELS[:5]] + [spare])


def _publisher_main(q: mp.Queue, go: mp.Event, data: np.ndarray) -> None:
    """Child process: bind, wait for go, then publish the blocks at the rate of the clock."""

    pub = Publisher("tcp://127.0.0.1:0", sndhwm=100_000)
    q.put(pub.endpoint)
    meta = StreamMeta(stream="rig", channels=CHANNELS, units=("m", "rad", "m/s", "m/s", "degC", "V", "V", "V"),
                      rig="brake-2dof", source="bench", rate_hz=RATE_HZ)
    go.wait(30.0)
    n_blocks = data.shape[0] // BLOCK
    t0 = time.monotonic() + 0.02
    late = 0.0
    for k in range(n_blocks):
        t_last = t0 + ((k + 1) * BLOCK - 1) / RATE_HZ  # a block leaves once its last sample exists
        wait = t_last - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        late = max(late, time.monotonic() - t_last)
        t = t0 + (k * BLOCK + np.arange(BLOCK)) / RATE_HZ
        pub.publish(meta, t, data[k * BLOCK:(k + 1) * BLOCK])
    q.put({"blocks": n_blocks, "samples": n_blocks * BLOCK, "late_max_s": late})
    pub.close()  # LINGER flushes what is queued


def _sink_main(endpoint: str, q: mp.Queue, ready: mp.Event, stop: mp.Event) -> None:
    """Child process: receive the estimates, measure input sent -> estimate received."""

    sub = Subscriber(endpoint, streams=["estimator"], events=False, name="bench-sink")
    ready.set()
    lat: list[float] = []
    samples = 0
    idle = 0
    while idle < 3 or not stop.is_set():  # after stop, leave once the socket is quiet
        m = sub.recv(0.05)
        idle = 0 if m is not None else idle + 1
        if isinstance(m, Block) and m.meta.stream == "estimator":
            now = time.monotonic()
            col = m.meta.channels.index("latency")
            input_sent = m.header.sent_host_time - float(m.data[:, col].max())
            lat.append(now - input_sent)
            samples += m.header.n
    q.put({"latency": lat, "samples": samples, "lost": sub.stats.lost_blocks})
    sub.close()


def _start_publisher(ctx, data: np.ndarray):
    """Start a publisher process; returns (process, result queue, go event, endpoint)."""
    q, go = ctx.Queue(), ctx.Event()
    p = ctx.Process(target=_publisher_main, args=(q, go, data), daemon=True)
    p.start()
    return p, q, go, q.get(timeout=60.0)


def _pcts(x: list[float] | np.ndarray) -> dict[str, float]:
    """p50 / p99 / max in milliseconds."""
    a = np.asarray(x, dtype=float) * 1e3
    if a.size == 0:
        return {"p50_ms": math.nan, "p99_ms": math.nan, "max_ms": math.nan}
    return {"p50_ms": float(np.percentile(a, 50)), "p99_ms": float(np.percentile(a, 99)), "max_ms": float(a.max())}


def _growth_ms(lat: list[float]) -> float:
    """Median latency of the last quarter minus the first quarter's: > 0 means a backlog builds up."""
    a = np.asarray(lat, dtype=float)
    if a.size < 8:
        return math.nan
    q = a.size // 4
    return float((np.median(a[-q:]) - np.median(a[:q])) * 1e3)


def _baseline(ctx, data: np.ndarray, seconds: float) -> dict:
    """Receive and decode only: the bus's own latency for the same blocks."""

    proc, q, go, endpoint = _start_publisher(ctx, data)
    sub = Subscriber(endpoint, streams=["rig"], events=False, rcvhwm=100_000, name="bench-baseline")
    time.sleep(0.3)  # let the subscription reach the publisher
    go.set()
    lat: list[float] = []
    samples = 0
    end = time.monotonic() + seconds + 3.0
    expected = (data.shape[0] // BLOCK) * BLOCK
    while time.monotonic() < end and samples < expected:
        m = sub.recv(0.05)
        if isinstance(m, Block):
            lat.append(time.monotonic() - m.header.sent_host_time)
            samples += m.header.n
    sent = q.get(timeout=10.0)
    proc.join(5.0)
    lost = sub.stats.lost_blocks
    sub.close()
    return {"latency": lat, "samples": samples, "lost": lost, "sent": sent}


def _estimator_run(ctx, data: np.ndarray, seconds: float) -> dict:
    """The OnlineEstimator on the same stream, a sink process on its output."""

    proc, q, go, endpoint = _start_publisher(ctx, data)
    est = OnlineEstimator(load_rig("brake-2dof"), OnlineCfg(sub_endpoint=endpoint, fit="process"))
    sink_q, sink_ready, sink_stop = ctx.Queue(), ctx.Event(), ctx.Event()
    sink = ctx.Process(target=_sink_main, args=(est.endpoint, sink_q, sink_ready, sink_stop), daemon=True)
    sink.start()  # boots while the estimator compiles and starts its fit worker
    est.warm_up()
    sink_ready.wait(60.0)
    time.sleep(0.3)  # both subscriptions in place
    go.set()
    cpu0, wall0 = time.process_time(), time.monotonic()
    expected = (data.shape[0] // BLOCK) * BLOCK
    end = wall0 + seconds + 3.0
    while time.monotonic() < end and est.stats.samples_in < expected:
        est.poll(0.02)
    for _ in range(5):  # flush what the last block left pending
        est.poll(0.01)
    wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
    sent = q.get(timeout=10.0)
    proc.join(5.0)
    sink_stop.set()
    sink_res = sink_q.get(timeout=30.0)
    sink.join(5.0)
    res = {"latency": list(est.latency_log), "work": list(est.work_log), "stats": est.stats.model_dump(),
           "n_taps": est.fe.n_taps if est.fe else 0, "delay_s": est.fe.delay_s if est.fe else math.nan,
           "sent": sent, "sink": sink_res, "wall": wall, "cpu": cpu,
           "fit": est.last_fit.model_dump() if est.last_fit else None}
    est.close()
    return res


def bench_estimator(seconds: float = 5.0) -> dict:
    """Run both phases for ``seconds`` of real-time data each; returns the figures (JSON-able)."""
    ctx = mp.get_context("spawn")
    data = _signals(seconds)
    base = _baseline(ctx, data, seconds)
    run = _estimator_run(ctx, data, seconds)
    st = run["stats"]
    lat, b = _pcts(run["latency"]), _pcts(base["latency"])
    e2e, work = _pcts(run["sink"]["latency"]), _pcts(run["work"])
    expected = run["sent"]["samples"]
    all_done = st["samples_in"] == expected and st["samples_out"] == expected - (run["n_taps"] - 1)
    growth = _growth_ms(run["latency"])
    keeps_up = bool(st["lost_blocks"] == 0 and all_done and not growth > 1.0)
    fit = run["fit"]
    return {
        "benchmark": "estimator",
        "case": f"brake-2dof, {len(CHANNELS)} channels x {RATE_HZ:.0f} Hz, {BLOCK}-sample blocks, {seconds:g} s, "
                "real ZeroMQ sockets, publisher/sink in their own processes",
        "channels": len(CHANNELS),
        "rate_hz": RATE_HZ,
        "block_samples": BLOCK,
        "seconds": seconds,
        "latency_p50_ms": lat["p50_ms"],
        "latency_p99_ms": lat["p99_ms"],
        "latency_max_ms": lat["max_ms"],
        "e2e_latency_p50_ms": e2e["p50_ms"],
        "e2e_latency_p99_ms": e2e["p99_ms"],
        "work_per_block_p50_ms": work["p50_ms"],
        "work_per_block_p99_ms": work["p99_ms"],
        "keeps_up": keeps_up,
        "lost_blocks": st["lost_blocks"],
        "blocks_sent": run["sent"]["blocks"],
        "blocks_processed": st["blocks_in"],
        "estimates": st["samples_out"],
        "estimates_received": run["sink"]["samples"],
        "samples_per_s": st["samples_in"] * len(CHANNELS) / run["wall"],
        "cpu_fraction": run["cpu"] / run["wall"],
        "latency_growth_ms": growth,
        "publisher_late_max_ms": run["sent"]["late_max_s"] * 1e3,
        "differentiator_delay_ms": run["delay_s"] * 1e3,
        "fits_published": st["fits_published"],
        "last_fit": None if fit is None else {k: fit["params"][k] for k in fit["free"]},
        "baseline": "plain Subscriber: receive + decode the same blocks, latency sent -> decoded",
        "baseline_latency_p50_ms": b["p50_ms"],
        "baseline_latency_p99_ms": b["p99_ms"],
        "baseline_lost_blocks": base["lost"],
        "baseline_samples": base["samples"],
        "target": {"latency_p99_ms_max": TARGET_P99_MS, "channels": 8, "rate_hz": RATE_HZ},
        "meets_target": bool(keeps_up and lat["p99_ms"] <= TARGET_P99_MS),
    }


def format_estimator(r: dict) -> str:
    """Human report: the estimator's figures beside the baseline of the same run."""
    ok = "yes" if r["keeps_up"] else "NO"
    return "\n".join([
        f"benchmark {r['benchmark']}: {r['case']}",
        f"  estimator   latency p50 {r['latency_p50_ms']:6.2f} ms  p99 {r['latency_p99_ms']:6.2f} ms"
        f"  max {r['latency_max_ms']:6.2f} ms  (input sent -> estimate published; target p99 <= "
        f"{r['target']['latency_p99_ms_max']:g} ms)",
        f"  + one hop   latency p50 {r['e2e_latency_p50_ms']:6.2f} ms  p99 {r['e2e_latency_p99_ms']:6.2f} ms"
        f"  (-> estimate received by a subscriber; {r['estimates_received']} estimates)",
        f"  baseline    latency p50 {r['baseline_latency_p50_ms']:6.2f} ms  p99 {r['baseline_latency_p99_ms']:6.2f} ms"
        f"  (receive + decode only)",
        f"  work        {r['work_per_block_p50_ms']:.3f} ms per block (p99 {r['work_per_block_p99_ms']:.3f} ms),"
        f" {r['cpu_fraction'] * 100:.0f} % of one core, {r['samples_per_s'] / 1e3:.0f} k samples/s",
        f"  keeps up    {ok}: {r['blocks_processed']}/{r['blocks_sent']} blocks, {r['lost_blocks']} lost,"
        f" latency growth {r['latency_growth_ms']:+.2f} ms; {r['fits_published']} law fits"
        f" (last {r['last_fit']}); differentiator delay {r['differentiator_delay_ms']:.1f} ms (not in latency)",
    ])
