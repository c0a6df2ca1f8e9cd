"""The crash-safe recorder: bus blocks and events -> one HDF5 file per run.

Why this shape: the file is written in HDF5 SWMR mode, so what is on disk is always a
consistent file holding everything up to the last flush; the writer flushes every
``flush_s`` (0.25 s by default), hence a kill -9 loses at most that much plus what was
still in flight. Appends only queue the block (no copy, no HDF5 call); each flush writes
one concatenated array per dataset, so the per-sample cost is a memcpy and a write.

A new stream after the first flush needs new datasets, which SWMR mode does not allow:
the writer closes the file (leaving it clean) and reopens it to add them, a window of
milliseconds in which a kill leaves a file that ``daq.io.interchange.read_h5`` still
opens (or ``daq.io.h5recover.recover`` repairs), and a reader that opens the file just
then sees it as a finished file. Declare streams up front to avoid the reopen.

Run as a process:
    python -m daq.recorder --endpoint tcp://127.0.0.1:5560 --rig brake-2dof -o run.h5 [--flush-s 0.25]
stdout: ``ready ENDPOINT PATH`` once subscribed, ``stream NAME`` when a stream's datasets exist;
stderr: one progress line per second; SIGTERM/SIGINT close the file cleanly.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
import zmq
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from . import __version__
from .bus import BusCfg, Subscriber
from .config import RigConfig, config_text, load_rig
from .errors import InputError
from .io.interchange import EVENT_DTYPE, FORMAT_RUN, STREAM_RESERVED
from .stream import Block, BusEvent, StreamMeta

SOFTWARE = f"friction-daq {__version__}"


class WriterCfg(BaseModel):
    """How often the file is made durable, and how big its chunks are."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    flush_s: float = Field(0.25, gt=0.0, le=1.0, description="max seconds between flushes (bounds loss on a crash)")
    max_pending_bytes: int = Field(256 << 20, gt=0, description="flush early when this much is queued")
    chunk_s: float = Field(0.5, gt=0.0, description="a chunk holds about this many seconds of a regular stream")
    min_chunk: int = Field(1024, ge=16)
    max_chunk: int = Field(65536, ge=16, description="elements per chunk (65536 float64 = 512 KiB)")
    event_chunk: int = Field(1024, ge=16)


class RecorderCfg(BaseModel):
    """The recorder process: where it listens and how deep its queue is."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    endpoint: str = BusCfg().endpoint
    also: list[str] = Field(default_factory=list, description="more publishers to record (e.g. the estimator's)")
    rcvhwm: int = Field(100_000, ge=1, description="blocks queued before the subscriber drops (deep: never drop)")
    streams: list[str] | None = Field(None, description="stream names to record; None = all")
    name: str = "recorder"
    progress_s: float = Field(1.0, gt=0.0)
    poll_s: float = Field(0.05, gt=0.0, le=0.25, description="receive timeout; also the idle flush tick")
    drain_s: float = Field(2.0, ge=0.0, description="on stop, keep writing what is already queued, this long at most")


class BlockRejected(ValueError):
    """A well-formed bus message the file cannot hold (bad channel names, a stream that changed shape)."""


def _chunk_rows(meta: StreamMeta, cfg: WriterCfg) -> int:
    """Chunk length: about chunk_s of the stream, a power of two within [min_chunk, max_chunk]."""
    want = meta.rate_hz * cfg.chunk_s if meta.rate_hz else cfg.max_chunk / 4
    return int(min(cfg.max_chunk, max(cfg.min_chunk, 2 ** math.ceil(math.log2(max(want, 1.0))))))


def check_meta(meta: StreamMeta) -> None:
    """Refuse stream metadata that would not map onto one dataset per channel."""
    if len(meta.units) != len(meta.channels):
        raise BlockRejected(f"{meta.stream}: {len(meta.units)} units for {len(meta.channels)} channels")
    seen: set[str] = set()
    for ch in meta.channels:
        if not ch or "/" in ch or ch in (".", "..") or ch in STREAM_RESERVED:
            raise BlockRejected(f"{meta.stream}: channel name {ch!r} cannot be a dataset")
        if ch in seen:
            raise BlockRejected(f"{meta.stream}: duplicate channel {ch!r}")
        seen.add(ch)


def _same_layout(a: StreamMeta, b: StreamMeta) -> bool:
    return a.channels == b.channels and a.units == b.units and a.dtype == b.dtype


@dataclass
class _Sink:
    """One stream's datasets and the blocks queued for the next flush."""

    meta: StreamMeta
    has_device_t: bool
    rows: int = 0  # rows already written
    pending: list[Block] = field(default_factory=list)
    pending_rows: int = 0
    created: bool = False


