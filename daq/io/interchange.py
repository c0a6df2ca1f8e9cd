"""The measurement interchange format: CSV (``t`` first, SI units) and HDF5 recordings.

HDF5 layout (readable by h5py, pandas via h5py, and MATLAB's h5read):
    /t                      float64 [s]
    /channels/<name>        float64, attribute ``unit``
    /truth/<name>           simulator ground truth (simulations only)
    root attributes         rig, software, created, source, rig_config (TOML text), ramp, ...
Files are written to a temporary name and renamed, so a failed write leaves nothing behind.
"""

from __future__ import annotations

import csv
import json
import os
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import h5py
import numpy as np

from ..errors import InputError


@dataclass
class Recording:
    rig: str | None
    t: np.ndarray
    channels: dict[str, np.ndarray]
    units: dict[str, str] = field(default_factory=dict)
    meta: dict[str, object] = field(default_factory=dict)
    truth: dict[str, np.ndarray] = field(default_factory=dict)


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


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
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            fh.write(",".join(names) + "\n")
            np.savetxt(fh, data, delimiter=",", fmt="%.9g")


def _attr(v: object) -> object:
    if isinstance(v, (dict, list)):
        return json.dumps(v)
    return v


def write_h5(rec: Recording, path: str | Path) -> None:
    _check_shapes(rec)
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = "friction-daq recording 1"
            if rec.rig:
                f.attrs["rig"] = rec.rig
            for k, v in rec.meta.items():
                f.attrs[k] = _attr(v)
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


def write_recording(rec: Recording, path: str | Path, truth_in_csv: bool = False) -> None:
    suffix = Path(path).suffix.lower()
    if suffix in (".h5", ".hdf5"):
        write_h5(rec, path)
    elif suffix == ".csv":
        write_csv(rec, path, truth=truth_in_csv)
    else:
        raise InputError(str(path), "-o", "output must end in .h5, .hdf5 or .csv")


def read_csv(path: str | Path) -> Recording:
    """Read an interchange CSV: header row, first column ``t`` [s], numbers only."""
    src = str(path)
    try:
        fh = open(path, newline="", encoding="utf-8-sig")  # tolerate the BOM Excel writes
    except OSError as exc:
        raise InputError(src, "(file)", exc.strerror or str(exc)) from None
    with fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if not header:
            raise InputError(src, "(header)", "empty file")
        header = [h.strip() for h in header]
        if header[0] != "t":
            raise InputError(src, "t", f"first column must be 't' [s], found {header[0]!r}")
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
    return Recording(None, data[:, 0], channels, truth=truth)


def _isfloat(x: str) -> bool:
    try:
        float(x)
        return True
    except ValueError:
        return False


def read_h5(path: str | Path) -> Recording:
    src = str(path)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputError(src, "(file)", f"not a readable HDF5 file ({exc})") from None
    with f:
        if "t" not in f or "channels" not in f:
            raise InputError(src, "t" if "t" not in f else "channels", "missing dataset")
        t = f["t"][()]
        channels = {k: d[()] for k, d in f["channels"].items()}
        units = {k: str(d.attrs.get("unit", "")) for k, d in f["channels"].items()}
        truth = {k: d[()] for k, d in f["truth"].items()} if "truth" in f else {}
        meta = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
    return Recording(meta.get("rig"), t, channels, units, meta, truth)


def read_recording(path: str | Path) -> Recording:
    suffix = Path(path).suffix.lower()
    if suffix in (".h5", ".hdf5"):
        return read_h5(path)
    if suffix == ".csv":
        return read_csv(path)
    raise InputError(str(path), "(file)", "unsupported format (use .csv, .h5)")
