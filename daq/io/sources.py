"""Files as labs write them, read into named variables: MATLAB (v5 and v7.3), delimited text, TDMS.

Why a second reader beside the interchange's: the interchange CSV is our contract (``t`` first, channel
names, SI units) and its reader refuses anything else, on purpose. A lab's file has its own names, its own
delimiter, perhaps no header, MATLAB's column-major matrices and structs. This module only reads: every
numeric vector becomes a variable under the name the file gives it (struct fields as ``s.field``, a TDMS
channel as ``group/channel``, an n x k matrix as ``name_1`` ... ``name_k``), scalars become constants;
what is not numeric is listed, not guessed. Turning variables into channels is ``daq import --map``
(``daq/io/importer.py``).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
import scipy.io
from nptdms import TdmsFile

from daq.errors import InputError

TEXT_SUFFIXES = (".csv", ".tsv", ".txt", ".dat")
MAT_NUMERIC = {"double", "single", "logical", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32",
               "uint64"}
_UNIT = re.compile(r"^\s*([^\[\]()]+?)\s*[\[(]\s*([^\[\]()]*?)\s*[\])]\s*$")
_MISSING = {"", "nan", "na", "n/a", "-nan"}


@dataclass
class SourceFile:
    """A file's numeric content: 1-D variables, scalar constants, units where the file states them."""

    source: str
    kind: str  # "mat-v5", "mat-v7.3", "text", "tdms"
    variables: dict[str, np.ndarray] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    scalars: dict[str, float] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)  # name -> why it is not a variable
    waveform_t: np.ndarray | None = None  # TDMS waveform timing, when the channels carry it

    def add_array(self, name: str, value: object) -> None:
        """One MATLAB-like value: a number, a vector, an n x k matrix (k columns), or something skipped."""
        arr = np.asarray(value)
        if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == np.bool_):
            self.skipped[name] = f"not numeric ({arr.dtype})"
        elif np.iscomplexobj(arr):
            self.skipped[name] = "complex"
        elif arr.size == 1:
            self.scalars[name] = float(arr.reshape(()))
        elif arr.ndim == 1 or (arr.ndim == 2 and min(arr.shape) == 1):
            self.variables[name] = arr.reshape(-1).astype(np.float64)
        elif arr.ndim == 2:
            cols = arr if arr.shape[0] >= arr.shape[1] else arr.T  # samples along the longer axis
            for j in range(cols.shape[1]):
                self.variables[f"{name}_{j + 1}"] = cols[:, j].astype(np.float64)
        else:
            self.skipped[name] = f"{arr.ndim}-D array"

    def sample_count(self) -> int:
        """The most common vector length: the record's samples (other lengths are kept out of the maps)."""
        if not self.variables:
            raise InputError(self.source, "(file)", "no numeric vectors in the file"
                             + (f" (skipped: {', '.join(self.skipped)})" if self.skipped else ""))
        sizes = [v.size for v in self.variables.values()]
        return max(set(sizes), key=lambda n: (sizes.count(n), n))


def read_source(path: str | Path) -> SourceFile:
    """Dispatch on the suffix; one InputError for an unreadable file or an unsupported format."""
    src, suffix = str(path), Path(path).suffix.lower()
    if not Path(path).exists():
        raise InputError(src, "(file)", "No such file")
    if suffix == ".mat":
        return read_mat_v73(path) if h5py.is_hdf5(path) else read_mat_v5(path)
    if suffix in TEXT_SUFFIXES:
        return read_text(path)
    if suffix == ".tdms":
        return read_tdms(path)
    raise InputError(src, "(file)", f"unsupported format {suffix or '(none)'} (use .mat, .csv, .tsv, .txt, .dat "
                                    "or .tdms)")


def read_mat_v5(path: str | Path) -> SourceFile:
    """MATLAB v4-v7.2 through scipy.io; structs (also nested) flattened as ``s.field``."""
    src = str(path)
    try:
        content = scipy.io.loadmat(path, squeeze_me=True, simplify_cells=True)
    except Exception as exc:  # scipy raises assorted errors on a damaged or foreign file
        raise InputError(src, "(file)", f"not a readable MATLAB file ({type(exc).__name__}: {exc})") from None
    out = SourceFile(src, "mat-v5")

    def walk(prefix: str, value: object) -> None:
        if isinstance(value, dict):
            for key, sub in value.items():
                walk(f"{prefix}.{key}", sub)
        else:
            out.add_array(prefix, value)

    for name, value in content.items():
        if not name.startswith("__"):
            walk(name, value)
    return out


def read_mat_v73(path: str | Path) -> SourceFile:
    """MATLAB v7.3 (HDF5) through h5py: numeric datasets by their MATLAB_class, transposed back (MATLAB
    writes column-major), structs as groups -> ``s.field``; cells, strings and references skipped."""
    src = str(path)
    out = SourceFile(src, "mat-v7.3")
    try:
        with h5py.File(path, "r") as f:
            def walk(prefix: str, group: h5py.Group) -> None:
                for key, item in group.items():
                    if key.startswith("#"):  # '#refs#', '#subsystem#': MATLAB's internals
                        continue
                    name = f"{prefix}.{key}" if prefix else key
                    cls = item.attrs.get("MATLAB_class", b"")
                    cls = cls.decode() if isinstance(cls, bytes) else str(cls)
                    if isinstance(item, h5py.Group):
                        walk(name, item)
                    elif cls and cls not in MAT_NUMERIC:
                        out.skipped[name] = f"MATLAB {cls}"
                    elif item.attrs.get("MATLAB_empty", 0):
                        out.skipped[name] = "empty"
                    else:
                        data = item[()]
                        out.add_array(name, data.T if getattr(data, "ndim", 0) == 2 else data)
            walk("", f)
    except OSError as exc:
        raise InputError(src, "(file)", f"not a readable MATLAB v7.3 file ({exc})") from None
    return out