class RunWriter:
    """The file side of the recorder: SWMR HDF5, appended in few large writes, flushed by time."""

    def __init__(self, cfg: WriterCfg | None = None) -> None:
        self.cfg = cfg or WriterCfg()
        self.path: Path | None = None
        self.f: h5py.File | None = None
        self.start_host_time = 0.0
        self._sinks: dict[str, _Sink] = {}
        self._events: list[tuple] = []
        self._event_rows = 0
        self._pending_bytes = 0
        self._last_flush = 0.0
        self.samples_written = 0  # values (rows x channels) on disk
        self.samples_appended = 0  # values accepted (on disk or queued)
        self.rows_written = 0
        self.blocks_appended = 0
        self.events_written = 0
        self.flushes = 0
        self.on_new_stream = None  # optional callback(name) once a stream's datasets exist

    # ------------------------------------------------------------------ open / close

    def open(self, path: str | Path, rig_cfg: RigConfig | None, ramp_text: str = "",
             extra_attrs: dict[str, object] | None = None, streams: list[tuple[StreamMeta, bool]] = (),
             start_host_time: float | None = None) -> "RunWriter":
        """Create the file with its attributes and event table, then enter SWMR mode.

        ``streams``: (meta, has_device_t) of streams known in advance; their datasets are made
        now, so their first blocks need no reopen.
        """
        self.path = Path(path)
        self.start_host_time = time.monotonic() if start_host_time is None else float(start_host_time)
        f = h5py.File(self.path, "w", libver="latest")
        try:
            a = f.attrs
            a["format"] = FORMAT_RUN
            a["software"] = SOFTWARE
            a["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")
            a["start_host_time"] = self.start_host_time
            a["rig"] = rig_cfg.rig if rig_cfg is not None else ""
            a["rig_config"] = config_text(rig_cfg) if rig_cfg is not None else ""
            a["ramp"] = ramp_text or ""
            for k, v in (extra_attrs or {}).items():
                a[k] = v
            f.create_dataset("events", shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE,
                             chunks=(self.cfg.event_chunk,))
            f.create_group("streams")
            self.f = f
            for meta, has_device_t in streams:
                check_meta(meta)
                self._create(meta, has_device_t)
            f.swmr_mode = True
        except BaseException:
            f.close()
            self.f = None
            raise
        self._last_flush = time.monotonic()
        return self

    def close(self) -> None:
        """Write what is queued and close; the file is then clean (plain h5py opens it)."""
        if self.f is None:
            return
        try:
            self.flush()
        finally:
            self.f.close()
            self.f = None

    def __enter__(self) -> "RunWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ appends

    def append(self, block: Block) -> None:
        """Queue a block (no copy); flush if flush_s has passed. BlockRejected: the file cannot hold it."""
        meta = block.header.meta
        sink = self._sinks.get(meta.stream)
        if sink is None:
            check_meta(meta)
            sink = self._sinks[meta.stream] = _Sink(meta, block.device_t is not None)
        elif meta is not sink.meta and not _same_layout(meta, sink.meta):
            raise BlockRejected(f"{meta.stream}: channels/units/dtype changed mid-run "
                                f"({list(sink.meta.channels)} -> {list(meta.channels)})")
        n = block.header.n
        if n:
            if (block.device_t is not None) != sink.has_device_t:
                raise BlockRejected(f"{meta.stream}: device_t present in some blocks only")
            sink.pending.append(block)
            sink.pending_rows += n
            self.samples_appended += n * len(meta.channels)
            self._pending_bytes += block.data.nbytes + block.t.nbytes
        self.blocks_appended += 1
        self.tick()

    def event(self, ev: BusEvent) -> None:
        """Queue an event row for the table."""
        self._events.append((ev.host_time, ev.kind, ev.source, ev.detail,
                             -1 if ev.count is None else ev.count, math.nan if ev.gap_s is None else ev.gap_s))
        self.tick()

    def note(self, kind: str, detail: str = "", source: str = "recorder", **kw: object) -> None:
        """An event of the writer's own (start, stop, rejected blocks)."""
        self.event(BusEvent(kind=kind, source=source, host_time=time.monotonic(), detail=detail, **kw))

    def tick(self) -> None:
        """Flush if flush_s has passed or too much is queued; call it when idle too."""
        if self._pending_bytes >= self.cfg.max_pending_bytes or time.monotonic() - self._last_flush >= self.cfg.flush_s:
            self.flush()

    # ------------------------------------------------------------------ the writes

    def flush(self) -> None:
        """Write every queued block and event, then make the file consistent on disk (H5Fflush)."""
        if self.f is None:
            raise RuntimeError("RunWriter is not open")
        new = [s for s in self._sinks.values() if not s.created]
        if new:
            self._add_streams(new)  # reopens: self.f is a new handle
        f = self.f
        for name, sink in self._sinks.items():
            if sink.pending_rows:
                self._write_stream(f["streams"][name], sink)
        if self._events:
            rows = np.array(self._events, dtype=EVENT_DTYPE)
            ds = f["events"]
            ds.resize((self._event_rows + rows.size,))
            ds[self._event_rows:] = rows
            self._event_rows += rows.size
            self.events_written += rows.size
            self._events = []
        f.flush()
        self._pending_bytes = 0
        self._last_flush = time.monotonic()
        self.flushes += 1

    def _write_stream(self, g: h5py.Group, sink: _Sink) -> None:
        blocks, n = sink.pending, sink.pending_rows
        r0, r1 = sink.rows, sink.rows + n
        t = np.concatenate([b.t for b in blocks]) if len(blocks) > 1 else blocks[0].t
        data = np.concatenate([b.data for b in blocks]) if len(blocks) > 1 else blocks[0].data
        cols = np.ascontiguousarray(data.T)  # one transpose: each channel becomes one contiguous write
        for i, ch in enumerate(sink.meta.channels):
            ds = g[ch]
            ds.resize((r1,))
            ds.write_direct(cols[i], dest_sel=np.s_[r0:r1])
        if sink.has_device_t:
            dev = np.concatenate([b.device_t for b in blocks])
            g["device_t"].resize((r1,))
            g["device_t"].write_direct(dev, dest_sel=np.s_[r0:r1])
        g["t"].resize((r1,))  # a crash mid-flush may leave datasets at different lengths: readers cut to the shortest
        g["t"].write_direct(np.ascontiguousarray(t), dest_sel=np.s_[r0:r1])
        sink.rows = r1
        sink.pending = []
        sink.pending_rows = 0
        self.rows_written += n
        self.samples_written += n * len(sink.meta.channels)

    def _add_streams(self, sinks: list[_Sink]) -> None:
        """Create datasets for new streams: leave SWMR mode by closing (clean file), reopen, create, re-enter.

        The reopen ignores HDF5's file lock: a reader that holds the file (a live plot, an
        analysis run on the growing file) must not make the recorder fail. We are the only writer.
        """
        assert self.f is not None and self.path is not None
        self.f.flush()
        self.f.close()
        self.f = h5py.File(self.path, "a", libver="latest", locking=False)
        for sink in sinks:
            self._create(sink.meta, sink.has_device_t)
        self.f.swmr_mode = True
        if self.on_new_stream is not None:
            for sink in sinks:
                self.on_new_stream(sink.meta.stream)

    def _create(self, meta: StreamMeta, has_device_t: bool) -> None:
        assert self.f is not None
        sink = self._sinks.get(meta.stream)
        if sink is None:
            sink = self._sinks[meta.stream] = _Sink(meta, has_device_t)
        rows = _chunk_rows(meta, self.cfg)
        g = self.f["streams"].create_group(meta.stream)
        g.attrs["source"] = meta.source
        g.attrs["rate_hz"] = meta.rate_hz if meta.rate_hz is not None else math.nan
        g.attrs["channels"] = list(meta.channels)
        g.attrs["dtype"] = meta.dtype
        if meta.rig:
            g.attrs["rig"] = meta.rig
        ds = g.create_dataset("t", shape=(0,), maxshape=(None,), dtype="f8", chunks=(rows,))
        ds.attrs["unit"] = "s"
        if has_device_t:
            g.create_dataset("device_t", shape=(0,), maxshape=(None,), dtype="f8", chunks=(rows,)).attrs["unit"] = "s"
        for ch, unit in zip(meta.channels, meta.units):
            d = g.create_dataset(ch, shape=(0,), maxshape=(None,), dtype=meta.dtype, chunks=(rows,))
            d.attrs["unit"] = unit
        sink.created = True


