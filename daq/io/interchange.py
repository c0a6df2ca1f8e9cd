"""The measurement interchange format: CSV (``t`` first, SI units) and HDF5 recordings.

Two HDF5 layouts, both readable by h5py, pandas via h5py, and MATLAB's h5read:

Simple (``format = "friction-daq recording 1"``: simulations, conversions):
    /t                      float64 [s]
    /channels/<name>        float64, attribute ``unit``
    /truth/<name>           simulator ground truth (simulations only)
    /events                 optional event table (as below)
    root attributes         rig, software, created, source, rig_config (TOML text), ramp, ...
Files are written to a temporary name and renamed, so a failed write leaves nothing behind.

Run (``format = "friction-daq run 1"``, written live by ``daq.streaming.recorder``):
    /streams/<stream>/t             float64 host monotonic time [s]
    /streams/<stream>/device_t      float64 device time [s] (if the stream has it)
    /streams/<stream>/<channel>     the stream's dtype, attribute ``unit``
        stream attributes           source, rate_hz (nan if irregular), channels, dtype
    /events                 compound (host_time f8, kind str, source str, detail str,
                            count i8 (-1 = none), gap_s f8 (nan = none))
    /event_columns/<field>  the same table, one dataset per field (strings fixed-length bytes), for
                            readers without compound types (Octave's load); written when a file is finished
    root attributes         format, rig, software, created (UTC ISO), start_host_time,
                            rig_config (TOML), ramp (text, may be empty), ...
``read_h5`` puts every stream's channels on the fastest stream's time base (others
interpolated linearly, NaN outside their span and across their gaps), with ``t`` counted
from ``start_host_time``; a file left unclean by a killed recorder opens without any step.

Both are written with library-version bounds that stop at the HDF5 1.10 format (LIBVER_RUN,
LIBVER_SIMPLE), so HDF5 1.10 readers (Octave 7, many MATLAB releases) decode every object:
docs/decisions/0018-hdf5-for-old-readers.md.
"""

from __future__ import annotations

import csv
import json
import re
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from daq.errors import InputError
from daq.io import h5recover
from daq.io.files import atomic_path
from daq.io.recording import Recording  # its home since decision 37; still importable from here
from daq.signals import clock_line

FORMAT_SIMPLE = "friction-daq recording 1"
FORMAT_RUN = "friction-daq run 1"
STREAM_RESERVED = ("t", "device_t")  # dataset names in a stream group that are not channels
GAP_PERIODS = 5.0  # a slower stream is not interpolated across holes longer than this many sample periods

# Library-version bounds of every file we write (decision 18): nothing newer than the HDF5 1.10 format. Under
# libver="latest" the HDF5 2.0 in h5py stamps a compound datatype (the /events table) with datatype message version 5,
# which HDF5 1.10 cannot decode ("bad version number for datatype message"); under these bounds it is version 3. Run
# files need the 1.10 format itself (SWMR: superblock version 3); simple files keep the oldest format that holds them.
LIBVER_RUN = ("v110", "v110")
LIBVER_SIMPLE = ("earliest", "v110")

EVENT_STR = h5py.string_dtype("utf-8")  # variable-length UTF-8: HDF5 1.10 reads it (the bounds were the problem)
EVENT_DTYPE = np.dtype([("host_time", "f8"), ("kind", EVENT_STR), ("source", EVENT_STR), ("detail", EVENT_STR),
                        ("count", "i8"), ("gap_s", "f8")])
EVENT_FIELDS = ("host_time", "kind", "source", "detail", "count", "gap_s")


def events_to_array(events: list[dict[str, object]]) -> np.ndarray:
    """Event dicts (keys as EVENT_FIELDS; count/gap_s may be None) as rows of the /events table."""
    arr = np.empty(len(events), dtype=EVENT_DTYPE)
    for i, ev in enumerate(events):
        count, gap = ev.get("count"), ev.get("gap_s")
        arr[i] = (float(ev.get("host_time", np.nan)), str(ev.get("kind", "")), str(ev.get("source", "")),
                  str(ev.get("detail", "")), -1 if count is None else int(count), np.nan if gap is None else float(gap))
    return arr


def write_event_columns(f: h5py.File) -> None:
    """``/event_columns``: the /events table once more, one plain dataset per field (strings as fixed-length
    bytes, UTF-8). Why twice: Octave's ``load`` (and MATLAB's of an HDF5 file) skips compound datasets, so
    the table itself is invisible there; these columns load as a struct of vectors and char matrices
    (tests/test_old_readers.py). Written when a file is finished (closed, recovered), from /events."""
    rows = f["events"][()] if "events" in f else np.empty(0, dtype=EVENT_DTYPE)
    if "event_columns" in f:
        del f["event_columns"]
    g = f.create_group("event_columns")
    g.attrs["about"] = "the /events table as columns, for readers without compound types (Octave load)"
    for name in EVENT_FIELDS:
        col = rows[name]
        if col.dtype == object:
            texts = [v if isinstance(v, bytes) else str(v).encode("utf-8") for v in col]
            g.create_dataset(name, data=np.array(texts, dtype=f"S{max([1, *map(len, texts)])}"))
        else:
            g.create_dataset(name, data=col)


