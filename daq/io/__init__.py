"""Files: the interchange format (CSV, HDF5 runs, TDMS import), the stream format, atomic writes, JSON and PNG output."""


def __getattr__(name: str):
    """``daq.io.open(path)``: a recording from any file we read (``frames.open_recording``), then
    ``rec.to_pandas()``, ``rec.events_to_pandas()``, ``rec.to_xarray()``. Looked up lazily: the command line
    imports this package (its JSON printer) and must not pay for numpy and h5py to print its help."""
    if name == "open":
        from .frames import open_recording

        return open_recording
    raise AttributeError(f"module 'daq.io' has no attribute {name!r}")
