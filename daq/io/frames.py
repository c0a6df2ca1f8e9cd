"""A recording in one call from Python, as the tables notebooks take: pandas DataFrames and an xarray Dataset.

Why: a researcher's next step after a run is a notebook, and QCoDeS/Bluesky users expect ``to_pandas()`` /
``to_xarray()`` rather than our HDF5 layout. ``open_recording`` reads a run file, a simple HDF5 or an
interchange CSV as they are, and any other file ``daq import`` takes (MATLAB, text, TDMS, with ``maps``)
through the same import, so a notebook sees exactly what the command line would store. Units and the rig
config go into the attributes; events are their own table (they are not samples).

pandas and xarray are optional (``pip install 'friction-daq[notebook]'``): they are imported when a
conversion is asked for, with one clear error when they are missing.
"""

from __future__ import annotations

import importlib
import json
import tempfile
from pathlib import Path
from types import ModuleType

import numpy as np

from daq.errors import InputError

from .importer import import_file
from .interchange import Recording, read_recording

EVENT_COLUMNS = ("t", "host_time", "kind", "source", "detail", "count", "gap_s")


def open_recording(path: str | Path, rig: str | Path | None = None, maps: list[str] | None = None,
                   time: str | None = None, rate: float | None = None) -> Recording:
    """A recording from any file we read: .h5/.hdf5/.csv as they are; other files (.mat, .txt, .tdms, ...)
    or any file with ``maps``/``time``/``rate`` through ``daq import``'s path (``rig`` needed then)."""
    suffix = Path(path).suffix.lower()
    if suffix in (".h5", ".hdf5", ".csv") and not (maps or time is not None or rate is not None):
        return read_recording(path)
    if rig is None:
        raise InputError(str(path), "rig", "importing this file needs the rig (a built-in name or a rig file)")
    with tempfile.TemporaryDirectory(prefix="daq-open-") as tmp:
        out = Path(tmp) / "import.h5"
        import_file(path, rig, out, maps=maps, time=time, rate=rate)
        return read_recording(out)


def _optional(name: str) -> ModuleType:
    try:
        return importlib.import_module(name)
    except ImportError:
        raise InputError(name, "(module)", f"{name} is not installed: pip install 'friction-daq[notebook]'") from None


def _attr_value(v: object) -> object:
    """Attributes both pandas and xarray (and netCDF) keep: numbers and strings; the rest as JSON text."""
    if isinstance(v, (str, int, float, np.integer, np.floating)):
        return v
    try:
        return json.dumps(v, default=str)
    except TypeError:
        return str(v)


def attributes(rec: Recording) -> dict[str, object]:
    attrs = {k: _attr_value(v) for k, v in rec.meta.items()}
    attrs["rig"] = rec.rig or ""
    return attrs


def to_pandas(rec: Recording):
    """The samples as a DataFrame indexed by ``t`` [s], one column per channel (truth columns as
    ``truth_NAME``); ``df.attrs``: ``units`` (channel -> unit) and the recording's attributes (rig config)."""
    pd = _optional("pandas")
    cols = {**rec.channels, **{f"truth_{k}": v for k, v in rec.truth.items()}}
    df = pd.DataFrame(cols, index=pd.Index(np.asarray(rec.t, dtype=float), name="t"))
    df.attrs = {**attributes(rec), "units": {k: rec.units.get(k, "") for k in rec.channels}}
    return df


def events_to_pandas(rec: Recording):
    """The events (ramp steps, interlocks, notes, gaps) as their own table, one row each."""
    pd = _optional("pandas")
    return pd.DataFrame([{c: ev.get(c) for c in EVENT_COLUMNS} for ev in rec.events], columns=list(EVENT_COLUMNS))


def to_xarray(rec: Recording):
    """The samples as a Dataset over ``t`` [s], each channel a variable with its ``units``; the events as
    variables over their own dimension ``event``; the recording's attributes (rig config) on the Dataset."""
    xr = _optional("xarray")
    data = {k: ("t", np.asarray(v, dtype=float), {"units": rec.units.get(k, "")}) for k, v in rec.channels.items()}
    data.update({f"truth_{k}": ("t", np.asarray(v, dtype=float), {"units": rec.units.get(k, "")})
                 for k, v in rec.truth.items()})
    ev = rec.events
    data.update({
        "event_t": ("event", np.array([e.get("t", np.nan) for e in ev], dtype=float), {"units": "s"}),
        "event_kind": ("event", np.array([str(e.get("kind", "")) for e in ev], dtype=str)),
        "event_source": ("event", np.array([str(e.get("source", "")) for e in ev], dtype=str)),
        "event_detail": ("event", np.array([str(e.get("detail", "")) for e in ev], dtype=str)),
    })
    return xr.Dataset(data, coords={"t": ("t", np.asarray(rec.t, dtype=float), {"units": "s"})},
                      attrs=attributes(rec))