def events_from_array(arr: np.ndarray, t0: float = 0.0) -> list[dict[str, object]]:
    """Rows of an /events table as dicts; ``t`` is host_time on the recording's time base (minus ``t0``)."""
    def text(v: object) -> str:
        return v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)

    out: list[dict[str, object]] = []
    for row in arr:
        count, gap = int(row["count"]), float(row["gap_s"])
        out.append({"t": float(row["host_time"]) - t0, "host_time": float(row["host_time"]), "kind": text(row["kind"]),
                    "source": text(row["source"]), "detail": text(row["detail"]),
                    "count": None if count < 0 else count, "gap_s": None if np.isnan(gap) else gap})
    return out




def _check_shapes(rec: Recording) -> None:
    """Refuse a recording whose channels do not match ``t`` sample for sample; it would write a malformed file."""
    n = np.shape(rec.t)
    if len(n) != 1:
        raise ValueError(f"t must be one-dimensional, has shape {n}")
    for group, arrays in (("channels", rec.channels), ("truth", rec.truth)):
        for name, x in arrays.items():
            if np.shape(x) != n:
                raise ValueError(f"{group}/{name} has shape {np.shape(x)}, t has {n}")


def write_csv(rec: Recording, path: str | Path, truth: bool = False) -> None:
    _check_shapes(rec)
    cols = {"t": rec.t, **rec.channels}
    if truth:
        cols.update({f"truth_{k}": v for k, v in rec.truth.items()})
    names = list(cols)
    data = np.column_stack([np.asarray(cols[n], dtype=float) for n in names])
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        fh.write(",".join(names) + "\n")
        np.savetxt(fh, data, delimiter=",", fmt="%.9g")


def _attr(v: object) -> object:
    if isinstance(v, (dict, list)):
        return json.dumps(v)
    return v


def write_h5(rec: Recording, path: str | Path) -> None:
    _check_shapes(rec)
    with atomic_path(path) as tmp, h5py.File(tmp, "w", libver=LIBVER_SIMPLE) as f:
        if rec.rig:
            f.attrs["rig"] = rec.rig
        for k, v in rec.meta.items():
            f.attrs[k] = _attr(v)
        f.attrs["format"] = FORMAT_SIMPLE  # also when rec came from a run file
        ds = f.create_dataset("t", data=rec.t)
        ds.attrs["unit"] = "s"
        g = f.create_group("channels")
        for name, x in rec.channels.items():
            d = g.create_dataset(name, data=np.asarray(x, dtype=float))
            d.attrs["unit"] = rec.units.get(name, "")
        if rec.truth:
            tg = f.create_group("truth")
            for name, x in rec.truth.items():
                tg.create_dataset(name, data=np.asarray(x, dtype=float))
        if rec.events:
            f.create_dataset("events", data=events_to_array(rec.events))
            write_event_columns(f)


def write_recording(rec: Recording, path: str | Path, truth_in_csv: bool = False) -> None:
    suffix = Path(path).suffix.lower()
    if suffix in (".h5", ".hdf5"):
        write_h5(rec, path)
    elif suffix == ".csv":
        write_csv(rec, path, truth=truth_in_csv)
    else:
        raise InputError(str(path), "-o", "output must end in .h5, .hdf5 or .csv")


_T_HEADER = re.compile(r"^t\s*(?:[\[(]\s*([^\[\]()]*?)\s*[\])])?$")


def read_csv(path: str | Path) -> Recording:
    """Read an interchange CSV: header row, first column ``t`` [s], numbers only."""
    src = str(path)
    try:
        fh = open(path, newline="", encoding="utf-8-sig")  # noqa: SIM115 (closed below); utf-8-sig: Excel's BOM
    except OSError as exc:
        raise InputError(src, "(file)", exc.strerror or str(exc)) from None
    try:
        with fh:
            return _parse_csv(src, csv.reader(fh))
    except UnicodeDecodeError as exc:  # a binary file (an HDF5, a MAT file) named .csv
        raise InputError(src, f"(byte {exc.start})", "not a UTF-8 text file; is it a binary file named .csv?") from None
    except csv.Error as exc:  # e.g. a NUL byte
        raise InputError(src, "(file)", f"not a CSV text file: {exc}") from None


