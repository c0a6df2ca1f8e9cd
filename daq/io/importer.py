"""``daq import``: a lab's file (interchange CSV, TDMS, MATLAB, any text) -> the recorder's HDF5 run format;
and back to CSV.

Why: analysis reads one format. An imported file becomes a run file (``friction-daq run 1``)
with one stream, ``import``, holding the file's columns; times are kept as they are in the
file (``start_host_time = 0``), so ``read_h5`` gives back the same ``t``. The rig's config
is stored with it, as for a recording, and an ``import`` event names the source file.

Accepted input (SPEC "Measurement interchange"): columns named as the interchange
channels, SI units, ``t`` in seconds. A CSV header may carry a unit in brackets
(``x1 [m]``); a TDMS channel may carry ``unit_string``. A unit that is not the channel's SI
unit is refused (we do not convert silently). TDMS: the channels in one group, with a
``t`` channel or waveform timing (``wf_start_offset``, ``wf_increment``).

Any other file (MATLAB ``.mat`` v5 or v7.3, ``.tsv``/``.txt``/``.dat``, or a CSV or TDMS with its own names)
goes through ``--map CHANNEL=EXPR`` (arithmetic over the file's variables, ``daq/io/expressions.py``) and
``--time EXPR`` or ``--rate HZ``. The maps, the time and the source are stored in the run's attributes;
the file's other vectors are kept as channels too (``/`` in a name becomes ``.``; a name a map took is
kept as ``file.NAME``). A mapped channel is in SI units by contract: the expression does the conversion.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from daq.config import RigConfig, load_rig
from daq.errors import InputError
from daq.io.runfile import RunWriter

from .expressions import Expression
from .interchange import STREAM_RESERVED, atomic_path, read_csv, read_recording, write_csv
from .plausible import check_values
from .sources import SourceFile, open_tdms, read_source, split_header
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
    tf = open_tdms(path)
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
        if not channel_name_ok(name):
            field = (name if name.isprintable() else repr(name)) if name else "(empty)"
            raise InputError(src, field, "column name cannot be stored as a channel")
        spec = cfg.channels.get(name)
        if spec is not None and not is_si(unit, spec.unit):
            raise InputError(src, name, f"unit {unit!r} is not the SI unit {spec.unit!r} of the interchange "
                                        "(convert before importing)")
        channels.append(name)
        units.append(spec.unit if spec is not None else (unit or ""))
    return channels, units


def channel_name_ok(name: str) -> bool:
    """A name HDF5 stores as a dataset name (no '/', no NUL or other control character) and not reserved."""
    return (bool(name) and name.isprintable() and "/" not in name and name not in (".", "..", "t")
            and name not in STREAM_RESERVED)


def parse_maps(maps: list[str], src: SourceFile) -> dict[str, Expression]:
    """``CHANNEL=EXPR`` strings -> parsed expressions; one InputError naming the ``--map`` on a bad one."""
    out: dict[str, Expression] = {}
    names = [*src.variables, *src.scalars]
    for text in maps:
        channel, eq, expr = text.partition("=")
        channel = channel.strip()
        where = f"--map {channel or text}"
        if not eq:
            raise InputError(src.source, where, f"expected CHANNEL=EXPR, got {text!r}")
        if not channel_name_ok(channel):
            raise InputError(src.source, where, f"{channel!r} cannot be a channel name")
        if channel in out:
            raise InputError(src.source, where, "mapped twice")
        out[channel] = Expression.parse(expr, names, src.source, where)
    return out


def default_time(src: SourceFile) -> str | None:
    """The file's time variable when it has an obvious one: ``t``, ``time``, or one ``…/t``, ``….time``."""
    for want in ("t", "time"):
        hits = [n for n in src.variables if re.split(r"[./]", n)[-1].casefold() == want]
        if len(hits) == 1:
            return hits[0]
    return None


