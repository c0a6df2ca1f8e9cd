"""The run file: bus blocks and events -> one HDF5 file per run, written in SWMR mode, flushed often.

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

Streams named in ``WriterCfg.root_tables`` (the estimator's ``cycles``: one row per stick–slip
cycle) are written the same way, as a root group (``/cycles``) beside ``/streams`` and ``/events``.

The recorder process (daq/streaming/recorder.py) feeds it from the bus; ``daq import``
(daq/io/importer.py) writes imported files through it too, so both make the same file.

Decision record: docs/decisions/0004-swmr-hdf5-periodic-flush.md.
Library-version bounds (the 1.10 format, nothing newer, for old readers): docs/decisions/0018-hdf5-for-old-readers.md.
"""

from __future__ import annotations

import datetime as _dt
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
from pydantic import ConfigDict, Field

from daq import __version__
from daq.config import RigConfig, config_text
from daq.errors import DaqError
from daq.io.h5recover import recover
from daq.io.interchange import EVENT_DTYPE, FORMAT_RUN, LIBVER_RUN, STREAM_RESERVED, write_event_columns
from daq.io.stream_format import Block, BusEvent, StreamMeta
from daq.strict import Closed

SOFTWARE = f"friction-daq {__version__}"


class WriterCfg(Closed):
    """How often the file is made durable, and how big its chunks are."""

    model_config = ConfigDict(frozen=True)
    flush_s: float = Field(0.25, gt=0.0, le=1.0, description="max seconds between flushes (bounds loss on a crash)")
    max_pending_bytes: int = Field(256 << 20, gt=0, description="flush early when this much is queued")
    chunk_s: float = Field(0.5, gt=0.0, description="a chunk holds about this many seconds of a regular stream")
    min_chunk: int = Field(1024, ge=16)
    max_chunk: int = Field(65536, ge=16, description="elements per chunk (65536 float64 = 512 KiB)")
    event_chunk: int = Field(1024, ge=16)
    root_tables: tuple[str, ...] = Field(("cycles",), description="streams stored as a root group beside /streams "
                                                                   "(one row per event, e.g. stick-slip cycles)")


class BlockRejected(DaqError, ValueError):
    """A well-formed bus message the file cannot hold (bad channel names, a stream that changed shape)."""


def _keep_only_used_metadata(f: h5py.File) -> None:
    """HDF5's metadata cache of a file being written: entries unused for 3 epochs of 10 000 accesses are evicted,
    the cache shrinking down to 128 KiB. Each dataset's header and chunk index stay, used at every flush.

    Why: the event table's strings go to global heap collections that the writer never reads again. The default
    cache (2 MiB at first, shrinking only after an epoch of 50 000 accesses with 99.9 % hits) kept them until it
    was full, ~1.1 kB of the recorder per event: at one ``friction_fit`` event a second the recorder grew
    0.13 MB/min for its first 30 minutes (issue 29's soak). With this its cache holds 0.13 MB and the recorder
    stays flat. 360 datasets flushed 4 times a second took the same CPU time with it as without.
    """
    c = f.id.get_mdc_config()
    c.decr_mode = 2  # H5C_decr__age_out: evict what was not used for epochs_before_eviction epochs
    c.epoch_length = 10_000
    c.epochs_before_eviction = 3
    c.min_size = 128 << 10
    f.id.set_mdc_config(c)


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
        f = h5py.File(self.path, "w", libver=LIBVER_RUN)
        try:
            _keep_only_used_metadata(f)
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
        """Write what is queued and close; the file is then clean (plain h5py opens it). Then, outside SWMR
        mode (which cannot add objects), the event table's columns for readers without compound types."""
        if self.f is None:
            return
        try:
            self.flush()
        finally:
            self.f.close()
            self.f = None
        with h5py.File(self.path, "a", libver=LIBVER_RUN, locking=False) as f:
            write_event_columns(f)

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
                self._write_stream(self._parent(name)[name], sink)
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
        self.f = h5py.File(self.path, "a", libver=LIBVER_RUN, locking=False)
        _keep_only_used_metadata(self.f)
        for sink in sinks:
            self._create(sink.meta, sink.has_device_t)
        self.f.swmr_mode = True
        if self.on_new_stream is not None:
            for sink in sinks:
                self.on_new_stream(sink.meta.stream)

    def _parent(self, stream: str) -> h5py.Group:
        """Where a stream's group lives: /streams, or the root for a table stream (``/cycles``).

        Why the root: a cycle table has one row per stick–slip cycle, not samples of a signal;
        beside /streams, readers that take every stream for a signal (export, models) leave it alone.
        """
        assert self.f is not None
        return self.f if stream in self.cfg.root_tables else self.f["streams"]

    def _create(self, meta: StreamMeta, has_device_t: bool) -> None:
        assert self.f is not None
        sink = self._sinks.get(meta.stream)
        if sink is None:
            sink = self._sinks[meta.stream] = _Sink(meta, has_device_t)
        rows = _chunk_rows(meta, self.cfg)
        g = self._parent(meta.stream).create_group(meta.stream)
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


def recover_run(path: str | Path) -> None:
    """A run file whose writer died, made a finished file: the open-for-write flags cleared
    (``h5recover.recover``; plain h5py, MATLAB and Octave then open it) and the event columns written
    (``write_event_columns``). Do not call it on a file that a live writer still has open."""
    recover(path)
    with h5py.File(path, "a", libver=LIBVER_RUN, locking=False) as f:
        write_event_columns(f)