def _parse_csv(src: str, reader) -> Recording:
    """An interchange CSV from its rows (read_csv opens the file and turns decoding errors into InputError)."""
    header = next(reader, None)
    if not header:
        raise InputError(src, "(header)", "empty file")
    header = [h.strip() for h in header]
    t_unit = None
    m = _T_HEADER.match(header[0])
    if m is None:
        raise InputError(src, "t", f"first column must be 't' [s], found {header[0]!r}")
    if m.group(1) is not None:  # 't [s]': the unit is checked by the importer
        t_unit = m.group(1).strip()
        header[0] = "t"
    dup = next((h for i, h in enumerate(header) if h in header[:i]), None)
    if dup is not None:
        raise InputError(src, dup, "duplicate column")
    rows = []
    for n, row in enumerate(reader, start=2):
        if not row:
            continue
        if len(row) != len(header):
            raise InputError(src, f"line {n}", f"{len(row)} fields, header has {len(header)}")
        try:
            rows.append([float(x) for x in row])
        except ValueError:
            bad = next(i for i, x in enumerate(row) if not _isfloat(x))
            raise InputError(src, f"{header[bad]} (line {n})", f"not a number: {row[bad]!r}") from None
    data = np.asarray(rows, dtype=float).reshape(-1, len(header))
    if data.shape[0] < 2 or not np.all(np.isfinite(data[:, 0])) or not np.all(np.diff(data[:, 0]) > 0):
        raise InputError(src, "t", "need at least two rows with strictly increasing t")
    channels = {h: data[:, i] for i, h in enumerate(header) if i > 0 and not h.startswith("truth_")}
    truth = {h.removeprefix("truth_"): data[:, i] for i, h in enumerate(header) if h.startswith("truth_")}
    rec = Recording(None, data[:, 0], channels, truth=truth)
    if t_unit is not None:
        rec.meta["t_unit"] = t_unit
    return rec


def _isfloat(x: str) -> bool:
    try:
        float(x)
        return True
    except ValueError:
        return False


def open_h5(path: str | Path) -> h5py.File:
    """Open an HDF5 file for reading, also when a killed (or still running) writer left it marked open.

    Plain open first; then SWMR read mode (what the recorder's files need after kill -9, and
    while it still writes); then a read-only view with the superblock flags cleared (a file
    killed outside SWMR mode). The file itself is never modified.
    """
    src = str(path)
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        first = exc
    try:
        unclean = h5recover.is_unclean(path)
    except InputError:
        unclean = False
    if unclean:
        try:
            return h5py.File(path, "r", swmr=True)
        except OSError:
            pass
        try:
            return h5py.File(h5recover.CleanView(path), "r")
        except (OSError, InputError):
            pass
    raise InputError(src, "(file)", f"not a readable HDF5 file ({first})") from None


def _text_attrs(attrs: h5py.AttributeManager) -> dict[str, object]:
    return {k: (v.decode() if isinstance(v, bytes) else v) for k, v in attrs.items()}


def read_h5(path: str | Path) -> Recording:
    src = str(path)
    f = open_h5(path)
    with f:
        meta = _text_attrs(f.attrs)
        if "streams" in f:
            return _read_run(f, src, meta)
        if "t" not in f or "channels" not in f:
            raise InputError(src, "t" if "t" not in f else "channels", "missing dataset")
        t = f["t"][()]
        channels = {k: d[()] for k, d in f["channels"].items()}
        units = {k: str(d.attrs.get("unit", "")) for k, d in f["channels"].items()}
        truth = {k: d[()] for k, d in f["truth"].items()} if "truth" in f else {}
        t0 = float(meta.get("start_host_time", 0.0))
        events = events_from_array(f["events"][()], t0) if "events" in f else []
    return Recording(meta.get("rig"), t, channels, units, meta, truth, events)


@dataclass
class _Stream:
    """One stream of a run file, read whole and cut to the length all its datasets reached."""

    name: str
    t: np.ndarray
    channels: dict[str, np.ndarray]
    units: dict[str, str]
    info: dict[str, object]

    @property
    def rate(self) -> float:
        span = float(self.t[-1] - self.t[0]) if self.t.size > 1 else 0.0
        return (self.t.size - 1) / span if span > 0 else 0.0


def _stream_channels(g: h5py.Group) -> list[str]:
    names = g.attrs.get("channels")
    if names is None:
        return [k for k in g if k not in STREAM_RESERVED]
    return [n.decode() if isinstance(n, bytes) else str(n) for n in np.atleast_1d(names)]