def split_header(name: str) -> tuple[str, str | None]:
    """``"x1 [m]"`` or ``"x1 (m)"`` -> ("x1", "m"); ``"x1"`` -> ("x1", None)."""
    m = _UNIT.match(name)
    return (m.group(1), m.group(2)) if m else (name.strip(), None)


def _split_line(line: str, delimiter: str | None) -> list[str]:
    return [f.strip().strip('"').strip("'") for f in (line.split(delimiter) if delimiter else line.split())]


def _is_number(text: str) -> bool:
    if text.casefold() in _MISSING:
        return True
    try:
        float(text)
    except ValueError:
        return False
    return True


def _merge_units(fields: list[str], n: int) -> list[str]:
    """Whitespace headers split ``Force (N)`` in two: glue bracketed units back to their name."""
    out: list[str] = []
    for f in fields:
        if out and len(fields) > n and re.fullmatch(r"[\[(][^\[\]()]*[\])]", f):
            out[-1] = f"{out[-1]} {f}"
        else:
            out.append(f)
    return out


def read_text(path: str | Path) -> SourceFile:
    """Delimited text: comma, tab, semicolon or whitespace (sniffed from the first data line); an optional
    header row (names, ``name [unit]`` or ``name (unit)``); ``#`` and ``%`` lines are comments; empty fields
    and NaN are gaps (NaN)."""
    src = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(src, "(file)", f"not a readable text file ({exc})") from None
    lines = [(n, ln) for n, ln in enumerate(text.splitlines(), start=1)
             if ln.strip() and not ln.lstrip().startswith(("#", "%"))]
    if not lines:
        raise InputError(src, "(file)", "no data lines")
    first_data = next((ln for _, ln in lines[1:2]), lines[0][1])
    delimiter = next((d for d in ("\t", ",", ";") if d in first_data), None)
    head = _split_line(lines[0][1], delimiter)
    has_header = not all(_is_number(f) for f in head)
    rows = lines[1:] if has_header else lines
    if not rows:
        raise InputError(src, "(file)", "a header but no data lines")
    width = len(_split_line(rows[0][1], delimiter))
    names = _merge_units(head, width) if has_header else [f"col{j + 1}" for j in range(width)]
    out = SourceFile(src, "text")
    parsed = []
    for j, name in enumerate(names):
        names[j], unit = split_header(name)
        if unit:
            out.units[names[j]] = unit
    dup = next((h for j, h in enumerate(names) if h in names[:j]), None)
    if dup is not None:
        raise InputError(src, dup, "duplicate column")
    for n, line in rows:
        fields = _split_line(line, delimiter)
        if len(fields) != len(names):
            raise InputError(src, f"line {n}", f"{len(fields)} fields, the header has {len(names)}")
        bad = next((j for j, f in enumerate(fields) if not _is_number(f)), None)
        if bad is not None:
            raise InputError(src, f"{names[bad]} (line {n})", f"not a number: {fields[bad]!r}")
        parsed.append([np.nan if f.casefold() in _MISSING else float(f) for f in fields])
    data = np.asarray(parsed, dtype=np.float64)
    for j, name in enumerate(names):
        out.variables[name] = data[:, j]
    return out


def open_tdms(path: str | Path) -> TdmsFile:
    """A TDMS file read whole; one InputError for a missing or damaged one."""
    src = str(path)
    # its warnings about damaged segments would break the one-line error contract; npTDMS's modules have loggers
    # of their own (nptdms.reader, nptdms.tdms_segment, ...) with their own level and handler: quiet each
    logs = [logging.getLogger(name) for name in ["nptdms", *logging.Logger.manager.loggerDict]
            if name == "nptdms" or name.startswith("nptdms.")]
    levels = [log.level for log in logs]
    for log in logs:
        log.setLevel(logging.ERROR)
    try:
        return TdmsFile.read(path)
    except FileNotFoundError as exc:
        raise InputError(src, "(file)", exc.strerror or str(exc)) from None
    except Exception as exc:  # nptdms raises assorted errors on a damaged file
        raise InputError(src, "(file)", f"not a readable TDMS file ({type(exc).__name__}: {exc})") from None
    finally:
        for log, level in zip(logs, levels):
            log.setLevel(level)


def read_tdms(path: str | Path) -> SourceFile:
    """Every numeric channel of every group as ``group/channel``; the waveform timing when it is there."""
    out = SourceFile(str(path), "tdms")
    for group in open_tdms(path).groups():
        for ch in group.channels():
            name = f"{group.name}/{ch.name}"
            out.add_array(name, ch[:])
            unit = ch.properties.get("unit_string")
            if unit:
                out.units[name] = str(unit)
            if out.waveform_t is None and "wf_increment" in ch.properties and name in out.variables:
                out.waveform_t = np.asarray(ch.time_track(), dtype=np.float64)
    return out
