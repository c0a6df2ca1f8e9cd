"""Benchmark ``serial``: the binary stream driver over a real pty, beside raw pyserial reads of the same bytes.

Four figures from one run, all with the 2-channel frame of the brake rig's laser/Hall stream
(19 bytes): the pure in-memory decode rate (driver.decode, Samples included); raw pyserial
reads of the byte stream over a pty with no decoding (the baseline); the driver reading and
decoding the same stream over a pty with the writer going flat out (headroom); and the driver
fed AT the line rate of 921 600 baud 8N1 (92 160 B/s) for loss and CPU load. The writer is a
separate process (a device is not in our process and must not share our GIL); it keeps its
pty open until the reader has drained everything, so every byte written is accounted for.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import queue
import tempfile
import time
from pathlib import Path

import numpy as np
import serial

from drivers.framing import CRC_INIT, SYNC, TIME_MODULUS, StreamChannel, crc16
from drivers.serial_stream import BinaryStreamCfg, BinaryStreamDriver
from sim_backends.pty_port import PtyPort

BAUD = 921_600
LINE_RATE = BAUD / 10  # 8N1: start + 8 data + stop bits per byte
N_CHANNELS = 2
FRAME_BYTES = 11 + 4 * N_CHANNELS
FRAME_PERIOD_US = 1e6 * FRAME_BYTES / LINE_RATE  # device time of frames back to back at the line rate
CHANNELS = [StreamChannel(name="x1", scale=1e-7, unit="m"), StreamChannel(name="phi", scale=1e-6, unit="rad")]


def make_frames(seq0: int, n: int) -> bytes:
    """n consecutive 2-channel frames from seq0, built with numpy (fast enough to outrun any reader)."""
    dt = np.dtype([("sync", "S2"), ("n", "u1"), ("seq", "<u2"), ("t", "<u4"), ("v", "<i4", (N_CHANNELS,)),
                   ("crc", "<u2")])
    k = np.arange(seq0, seq0 + n, dtype=np.int64)
    a = np.zeros(n, dtype=dt)
    a["sync"] = SYNC
    a["n"] = N_CHANNELS
    a["seq"] = k % 65536
    a["t"] = np.rint(k * FRAME_PERIOD_US).astype(np.int64) % TIME_MODULUS
    a["v"][:, 0] = (np.sin(k * 1e-3) * 2e5).astype(np.int32)  # +-20 mm at 0.1 um
    a["v"][:, 1] = (np.cos(k * 7e-4) * 1e5).astype(np.int32)  # +-0.1 rad at 1 urad
    raw = a.view(np.uint8).reshape(n, dt.itemsize)
    body = raw[:, :-2].tobytes()
    m = dt.itemsize - 2
    crcs = np.fromiter((crc16(body[i * m:(i + 1) * m], CRC_INIT) for i in range(n)), dtype="<u2", count=n)
    a["crc"] = crcs
    return a.tobytes()


def _writer(link: str, rate: float | None, ready, go, stop, release, result) -> None:
    """Child process: the device. Writes whole frames to its pty, flat out or paced at ``rate`` bytes/s."""

    port = PtyPort(link)
    block_frames = 1 << 14
    seq = 0
    nxt = make_frames(seq, block_frames)
    ready.set()
    go.wait()
    step = FRAME_BYTES * (13 if rate else 1724)  # ~256 B (a UART FIFO) paced, ~32 KiB flat out
    written = 0
    t0 = time.monotonic()
    while not stop.is_set():
        block = nxt
        seq += block_frames
        for k in range(0, len(block), step):
            piece = block[k:k + step]
            if rate:  # each piece leaves when the line would have carried everything before it
                delay = t0 + written / rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            sent = port.write_all(piece, timeout=5.0)
            written += sent
            if sent < len(piece) or stop.is_set():
                break
        else:
            nxt = make_frames(seq, block_frames)
    result.put({"bytes": written, "frames": written // FRAME_BYTES, "dropped_bytes": port.dropped_bytes})
    release.wait(30.0)
    port.close()


class _Device:
    """Starts the writer process and hands its pty link to the reader; the context cleans up."""

    def __init__(self, rate: float | None) -> None:
        ctx = mp.get_context("spawn")
        self._tmp = tempfile.TemporaryDirectory(prefix="bench-serial-")
        self.link = str(Path(self._tmp.name) / "stream")
        self.ready, self.go, self.stop, self.release = (ctx.Event() for _ in range(4))
        self.result = ctx.Queue()
        self.proc = ctx.Process(target=_writer, args=(self.link, rate, self.ready, self.go, self.stop, self.release,
                                                      self.result), daemon=True)

    def __enter__(self) -> "_Device":
        """Start the writer and wait until its pty exists."""
        self.proc.start()
        if not self.ready.wait(30.0):
            raise RuntimeError("bench writer did not start")
        return self

    def finish(self, read) -> dict:
        """Stop writing and return what was written; ``read`` keeps draining meanwhile (the writer may block)."""
        self.stop.set()
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            try:
                return self.result.get_nowait()
            except queue.Empty:
                read()
        raise RuntimeError("bench writer did not report")

    def __exit__(self, *exc) -> None:
        """Let the writer close its pty and exit; remove the link's directory."""
        self.release.set()
        self.proc.join(timeout=10.0)
        if self.proc.is_alive():
            self.proc.kill()
        self._tmp.cleanup()


