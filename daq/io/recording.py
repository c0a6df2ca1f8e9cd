"""A recording in memory (``Recording``) and its notebook views: pandas DataFrames and an xarray Dataset.

Why its own module: interchange.py reads and writes recordings and frames.py opens any file as one (through
``daq import``, which itself writes through interchange.py); the type and its views sit below both, so that
``rec.to_pandas()`` needs neither and no module of daq/io imports one that imports it back
(docs/decisions/0037-no-circles-inside-a-package.md). Import it from here or, as before, from interchange.py.

Why the views: a researcher's next step after a run is a notebook, and QCoDeS/Bluesky users expect
``to_pandas()`` / ``to_xarray()`` rather than our HDF5 layout. Units and the rig config go into the attributes;
events are their own table (they are not samples). pandas and xarray are optional
(``pip install 'friction-daq[notebook]'``): they are imported when a conversion is asked for, with one clear
error when they are missing.
"""

from __future__ import annotations

import importlib
import json
from dataclasses import dataclass, field
from types import ModuleType

import numpy as np

from daq.errors import InputError

EVENT_COLUMNS = ("t", "host_time", "kind", "source", "detail", "count", "gap_s")


@dataclass
class Recording:
    rig: str | None
    t: np.ndarray
    channels: dict[str, np.ndarray]
    units: dict[str, str] = field(default_factory=dict)
    meta: dict[str, object] = field(default_factory=dict)
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    events: list[dict[str, object]] = field(default_factory=list)  # see interchange.events_from_array

    # notebook views (below)
    def to_pandas(self):
        """The samples as a pandas DataFrame indexed by t [s]; units and attributes in ``.attrs``."""
        return to_pandas(self)

    def events_to_pandas(self):
        """The events as their own pandas DataFrame."""
        return events_to_pandas(self)

    def to_xarray(self):
        """The samples (and events, over their own dimension) as an xarray Dataset with units."""
        return to_xarray(self)


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
