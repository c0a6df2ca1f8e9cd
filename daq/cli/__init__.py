"""The ``daq`` command line: one module per command group; `main.py` registers every command."""