def _raw_reads(seconds: float) -> float:
    """Baseline: bytes/s of the same stream read with pyserial (in_waiting/read as the driver does), no decoding."""

    with _Device(None) as dev:
        port = serial.serial_for_url(dev.link, baudrate=BAUD, timeout=0.05)
        dev.go.set()
        n = 0
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            k = port.in_waiting
            n += len(port.read(min(k, 1 << 16) if k else 1))
        elapsed = time.perf_counter() - t0
        total = n

        def read() -> None:
            """Keep draining while the writer winds down (it may be blocked on a full pty)."""
            nonlocal total
            k = port.in_waiting
            total += len(port.read(min(k, 1 << 16) if k else 1))

        written = dev.finish(read)["bytes"]
        deadline = time.monotonic() + 10.0
        while total < written and time.monotonic() < deadline:
            k = port.in_waiting
            total += len(port.read(min(k, 1 << 16) if k else 1))
        port.close()
    if total != written:
        raise RuntimeError(f"baseline lost bytes: read {total} of {written}")
    return n / elapsed


def _driver_run(seconds: float, rate: float | None) -> dict:
    """The driver reading the stream over a pty for ``seconds``; then it drains and loss is counted."""

    with _Device(rate) as dev:
        drv = BinaryStreamDriver(BinaryStreamCfg(url=dev.link, baudrate=BAUD, channels=CHANNELS), name="bench")
        drv.open()
        dev.go.set()
        t0 = time.perf_counter()
        c0 = time.thread_time()
        while time.perf_counter() - t0 < seconds:
            drv.read(0.05)
        elapsed = time.perf_counter() - t0
        cpu = time.thread_time() - c0
        in_window = drv.bytes_in
        w = dev.finish(lambda: drv.read(0.05))
        deadline = time.monotonic() + 10.0
        while drv.bytes_in < w["bytes"] and time.monotonic() < deadline:
            drv.read(0.05)
        c = drv.counters
        drv.close()
    missing = w["frames"] - c.frames
    return {"seconds": elapsed, "bytes_in_window": in_window, "bytes_per_s": in_window / elapsed,
            "cpu_fraction": cpu / elapsed, "bytes_sent": w["bytes"], "frames_sent": w["frames"],
            "frames_received": c.frames, "lost_frames": c.lost_frames, "checksum_errors": c.checksum_errors,
            "garbage_bytes": c.garbage_bytes, "writer_dropped_bytes": w["dropped_bytes"],
            "lost": max(missing, 0) + c.lost_frames + c.checksum_errors}


def _decode_only(seconds: float) -> float:
    """Bytes/s of driver.decode on an in-memory stream (no I/O): the CPU cost alone."""

    drv = BinaryStreamDriver(BinaryStreamCfg(url="loop://", channels=CHANNELS), name="decode-only")
    data = make_frames(0, 1 << 16)  # one full turn of the 16-bit sequence, so repeating it leaves no gap
    chunks = [data[i:i + 4096] for i in range(0, len(data), 4096)]
    n = 0
    t0 = time.perf_counter()
    while True:
        for chunk in chunks:
            drv.decode(chunk, 0.0)
        n += len(data)
        elapsed = time.perf_counter() - t0
        if elapsed >= seconds:
            break
    if drv.counters.lost_frames or drv.counters.checksum_errors or drv.counters.garbage_bytes:
        raise RuntimeError("decode-only stream is broken")
    return n / elapsed


def bench_serial(seconds: float = 3.0) -> dict:
    """Driver decode rate over a real pty vs raw pyserial reads and the 921600-baud line rate, plus loss."""
    part = seconds / 3.0
    decode_only = _decode_only(min(part, 1.0))
    baseline = _raw_reads(part)
    fast = _driver_run(part, None)
    paced = _driver_run(part, LINE_RATE)
    return {
        "bytes_per_s": fast["bytes_per_s"],
        "frames_per_s": fast["bytes_per_s"] / FRAME_BYTES,
        "lost": fast["lost"] + paced["lost"],
        "line_rate_bytes_per_s": LINE_RATE,
        "ratio": fast["bytes_per_s"] / LINE_RATE,
        "baseline_bytes_per_s": baseline,
        "decode_only_bytes_per_s": decode_only,
        "vs_baseline": fast["bytes_per_s"] / baseline,
        "frame_bytes": FRAME_BYTES,
        "channels": N_CHANNELS,
        "flat_out": fast,
        "at_line_rate": paced,
    }


def format_serial(result: dict) -> str:
    """Human-readable lines: the figure, its baseline and the line rate, side by side."""
    r = result
    p = r["at_line_rate"]
    lines = [
        f"serial stream, {r['channels']} channels, {r['frame_bytes']}-byte frames, over a real pty",
        f"  driver (read + decode + Samples), writer flat out: {r['bytes_per_s'] / 1e6:8.2f} MB/s "
        f"({r['frames_per_s']:,.0f} frames/s), {r['ratio']:.0f}x the line rate",
        f"  baseline: raw pyserial reads, no decoding:         {r['baseline_bytes_per_s'] / 1e6:8.2f} MB/s",
        f"  decode only (in memory):                           {r['decode_only_bytes_per_s'] / 1e6:8.2f} MB/s",
        f"  line rate 921600 baud 8N1:                         {r['line_rate_bytes_per_s'] / 1e6:8.3f} MB/s",
        f"  fed at the line rate for {p['seconds']:.1f} s: {p['frames_received']}/{p['frames_sent']} frames, "
        f"lost {p['lost']}, driver CPU {100 * p['cpu_fraction']:.1f} % of one core",
        f"  lost (all runs): {r['lost']}",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    res = bench_serial()
    print(format_serial(res))
    print(json.dumps(res, indent=1))
