"""Data acquisition, simulation and friction-model analysis for dry-friction test rigs.

Exports the errors every layer raises (``DaqError``, ``InputError``) and, for a notebook, the loop's steps
(``daq.compare``, ``daq.diagnose``, ``daq.propose``); the rest is in the subpackages. Here too, as
the one piece every package imports first: ``lazy_exports``, how each package says what it exports (issue 30), and
the one BLAS kernel set and thread count every machine computes with (``pin_blas_kernel``, ``pin_blas_threads``).
"""

from __future__ import annotations

import importlib
import os
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


# The loop's three steps (daq/api: ``daq.compare``, ``daq.diagnose``, ``daq.propose``) are here for a notebook's
# ``import daq``, the one exception to "a package exports nothing from above it" (tests/test_layering.py): each is
# imported when first used, so ``import daq`` still pays for nothing above this file.
__getattr__, __dir__, __all__ = lazy_exports(
    __name__, {"errors": ["DaqError", "InputError"], "api": ["compare", "diagnose", "propose"]}
)

BLAS_KERNEL = "Haswell"  # OpenBLAS's AVX2 + FMA kernels: every x86-64 CPU of the last ten years runs them


def cpu_flags(cpuinfo: str = "/proc/cpuinfo") -> set[str]:
    """The first CPU's flags as the kernel lists them (x86's ``flags`` line); empty where there is none to read
    (another architecture's cpuinfo has no such line, another system no such file)."""
    try:
        with open(cpuinfo, encoding="ascii", errors="replace") as f:
            return set(next((line for line in f if line.startswith("flags")), "").split())
    except OSError:
        return set()


def pin_blas_kernel(cpuinfo: str = "/proc/cpuinfo") -> str | None:
    """Make numpy's and scipy's OpenBLAS use one kernel set (``OPENBLAS_CORETYPE`` = BLAS_KERNEL) on every x86-64
    CPU that has AVX2 and FMA, unless the environment names one. Returns the kernel set, or None where it is left
    to OpenBLAS (another architecture, an older CPU, numpy already loaded: OpenBLAS reads the variable as it loads).

    Why: OpenBLAS picks its kernels by CPU, and kernels differ in how they round. The same code and data gave
    another proposal on another machine: `daq bench propose` named "decelerate 0.04628 m/s over 10 s" (z 2.56,
    separation 107.9) on the machine of 2026-11-27 and "accelerate 0.002644 -> 0.04628 m/s over 40 s" (z 3.49,
    116.1) on an AVX-512 one the next day, and ``OPENBLAS_CORETYPE=Haswell`` on the second gave the first's result
    exactly. A fit's normal equations go through BLAS, and a proposal or a diagnosis that rests on fits may not
    depend on the machine (as MKL's conditional numerical reproducibility does for MKL). Set before numpy loads:
    this package is imported before numpy by our commands, our processes and the test suite's conftest."""
    if "OPENBLAS_CORETYPE" in os.environ:
        return os.environ["OPENBLAS_CORETYPE"]
    if "numpy" in sys.modules or not {"avx2", "fma"} <= cpu_flags(cpuinfo):
        return None
    os.environ["OPENBLAS_CORETYPE"] = BLAS_KERNEL
    return BLAS_KERNEL


BLAS_THREADS = "1"
# what OpenBLAS reads for its thread count, in its order: a user who names any of them has chosen
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")


def pin_blas_threads() -> str | None:
    """One OpenBLAS thread in each of our processes (``OPENBLAS_NUM_THREADS`` = BLAS_THREADS), unless the environment
    names a count. Returns the count in force, or None where numpy was loaded first (OpenBLAS has started its threads).

    Why, first, the same numbers on every machine: OpenBLAS splits some operations over its threads, one per core by
    default, and a split changes how sums round. The rate-and-state coverage test (`tests/rsf_coverage.py`, 80
    fits a cell) gave other estimates with one thread than with two: every cell's mean biases moved (in the 2nd to
    6th digit) and eight coverage fractions of four cells by one event in 80. More cores would split otherwise again.
    Second, the parallelism is ours, a process a core (the fits' pools, Dask's workers, the daemon's processes): BLAS
    threads on top only spin beside them. Measured 2026-11-29 on the 2-core machine of the suite, `rsf_coverage`'s
    six-seed run: alone 8.2 s either way but 10.1 CPU-s with two threads against 7.8 with one; two runs at once
    13.0 s each with two threads, 8.0-8.2 s with one; in `make test` the rate-and-state file took 81 -> 59 CPU-s.
    The diagnoses' matrices are too small for OpenBLAS to split: a diagnosis gave the same JSON to the bit either
    way. Decision record: docs/decisions/0049-one-blas-thread.md."""
    for name in BLAS_THREAD_VARIABLES:
        if name in os.environ:
            return os.environ[name]
    if "numpy" in sys.modules:
        return None
    os.environ["OPENBLAS_NUM_THREADS"] = BLAS_THREADS
    return BLAS_THREADS


pin_blas_kernel()
pin_blas_threads()