class Recorder:
    """The bus side: one deep-queued subscriber feeding a RunWriter until stopped."""

    def __init__(self, writer: RunWriter, cfg: RecorderCfg | None = None, log=None) -> None:
        self.cfg = cfg or RecorderCfg()
        self.writer = writer
        self.sub = Subscriber(self.cfg.endpoint, streams=self.cfg.streams, events=True,
                              rcvhwm=self.cfg.rcvhwm, name=self.cfg.name)
        for ep in self.cfg.also:
            self.sub.sock.connect(ep)
        self.rejected = 0
        self._stop = threading.Event()
        self._log = log  # callable(str) for the progress lines, or None

    def stop(self) -> None:
        """Ask run() to return after writing what it has; safe from signal handlers and other threads."""
        self._stop.set()

    def run(self, duration: float | None = None) -> None:
        """Receive and record until stop() or ``duration`` seconds; the caller closes the writer.

        After stop() it drains what is already queued (up to ``drain_s``), so a clean stop
        loses nothing that reached the recorder.
        """
        w, sub, poll = self.writer, self.sub, self.cfg.poll_s
        end = None if duration is None else time.monotonic() + duration
        t_start = last_log = time.monotonic()
        next_log = t_start + self.cfg.progress_s
        last_samples = w.samples_written
        while not self._stop.is_set():
            msg = sub.recv(poll)
            if msg is None:
                w.tick()
            else:
                self._handle(msg)
            now = time.monotonic()
            if now >= next_log:
                if self._log is not None:
                    rate = (w.samples_written - last_samples) / (now - last_log)
                    self._log(f"recorder: {now - t_start:7.1f} s  {w.samples_written:>13,d} samples written  "
                              f"{rate / 1e6:7.2f} M/s  lost blocks {sub.stats.lost_blocks}  "
                              f"malformed {sub.stats.malformed}  rejected {self.rejected}")
                last_samples, last_log = w.samples_written, now
                next_log = now + self.cfg.progress_s
            if end is not None and now >= end:
                break
        if self._stop.is_set():
            self._drain()

    def _handle(self, msg: Block | BusEvent) -> None:
        if msg.__class__ is Block:
            try:
                self.writer.append(msg)
            except BlockRejected as exc:
                self.rejected += 1
                self.writer.note("rejected", str(exc)[:500], source=self.cfg.name, count=1)
        else:
            self.writer.event(msg)

    def _drain(self) -> None:
        deadline = time.monotonic() + self.cfg.drain_s
        while time.monotonic() < deadline:
            msg = self.sub.recv(0)
            if msg is None:
                return
            self._handle(msg)
        self.writer.note("stop_truncated", f"queue not empty after {self.cfg.drain_s} s of draining: "
                                           "blocks still queued at stop are not in the file", source=self.cfg.name)

    def close(self) -> None:
        self.sub.close()


