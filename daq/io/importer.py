"""``daq import``: interchange CSV and LabVIEW TDMS files -> the recorder's HDF5 run format; and back to CSV.

Why: analysis reads one format. An imported file becomes a run file (``friction-daq run 1``)
with one stream, ``import``, holding the file's columns; times are kept as they are in the
file (``start_host_time = 0``), so ``read_h5`` gives back the same ``t``. The rig's config
is stored with it, as for a recording, and an ``import`` event names the source file.

Accepted input (SPEC "Measurement interchange"): columns named as the interchange
channels, SI units, ``t`` in seconds. A CSV header may carry a unit in brackets
(``x1 [m]``); a TDMS channel may carry ``unit_string``. A unit that is not the channel's SI
unit is refused (we do not convert silently). TDMS: the channels in one group, with a
``t`` channel or waveform timing (``wf_start_offset``, ``wf_increment``).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from nptdms import TdmsFile

from daq.config import RigConfig, load_rig
from daq.errors import InputError
from daq.io.runfile import RunWriter

from .interchange import STREAM_RESERVED, atomic_path, read_csv, read_recording, write_csv
from .stream_format import BusEvent, StreamMeta, make_block

IMPORT_STREAM = "import"

# canonical unit (as in rig_configs) -> accepted spellings, compared case-insensitively without spaces
SI_SPELLINGS: dict[str, set[str]] = {
    "s": {"s", "sec", "second", "seconds"},
    "m": {"m", "meter", "meters", "metre", "metres"},
    "rad": {"rad", "radian", "radians"},
    "m/s": {"m/s", "ms^-1", "ms-1", "m*s^-1", "m.s^-1", "m.s-1", "m/sec"},
    "m/s^2": {"m/s^2", "m/s2", "m/s²", "ms^-2", "ms-2", "m*s^-2", "m.s^-2", "m.s-2"},
    "rad/s": {"rad/s", "rads^-1", "rads-1", "rad*s^-1", "rad.s^-1", "rad.s-1"},
    "N": {"n", "newton", "newtons"},
    "degC": {"degc", "°c", "℃", "c", "celsius", "degcelsius", "deg_c"},
    "count": {"count", "counts", "1", "-", "#"},
}
_HEADER_UNIT = re.compile(r"^\s*([^\[\]()]+?)\s*[\[(]\s*([^\[\]()]*?)\s*[\])]\s*$")


@dataclass
class Table:
    """Columns read from a file before validation: name -> (values, unit as written or None)."""

    source: str
    kind: str  # "csv" or "tdms"
    t: np.ndarray
    t_unit: str | None
    columns: dict[str, tuple[np.ndarray, str | None]] = field(default_factory=dict)
    attrs: dict[str, object] = field(default_factory=dict)


def required_channels(cfg: RigConfig) -> list[str]:
    """The interchange columns a file for this rig must have (SPEC table, minus the optional ones)."""
    if cfg.rig == "brake-2dof":
        return ["x1", "phi", "vb"]
    if cfg.rig == "belt-ndof":
        return [f"x{i + 1}" for i in range(cfg.mechanics.n_masses)] + ["vb"]
    return [c for c in cfg.channels if c != "vb_set"]  # drum-pendulum: every listed channel


def is_si(unit: str | None, canonical: str) -> bool:
    """True if ``unit`` is empty (SI by contract) or a spelling of the channel's SI unit."""
    if unit is None or not unit.strip():
        return True
    u = unit.replace(" ", "").casefold()
    return u == canonical.casefold() or u in SI_SPELLINGS.get(canonical, set())


def split_header(name: str) -> tuple[str, str | None]:
    """``"x1 [m]"`` -> ("x1", "m"); ``"x1"`` -> ("x1", None)."""
    m = _HEADER_UNIT.match(name)
    return (m.group(1), m.group(2)) if m else (name.strip(), None)


def read_csv_table(path: str | Path) -> Table:
    """An interchange CSV (via ``interchange.read_csv``), with any bracketed units split off the header."""
    src = str(path)
    rec = read_csv(path)
    table = Table(src, "csv", rec.t, rec.meta.get("t_unit"))
    cols = {**rec.channels, **{f"truth_{k}": v for k, v in rec.truth.items()}}
    for header, x in cols.items():
        name, unit = split_header(header)
        if name == "t":
            raise InputError(src, header, "duplicate column t")
        if name in table.columns:
            raise InputError(src, header, f"duplicate column {name!r}")
        table.columns[name] = (x, unit)
    return table


