"""Data acquisition, simulation and friction-model analysis for dry-friction test rigs.

Exports the errors every layer raises (``DaqError``, ``InputError``); the rest is in the subpackages. Here too, as
the one piece every package imports first: ``lazy_exports``, how each package says what it exports (issue 30).
"""

from __future__ import annotations

import importlib
import sys

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing: importing a package costs this file, no more
if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

__version__ = "0.1.0"


def lazy_exports(
    package: str, names: dict[str, list[str]] | None = None, modules: Iterable[str] = ()
) -> tuple[Callable[[str], object], Callable[[], list[str]], list[str]]:
    """``(__getattr__, __dir__, __all__)`` for ``package``: its exports, each imported from its submodule the first
    time it is asked for (PEP 562), so ``import daq.models`` does not pay for numpy, scipy or numba. A package's
    ``__init__.py`` says ``__getattr__, __dir__, __all__ = lazy_exports(__name__, {"session": ["Session"]})``.

    ``names`` maps each submodule to the names exported from it (``"open_recording as open"`` renames); ``modules``
    lists submodules exported as themselves. A function exported under its own module's name is refused: importing
    that submodule anywhere rebinds the package's attribute to the module. A name found is kept in the package's
    namespace, so ``__getattr__`` runs once a name. Decision record: docs/decisions/0012-layout-by-layer.md."""
    table: dict[str, tuple[str, str | None]] = {m: (m, None) for m in modules}  # name -> (submodule, attribute)
    for module, exported in (names or {}).items():
        for entry in exported:
            attr, _, alias = (part.strip() for part in entry.partition(" as "))
            name = alias or attr
            if name in table or name == module:
                raise ValueError(f"{package}: {name!r} exported twice, or under its own module's name")
            table[name] = (module, attr)
    namespace = vars(sys.modules[package])

    def __getattr__(name: str) -> object:
        if name not in table:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module, attr = table[name]
        value = importlib.import_module(f"{package}.{module}")
        if attr is not None:
            value = getattr(value, attr)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(table))

    return __getattr__, __dir__, list(table)


__getattr__, __dir__, __all__ = lazy_exports(__name__, {"errors": ["DaqError", "InputError"]})