def _parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="python -m daq.recorder", description="record the sample bus to one HDF5 file")
    ap.add_argument("--endpoint", default=BusCfg().endpoint, help="the publisher's endpoint")
    ap.add_argument("--also", action="append", default=[], metavar="ENDPOINT",
                    help="also record this publisher (repeatable; e.g. the estimator's endpoint)")
    ap.add_argument("--parent-pid", type=int, default=0,
                    help="close the file and exit once this process is no longer our parent (it died)")
    ap.add_argument("--rig", required=True, help="rig id or config TOML (stored in the file)")
    ap.add_argument("-o", "--output", required=True, help="OUT.h5")
    ap.add_argument("--ramp", help="ramp file that drives this run (its text is stored)")
    ap.add_argument("--flush-s", type=float, default=WriterCfg().flush_s)
    ap.add_argument("--rcvhwm", type=int, default=RecorderCfg().rcvhwm)
    ap.add_argument("--drain-s", type=float, default=RecorderCfg().drain_s,
                    help="on SIGTERM, keep writing what is already queued for at most this long")
    ap.add_argument("--stream", action="append", dest="streams", help="record only this stream (repeatable)")
    ap.add_argument("--duration", type=float, help="stop after S seconds")
    ap.add_argument("--note", action="append", default=[], help="operator note stored as an event (repeatable)")
    ap.add_argument("--force", action="store_true", help="overwrite an existing output file")
    return ap.parse_args(argv)


