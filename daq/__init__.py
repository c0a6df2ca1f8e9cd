"""Data acquisition, simulation and friction-model analysis for dry-friction test rigs."""

__version__ = "0.1.0"


def __getattr__(name: str):
    """``daq.open(path)``: a recording from any file we read (``daq.io.frames.open_recording``), then
    ``rec.to_pandas()``, ``rec.events_to_pandas()``, ``rec.to_xarray()``. Looked up lazily: the command line
    imports this package and must not pay for numpy and h5py to print its help."""
    if name == "open":
        from daq.io.frames import open_recording

        return open_recording
    raise AttributeError(f"module 'daq' has no attribute {name!r}")
