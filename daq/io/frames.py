"""A recording in one call from Python, as the tables notebooks take: pandas DataFrames and an xarray Dataset.

``open_recording`` reads a run file, a simple HDF5 or an interchange CSV as they are, and any other file
``daq import`` takes (MATLAB, text, TDMS, with ``maps``) through the same import, so a notebook sees exactly what
the command line would store. The views themselves (``rec.to_pandas()``, ``rec.events_to_pandas()``,
``rec.to_xarray()``) live with the ``Recording`` in recording.py, and are imported here for the old paths.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from daq.errors import InputError

from .importer import import_file
from .interchange import read_recording
from .recording import EVENT_COLUMNS, Recording, attributes, events_to_pandas, to_pandas, to_xarray

__all__ = ["EVENT_COLUMNS", "Recording", "attributes", "events_to_pandas", "open_recording", "to_pandas", "to_xarray"]


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