def _setup(args: argparse.Namespace) -> tuple[RunWriter, Recorder]:
    """Validate everything before creating the file, so bad input leaves nothing behind."""
    out = Path(args.output)
    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise InputError(str(out), "-o", "output must end in .h5 or .hdf5")
    if out.exists() and not args.force:
        raise InputError(str(out), "-o", "exists (use --force to overwrite)")
    try:
        wcfg = WriterCfg(flush_s=args.flush_s)
        rcfg = RecorderCfg(endpoint=args.endpoint, also=args.also, rcvhwm=args.rcvhwm, streams=args.streams,
                           drain_s=args.drain_s)
    except ValidationError as exc:
        err = exc.errors()[0]
        raise InputError("recorder", "--" + str(err["loc"][0]).replace("_", "-"), err["msg"]) from None
    cfg = load_rig(args.rig)
    ramp_text = ""
    if args.ramp:
        try:
            ramp_text = Path(args.ramp).read_text()
        except OSError as exc:
            raise InputError(args.ramp, "(file)", exc.strerror or str(exc)) from None
    writer = RunWriter(wcfg)
    try:
        rec = Recorder(writer, rcfg, log=lambda line: _say(line, sys.stderr))
    except zmq.ZMQError as exc:
        raise InputError(args.endpoint, "--endpoint", str(exc)) from None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        writer.open(out, cfg, ramp_text, {"endpoint": args.endpoint, "recorder_pid": os.getpid()})
    except OSError as exc:
        rec.close()
        raise InputError(str(out), "-o", f"cannot create ({exc})") from None
    writer.on_new_stream = lambda name: _say(f"stream {name}")
    return writer, rec


def _say(line: str, stream=None) -> None:
    """Print, but never let a reader that went away (a killed parent's pipe) stop the recording."""
    try:
        print(line, file=stream or sys.stdout, flush=True)
    except (BrokenPipeError, OSError, ValueError):
        pass


def main(argv: list[str] | None = None) -> int:
    """Record until SIGTERM/SIGINT (or --duration), then close the file cleanly."""
    args = _parse(argv)
    try:
        writer, rec = _setup(args)
    except InputError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: rec.stop())
    signal.signal(signal.SIGINT, lambda *_: rec.stop())
    writer.note("start", f"recording {args.endpoint}")
    for text in args.note:
        writer.note("note", text, source="operator")
    orphaned = threading.Event()
    if args.parent_pid:
        def watch_parent() -> None:
            while not rec._stop.wait(0.5):
                if os.getppid() != args.parent_pid:
                    orphaned.set()
                    rec.stop()
        threading.Thread(target=watch_parent, name="parent-watch", daemon=True).start()
    print(f"ready {args.endpoint} {writer.path}", flush=True)
    rc = 0
    try:
        rec.run(args.duration)
    except Exception as exc:  # a write error (disk full, ...): keep what is on disk, say why, exit non-zero
        _say(f"recorder: stopped by {type(exc).__name__}: {exc}", sys.stderr)
        rc = 1
    try:
        if orphaned.is_set():
            writer.note("parent_gone", f"process {args.parent_pid} died; file closed")
        writer.note("stop", f"{writer.samples_appended} samples, {rec.sub.stats.lost_blocks} lost blocks",
                    count=rec.sub.stats.lost_blocks)
        writer.close()
    except Exception as exc:
        _say(f"recorder: closing failed: {type(exc).__name__}: {exc}", sys.stderr)
        rc = 1
    finally:
        rec.close()
    _say(f"closed {writer.path} samples={writer.samples_written} lost_blocks={rec.sub.stats.lost_blocks}",
         sys.stderr)
    return rc


if __name__ == "__main__":
    sys.exit(main())