def mapped_table(src: SourceFile, cfg: RigConfig, maps: list[str], time: str | None,
                 rate: float | None) -> tuple[Table, dict[str, object]]:
    """The file's variables -> the interchange columns of ``cfg``'s rig, and the attributes that say how."""
    n = src.sample_count()
    env: dict[str, np.ndarray | float] = {**src.scalars, **{k: v for k, v in src.variables.items() if v.size == n}}
    if time is not None and rate is not None:
        raise InputError(src.source, "--time/--rate", "give one of --time and --rate, not both")
    if rate is not None:
        if not rate > 0:
            raise InputError(src.source, "--rate", f"must be > 0 Hz, got {rate}")
        t, how = np.arange(n) / rate, f"{rate:g} Hz from sample 0"
    else:
        if time is None:
            time = default_time(src)
        if time is None and src.waveform_t is not None and src.waveform_t.size == n:
            t, how = src.waveform_t, "TDMS waveform timing"
        elif time is None:
            raise InputError(src.source, "--time", "no time variable t or time in the file: give --time VAR or "
                                                   "--rate HZ")
        else:
            t = Expression.parse(time, list(env), src.source, "--time").evaluate(env, n)
            how = time
            if not is_si(src.units.get(time), "s"):
                raise InputError(src.source, f"--time {time}", f"unit {src.units[time]!r} is not seconds: convert "
                                                               f"in the expression (e.g. --time \"{time}/1000\")")
        if not np.all(np.isfinite(t)) or not np.all(np.diff(t) > 0):
            bad = int(np.argmax(~(np.diff(t) > 0))) + 1 if np.all(np.isfinite(t)) else int(np.argmax(~np.isfinite(t)))
            raise InputError(src.source, f"--time {how}", f"time must be finite and strictly increasing "
                                                          f"(sample {bad}: {t[bad]!r} after {t[max(bad - 1, 0)]!r})")
    exprs = parse_maps(maps, src)
    table = Table(src.source, src.kind, t, None)
    for channel, expr in exprs.items():
        table.columns[channel] = (expr.evaluate(env, n), None)
    kept = []
    for name, values in src.variables.items():
        if values.size != n or name == time:
            continue
        store = name.replace("/", ".")
        if store in table.columns or not channel_name_ok(store):
            store = f"file.{store}"
        if not store.isprintable():
            src.skipped[name] = "name has a control character"
        elif store not in table.columns:
            table.columns[store] = (values, src.units.get(name))
            kept.append(name)
    attrs = {"import_time": how, "import_map": json.dumps({c: e.text for c, e in exprs.items()}),
             "import_kept": json.dumps(kept),
             "import_skipped": json.dumps({**src.skipped, **{k: f"{v.size} samples, the record has {n}"
                                                            for k, v in src.variables.items() if v.size != n}}),
             "import_scalars": json.dumps(src.scalars)}
    return table, attrs


def import_file(path: str | Path, rig: str | Path, out: str | Path, maps: list[str] | None = None,
                time: str | None = None, rate: float | None = None, drop_nonfinite: bool = False) -> Path:
    """Import a file for ``rig`` into a run HDF5 file at ``out``; nothing is written on error.

    An interchange CSV or a TDMS with the interchange's names needs no options; any other file (or any
    file given ``maps``, ``time`` or ``rate``) goes through the mapping. The rig's channels must hold
    plausible, finite samples (daq/io/plausible.py); ``drop_nonfinite`` drops the rows where one does
    not, and each dropped span becomes a ``dropped`` event in the recording."""

    out = Path(out)
    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise InputError(str(out), "-o", "output must end in .h5 or .hdf5")
    cfg = load_rig(rig)
    suffix = Path(path).suffix.lower()
    if maps or time is not None or rate is not None or suffix not in (".csv", ".tdms"):
        source = read_source(path)
        table, extra = mapped_table(source, cfg, list(maps or []), time, rate)
        kind = source.kind
    else:
        table, extra = read_table(path), {}
        kind = table.kind
    channels, units = validate(table, cfg)
    keep, dropped = check_values(table.source, table.t, {c: table.columns[c][0] for c in channels}, cfg,
                                 drop_nonfinite=drop_nonfinite)
    if dropped:
        if keep.sum() < 2:
            raise InputError(table.source, "--drop-nonfinite", f"fewer than two rows left ({int(keep.sum())})")
        table = Table(table.source, table.kind, table.t[keep], table.t_unit,
                      {c: (x[keep], u) for c, (x, u) in table.columns.items()}, table.attrs)
    dt = float(np.median(np.diff(table.t)))
    meta = StreamMeta(stream=IMPORT_STREAM, channels=tuple(channels), units=tuple(units), rig=cfg.rig,
                      source=Path(path).name, rate_hz=1.0 / dt)
    data = np.column_stack([table.columns[c][0] for c in channels])
    block = make_block(meta, 0, table.t, data)
    attrs = {"source": "import", "source_file": str(path), "source_format": kind, **table.attrs, **extra}
    with atomic_path(out) as tmp:
        w = RunWriter().open(tmp, cfg, "", attrs, streams=[(meta, False)], start_host_time=0.0)
        try:
            w.event(BusEvent(kind="import", source="importer", host_time=float(table.t[0]),
                             detail=f"{kind} file {path}: {len(channels)} channels, {table.t.size} samples"))
            for d in dropped:
                w.event(BusEvent(kind="dropped", source="importer", host_time=d.t_start, detail=d.detail(),
                                 count=d.stop - d.start, gap_s=d.t_stop - d.t_start))
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
