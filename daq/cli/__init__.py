"""The ``daq`` command line: one module per command group; `main.py` registers every command.

Exports (``__all__``) the module ``main`` (``daq.cli.main:main`` is the ``daq`` script), imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, modules=["main"])
