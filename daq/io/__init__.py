"""Files: the interchange format (CSV, HDF5 runs, TDMS import), the stream format, atomic writes, JSON and PNG output.

Exports (``__all__``) ``open``, the recording's readers and writers, the stream format and the shared writers, each
imported when first used. ``daq.io.open(path)`` is a recording from any file we read (``frames.open_recording``), then
``rec.to_pandas()``, ``rec.events_to_pandas()``, ``rec.to_xarray()``. Lazily: the command line imports this package
(its JSON printer) and must not pay for numpy and h5py to print its help.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "frames": ["open_recording as open"],
        "recording": ["Recording"],
        "interchange": ["read_recording", "write_recording"],
        "importer": ["import_file"],
        "loading": ["load_data"],
        "runfile": ["RunWriter"],
        "stream_format": ["StreamMeta", "Block", "BusEvent"],
        "jsonout": ["print_json"],
        "files": ["atomic_path"],
    },
)
