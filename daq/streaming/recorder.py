"""The crash-safe recorder process: bus blocks and events -> one HDF5 file per run.

A deep-queued subscriber feeds a :class:`daq.io.runfile.RunWriter` (streams under ``/streams``, events in
``/events``, the estimator's stick–slip cycles as the table ``/cycles``; SWMR HDF5, flushed every
0.25 s: a kill -9 loses at most that much, see the writer's docstring and
docs/decisions/0004-swmr-hdf5-periodic-flush.md). Own process, so acquisition and the
estimator never wait for the disk.

Run as a process:
    python -m daq.streaming.recorder --endpoint tcp://127.0.0.1:5560 --rig brake-2dof -o run.h5 [--flush-s 0.25]
stdout: ``ready ENDPOINT PATH`` once subscribed, ``stream NAME`` when a stream's datasets exist;
stderr: one progress line per second; SIGTERM/SIGINT close the file cleanly.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
import threading
import time
from pathlib import Path

import zmq
from pydantic import ConfigDict, Field, ValidationError

from daq.background import BackgroundLoop
from daq.config import load_rig
from daq.errors import InputError
from daq.io.archive import catalog_new_file
from daq.io.runfile import BlockRejected, RunWriter, WriterCfg
from daq.io.stream_format import Block, BusEvent
from daq.strict import Closed

from . import heap
from .bus import BusCfg, Subscriber

MIN_FREE_BYTES = 64 << 20  # > 0.25 s at the 40 MB/s `daq bench bus` writes, plus room to close the file
FREE_CHECK_S = 0.25  # how often free space is read (statvfs: microseconds)


def free_space_refusal(path: Path, min_free: int, pending: int = 0) -> str | None:
    """Why a recording may not (go on) write to ``path``'s filesystem, or None.

    Why a margin: on a full disk h5py printed 4 563 lines of errno 28 over 8 s, status said all was
    well, then the recorder died by SIGSEGV and the file could not be recovered (issue 29). Stopping
    while there is room left closes the file cleanly, with an event saying why.
    """
    where = path
    while not where.is_dir() and where != where.parent:  # the file, or a folder not made yet: its filesystem
        where = where.parent
    free = shutil.disk_usage(where).free - pending
    if free >= min_free:
        return None
    return f"only {free / 1e6:.1f} MB free on the disk of {path} (the margin is {min_free / 1e6:.1f} MB)"


class RecorderCfg(Closed):
    """The recorder process: where it listens and how deep its queue is."""

    model_config = ConfigDict(frozen=True)
    endpoint: str = BusCfg().endpoint
    also: list[str] = Field(default_factory=list, description="more publishers to record (e.g. the estimator's)")
    rcvhwm: int = Field(100_000, ge=1, description="blocks queued before the subscriber drops (deep: never drop)")
    streams: list[str] | None = Field(None, description="stream names to record; None = all")
    name: str = "recorder"
    progress_s: float = Field(1.0, gt=0.0)
    poll_s: float = Field(0.05, gt=0.0, le=0.25, description="receive timeout; also the idle flush tick")
    drain_s: float = Field(2.0, ge=0.0, description="on stop, keep writing what is already queued, this long at most")
    min_free_bytes: int = Field(MIN_FREE_BYTES, ge=0, description="refuse to start, and stop cleanly, below this "
                                                                  "much free space on the file's filesystem")


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
        self.disk_full: str | None = None  # why run() stopped before the disk was full, if it did
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
        next_free = t_start
        while not self._stop.is_set():
            msg = sub.recv(poll)
            if msg is None:
                w.tick()
            else:
                self._handle(msg)
            now = time.monotonic()
            if now >= next_free:
                next_free = now + FREE_CHECK_S
                self.disk_full = free_space_refusal(Path(w.path), self.cfg.min_free_bytes, w._pending_bytes)
                if self.disk_full is not None:  # stop with room left to close the file; no drain
                    w.note("disk_full", f"recording stopped: {self.disk_full}", source=self.cfg.name)
                    return
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
            self.writer.event(_storable(msg))

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


def _storable(ev: BusEvent) -> BusEvent:
    """The event with every NUL written as ``\\x00``: HDF5's variable-length strings cannot hold one, and one
    such event ended the recording ("VLEN strings do not support embedded NULLs", issue 29). The control
    socket refuses a NUL; this covers every other publisher on the bus."""
    texts = {k: getattr(ev, k) for k in ("kind", "source", "detail")}
    if not any("\x00" in v for v in texts.values()):
        return ev
    return ev.model_copy(update={k: v.replace("\x00", "\\x00") for k, v in texts.items()})


def _parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="python -m daq.streaming.recorder", description="record the sample bus to one HDF5 file")
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
    ap.add_argument("--min-free-mb", type=float, default=MIN_FREE_BYTES / 1e6,
                    help="refuse to start, and stop cleanly, below this much free space (MB)")
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
                           drain_s=args.drain_s, min_free_bytes=int(args.min_free_mb * 1e6))
    except ValidationError as exc:
        err = exc.errors()[0]
        raise InputError("recorder", "--" + str(err["loc"][0]).replace("_", "-"), err["msg"]) from None
    low = free_space_refusal(out.parent, rcfg.min_free_bytes)
    if low is not None:
        raise InputError(str(out), "-o", f"cannot record: {low}")
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
            if os.getppid() != args.parent_pid:
                orphaned.set()
                rec.stop()
        BackgroundLoop(watch_parent, "parent-watch", interval=0.5, stop=rec._stop).start()
    heap_stop = threading.Event()
    heap.start(heap_stop)  # resident memory: what the recorder holds, not the high-water mark of its heap
    print(f"ready {args.endpoint} {writer.path}", flush=True)
    rc = 0
    try:
        rec.run(args.duration)
    except Exception as exc:  # a write error (disk full, ...): keep what is on disk, say why, exit non-zero
        _say(f"recorder: stopped by {type(exc).__name__}: {exc}", sys.stderr)
        rc = 1
    if rec.disk_full is not None:
        _say(f"recorder: stopped before the disk was full: {rec.disk_full}; the file is closed and readable",
             sys.stderr)
        rc = 3
    try:
        if orphaned.is_set():
            writer.note("parent_gone", f"process {args.parent_pid} died; file closed")
        writer.note("stop", f"{writer.samples_appended} samples, {rec.sub.stats.lost_blocks} lost blocks",
                    count=rec.sub.stats.lost_blocks)
        writer.close()
        catalog_new_file(writer.path, lambda line: _say(line, sys.stderr))  # never raises: the file is what counts
    except Exception as exc:
        _say(f"recorder: closing failed: {type(exc).__name__}: {exc}", sys.stderr)
        rc = 1
    finally:
        rec.close()
        heap_stop.set()
    _say(f"closed {writer.path} samples={writer.samples_written} lost_blocks={rec.sub.stats.lost_blocks}",
         sys.stderr)
    return rc


if __name__ == "__main__":
    sys.exit(main())
