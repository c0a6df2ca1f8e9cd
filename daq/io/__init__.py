"""Files: the interchange format (CSV, HDF5 runs, TDMS import), the stream format, atomic writes, JSON and PNG output."""