def read_tdms_table(path: str | Path) -> Table:
    """A LabVIEW TDMS file: one group of channels named as the interchange columns."""

    src = str(path)
    log = logging.getLogger("nptdms")
    level = log.level
    log.setLevel(logging.ERROR)  # its warnings about damaged segments would break the one-line error contract
    try:
        tf = TdmsFile.read(path)
    except FileNotFoundError as exc:
        raise InputError(src, "(file)", exc.strerror or str(exc)) from None
    except Exception as exc:  # nptdms raises assorted errors on a damaged file
        raise InputError(src, "(file)", f"not a readable TDMS file ({type(exc).__name__}: {exc})") from None
    finally:
        log.setLevel(level)
    groups = [g for g in tf.groups() if g.channels()]
    if not groups:
        raise InputError(src, "(file)", "no TDMS group with channels (not a TDMS file, or empty)")
    if len(groups) > 1:
        names = ", ".join(repr(g.name) for g in groups)
        raise InputError(src, "(group)", f"channels must be in one group, found {len(groups)}: {names}")
    group = groups[0]
    chans = {c.name: c for c in group.channels()}
    data: dict[str, tuple[np.ndarray, str | None]] = {}
    for name, ch in chans.items():
        x = ch[:]
        if not (np.issubdtype(x.dtype, np.number) or x.dtype == np.bool_) or np.iscomplexobj(x):
            raise InputError(src, f"{group.name}/{name}", f"not numeric data (TDMS type {x.dtype})")
        unit = ch.properties.get("unit_string")
        data[name] = (np.asarray(x, dtype=np.float64), None if unit is None else str(unit))
    if "t" in data:
        t, t_unit = data.pop("t")
    else:
        first = next(iter(chans.values()))
        if "wf_increment" not in first.properties:
            raise InputError(src, "t", "no 't' channel and no waveform timing (wf_increment) on the channels")
        try:
            t = np.asarray(first.time_track(), dtype=np.float64)
        except (KeyError, ValueError, TypeError) as exc:
            raise InputError(src, "t", f"bad waveform timing ({exc})") from None
        t_unit = None
        inc = first.properties["wf_increment"]
        for name, ch in chans.items():
            if ch.properties.get("wf_increment", inc) != inc or \
                    ch.properties.get("wf_start_offset", 0.0) != first.properties.get("wf_start_offset", 0.0):
                raise InputError(src, f"{group.name}/{name}", "waveform timing differs from the other channels")
    table = Table(src, "tdms", t, t_unit, attrs={"tdms_group": group.name})
    for name, (x, unit) in data.items():
        if x.shape != t.shape:
            raise InputError(src, f"{group.name}/{name}", f"{x.size} samples, t has {t.size}")
        table.columns[name] = (x, unit)
    return table


def read_table(path: str | Path) -> Table:
    suffix = Path(path).suffix.lower()
    if suffix == ".csv":
        return read_csv_table(path)
    if suffix == ".tdms":
        return read_tdms_table(path)
    raise InputError(str(path), "(file)", "unsupported format for import (use .csv or .tdms)")


def validate(table: Table, cfg: RigConfig) -> tuple[list[str], list[str]]:
    """Check time, required columns and SI units against the rig; return (channels, units) in file order."""
    src, t = table.source, table.t
    if t.ndim != 1 or t.size < 2 or not np.all(np.isfinite(t)) or not np.all(np.diff(t) > 0):
        raise InputError(src, "t", "need at least two samples with finite, strictly increasing t")
    if not is_si(table.t_unit, "s"):
        raise InputError(src, "t", f"unit {table.t_unit!r} is not seconds (the interchange needs SI units)")
    missing = [c for c in required_channels(cfg) if c not in table.columns]
    if missing:
        need = ", ".join(["t", *required_channels(cfg)])
        raise InputError(src, missing[0], f"missing column required for {cfg.rig} (needs {need})")
    channels, units = [], []
    for name, (_, unit) in table.columns.items():
        if not name or "/" in name or name in (".", "..") or name in STREAM_RESERVED:
            raise InputError(src, name or "(empty)", "column name cannot be stored as a channel")
        spec = cfg.channels.get(name)
        if spec is not None and not is_si(unit, spec.unit):
            raise InputError(src, name, f"unit {unit!r} is not the SI unit {spec.unit!r} of the interchange "
                                        "(convert before importing)")
        channels.append(name)
        units.append(spec.unit if spec is not None else (unit or ""))
    return channels, units


def import_file(path: str | Path, rig: str | Path, out: str | Path) -> Path:
    """Import a CSV or TDMS file for ``rig`` into a run HDF5 file at ``out``; nothing is written on error."""

    out = Path(out)
    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise InputError(str(out), "-o", "output must end in .h5 or .hdf5")
    cfg = load_rig(rig)
    table = read_table(path)
    channels, units = validate(table, cfg)
    dt = float(np.median(np.diff(table.t)))
    meta = StreamMeta(stream=IMPORT_STREAM, channels=tuple(channels), units=tuple(units), rig=cfg.rig,
                      source=Path(path).name, rate_hz=1.0 / dt)
    data = np.column_stack([table.columns[c][0] for c in channels])
    block = make_block(meta, 0, table.t, data)
    attrs = {"source": "import", "source_file": str(path), "source_format": table.kind, **table.attrs}
    with atomic_path(out) as tmp:
        w = RunWriter().open(tmp, cfg, "", attrs, streams=[(meta, False)], start_host_time=0.0)
        try:
            w.event(BusEvent(kind="import", source="importer", host_time=float(table.t[0]),
                             detail=f"{table.kind} file {path}: {len(channels)} channels, {table.t.size} samples"))
            w.append(block)
        finally:
            w.close()
    return out


def export_csv(h5_path: str | Path, out_csv: str | Path) -> Path:
    """Any recording (run or simple HDF5, or CSV) as an interchange CSV: t first, then the channels."""
    out_csv = Path(out_csv)
    if out_csv.suffix.lower() != ".csv":
        raise InputError(str(out_csv), "-o", "output must end in .csv")
    write_csv(read_recording(h5_path), out_csv)
    return out_csv
