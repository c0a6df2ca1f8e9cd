"""Benchmark ``can``: frames decoded per second by CanSensorDriver, beside raw python-can recv.

A virtual bus is pre-filled in bursts with the drum-pendulum's seven messages
(encoded with cantools from the project DBC); two receivers on the channel get the
very same frames: the driver (recv, decode, sequence/loss check, clock sync,
Sample) and a bare ``bus.recv()`` loop, the baseline. Only the draining is timed,
on one thread, so the figures are per core. A saturated 1 Mbit/s classic CAN bus
carries about 9 000 frames/s; the target is 20 000.
"""

from __future__ import annotations

import time
import uuid

import can

from drivers.can_sensors import (
    SEQ_MODULUS,
    SEQ_SIGNAL,
    TIME_MODULUS,
    TIME_SIGNAL,
    CanBusCfg,
    CanSensorCfg,
    CanSensorDriver,
    SensorSelection,
    value_signal,
)

TARGET_FRAMES_PER_S = 20_000.0
SAMPLE_PERIOD_US = 4096  # 4096 samples x 4096 us = 2^24 us: a burst ends where the time counter wraps
SAMPLES_PER_BURST = 4096  # also a multiple of 256, so replaying the burst keeps sequence and time continuous


def _burst(rig: str) -> list[can.Message]:
    """One burst of frames: per sample, one frame per message of the rig, consecutive seq and time."""

    msgs = SensorSelection(rig=rig).messages()
    out = []
    for k in range(SAMPLES_PER_BURST):
        t_us, seq = (k * SAMPLE_PERIOD_US) % TIME_MODULUS, k % SEQ_MODULUS
        for m in msgs:
            data = m.encode({value_signal(m): 1e-3 * (k % 1000), TIME_SIGNAL: t_us, SEQ_SIGNAL: seq})
            out.append(can.Message(arbitration_id=m.frame_id, data=data, is_extended_id=False))
    return out


def _drain_driver(drv, n: int, limit_s: float) -> tuple[int, float, float]:
    """Read until n samples came (or limit_s passed); returns (samples, wall s, thread CPU s)."""
    got = 0
    w0, c0 = time.perf_counter(), time.thread_time()
    deadline = w0 + limit_s
    while got < n and time.perf_counter() < deadline:
        got += len(drv.read(0.0))
    return got, time.perf_counter() - w0, time.thread_time() - c0


def _drain_raw(bus: can.BusABC, n: int) -> tuple[int, float]:
    """The baseline: take the same frames off the bus without decoding them."""
    got = 0
    w0 = time.perf_counter()
    recv = bus.recv
    while got < n and recv(0.0) is not None:
        got += 1
    return got, time.perf_counter() - w0


def bench_can(seconds: float = 3.0, rig: str = "drum-pendulum") -> dict:
    """Decode rate of the CAN sensor driver (about ``seconds`` of timed decoding) and its raw baseline."""

    bus_cfg = CanBusCfg(interface="virtual", channel=f"bench-can-{uuid.uuid4().hex}")
    drv = CanSensorDriver(CanSensorCfg(name="bench-can", bus=bus_cfg, select=SensorSelection(rig=rig),
                                       silence_timeout_s=3600.0))
    burst = _burst(rig)
    drv.open()
    raw, tx = bus_cfg.open(), bus_cfg.open()
    sent = decoded = raw_got = 0
    t_drv = c_drv = t_raw = 0.0
    try:
        while t_drv < seconds or decoded == 0:
            for msg in burst:
                tx.send(msg)
            sent += len(burst)
            got, w, c = _drain_driver(drv, len(burst), limit_s=max(10.0, 4 * seconds))
            decoded, t_drv, c_drv = decoded + got, t_drv + w, c_drv + c
            got, w = _drain_raw(raw, len(burst))
            raw_got, t_raw = raw_got + got, t_raw + w
            if decoded != sent:
                break
    finally:
        for bus in (raw, tx):
            bus.shutdown()
        drv.close()
    ctr = drv.counters
    fps = decoded / t_drv if t_drv > 0 else 0.0
    base = raw_got / t_raw if t_raw > 0 else 0.0
    return {
        "frames": decoded,
        "frames_sent": sent,
        "seconds": t_drv,
        "frames_per_s": fps,
        "cpu_frames_per_s": decoded / c_drv if c_drv > 0 else 0.0,
        "baseline_frames_per_s": base,
        "ratio": fps / base if base > 0 else 0.0,
        "baseline_frames": raw_got,
        "lost": ctr.lost_frames + ctr.frame_errors + (sent - decoded),
        "target_frames_per_s": TARGET_FRAMES_PER_S,
        "meets_target": fps >= TARGET_FRAMES_PER_S,
        "messages": len(burst) // SAMPLES_PER_BURST,
        "rig": rig,
    }


def format_can(result: dict) -> str:
    """The benchmark's figures for a person."""
    r = result
    return "\n".join([
        f"can: CanSensorDriver on a python-can virtual bus ({r['rig']}, {r['messages']} messages, "
        f"{r['frames']} frames in {r['seconds']:.2f} s)",
        f"  decoded           {r['frames_per_s']:>12,.0f} frames/s  ({r['cpu_frames_per_s']:,.0f} per CPU-second)",
        f"  baseline raw recv {r['baseline_frames_per_s']:>12,.0f} frames/s  (same frames, no decoding)",
        f"  ratio             {r['ratio']:>12.2f}",
        f"  target            {r['target_frames_per_s']:>12,.0f} frames/s  "
        f"({'met' if r['meets_target'] else 'NOT met'}; a full 1 Mbit/s classic CAN bus is ~9 000)",
        f"  lost              {r['lost']:>12d}",
    ])