def _device_time_on_host(device_t: np.ndarray, host_t: np.ndarray, info_rate=None) -> np.ndarray:
    """A device-clocked stream's sample times on the host clock, from one straight line over the run.

    Why: live, the host time of each sample comes from an online clock estimate that steps
    (by up to a few ms) as it learns the offset and drift; at 0.17 m/s belt speed one
    millisecond is 170 um of apparent displacement error. Offline we fit host = a + b*device
    once, under the quickest arrivals, its slope within a clock's tolerance
    (:func:`daq.signals.clock_line`: a delay that grows on a loaded host does not stretch the
    record's time). Falls back to the recorded times when the device clock is not usable (it
    restarted, or too few samples); a clock that restarts mid-run is left to the online times.
    """
    d = np.asarray(device_t, dtype=np.float64)
    h = np.asarray(host_t, dtype=np.float64)
    if d.size < 10 or not np.all(np.isfinite(d)) or not np.all(np.diff(d) > 0):
        return h
    line = clock_line(d, h)
    if not (0.99 < line.free_slope < 1.01):  # not the same seconds: do not trust it
        return h
    return line.host(d)


def _read_stream(name: str, g: h5py.Group, src: str) -> _Stream | None:
    if "t" not in g:
        raise InputError(src, f"streams/{name}/t", "missing dataset")
    chans = [c for c in _stream_channels(g) if c in g]
    # a crash between the writes of one flush can leave the datasets of a stream at different lengths
    n = min([g["t"].shape[0]] + [g[c].shape[0] for c in chans])
    if n == 0 or not chans:
        return None
    t = g["t"][:n]
    if "device_t" in g and g["device_t"].shape[0] >= n:
        t = _device_time_on_host(g["device_t"][:n], t, info_rate=g.attrs.get("rate_hz"))
    data = {c: np.asarray(g[c][:n], dtype=np.float64) for c in chans}
    units = {c: str(g[c].attrs.get("unit", "")) for c in chans}
    info = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in g.attrs.items() if k != "channels"}
    info.update(channels=chans, samples=int(n), device_clock="device_t" in g)
    if not np.all(np.diff(t) >= 0):  # a clock step or restarted source: keep the samples, in time order
        order = np.argsort(t, kind="stable")
        t = t[order]
        data = {c: x[order] for c, x in data.items()}
    return _Stream(name, t, data, units, info)


def _onto(base: np.ndarray, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """x(t) linearly interpolated at ``base``; NaN outside [t0, t_end] and inside holes > GAP_PERIODS periods."""
    if t.size == 1:
        return np.where(base == t[0], x[0], np.nan)
    y = np.interp(base, t, x, left=np.nan, right=np.nan)
    dt = np.diff(t)
    period = float(np.median(dt))
    if period > 0:
        hole = dt > GAP_PERIODS * period
        if hole.any():
            i = np.searchsorted(t, base, side="right") - 1  # interval [t[i], t[i+1]] holding each base time
            inside = (i >= 0) & (i < dt.size)
            in_hole = np.zeros(base.size, dtype=bool)
            in_hole[inside] = hole[i[inside]] & (base[inside] > t[i[inside]])
            y[in_hole] = np.nan
    return y


def _read_run(f: h5py.File, src: str, meta: dict[str, object]) -> Recording:
    """A recorder file as one Recording on the fastest stream's time base."""
    streams = [s for name, g in f["streams"].items() if (s := _read_stream(name, g, src)) is not None]
    if not streams:
        raise InputError(src, "streams", "no samples recorded")
    # the time base: the fastest stream; among streams within 1 % of that rate, a measured one (with a device
    # clock) first. The online estimator publishes one estimate per laser sample, stamped with host times that
    # jitter, and used to win by a hair now and then: every measured channel was then interpolated at jittered
    # instants (noise smoothed, sigma estimated 2x low, timing errors; the demo's diagnosis went wrong on it).
    top = max(s.rate for s in streams)
    streams.sort(key=lambda s: (s.rate < 0.99 * top, not s.info["device_clock"], -s.rate, s.name))
    base = streams[0]
    t0 = float(meta.get("start_host_time", base.t[0]))
    channels: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    for s in streams:
        for c, x in s.channels.items():
            key = c if c not in channels else f"{s.name}.{c}"
            channels[key] = x if s is base else _onto(base.t, s.t, x)
            units[key] = s.units[c]
    meta["streams"] = {s.name: s.info for s in streams}
    meta["time_base"] = base.name
    events = events_from_array(f["events"][()], t0) if "events" in f else []
    return Recording(meta.get("rig") or None, base.t - t0, channels, units, meta, {}, events)


def read_recording(path: str | Path) -> Recording:
    suffix = Path(path).suffix.lower()
    if suffix in (".h5", ".hdf5"):
        return read_h5(path)
    if suffix == ".csv":
        return read_csv(path)
    raise InputError(str(path), "(file)", "unsupported format (use .csv, .h5)")
