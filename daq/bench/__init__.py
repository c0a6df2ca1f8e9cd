"""Benchmarks (`daq bench NAME`): each prints its figures beside a baseline measured in the same run.

One module per benchmark, found through one registry (:data:`BENCHES`), as python-can finds its
interfaces: a module is imported only when its benchmark is asked for, so `daq --help` does not
pay for numba, zmq and the simulators.

Exports the registry (``BENCHES``) and ``run_bench``; the benchmarks' modules are not exported.

Decision records: docs/decisions/0012-layout-by-layer.md, docs/decisions/0013-benchmarks-beside-same-run-baselines.md.
"""

from __future__ import annotations

import importlib

__all__ = ["BENCHES", "run_bench"]

# name -> (module, benchmark function, report formatter); imported only when asked for
BENCHES: dict[str, tuple[str, str, str]] = {
    "sim": ("daq.bench.sim", "bench_sim", "format_sim"),
    "can": ("daq.bench.can", "bench_can", "format_can"),
    "serial": ("daq.bench.serial", "bench_serial", "format_serial"),
    "estimator": ("daq.bench.estimator", "bench_estimator", "format_estimator"),
    "bus": ("daq.bench.bus", "bench_bus", "format_bus"),
    "diagnose": ("daq.bench.diagnose", "bench_diagnose", "format_diagnose"),
    "web": ("daq.bench.web", "bench_web", "format_web"),
    "rsf": ("daq.bench.rsf", "bench_rsf", "format_rsf"),
    "archive": ("daq.bench.archive", "bench_archive", "format_archive"),
    "propose": ("daq.bench.propose", "bench_propose", "format_propose"),
}


def run_bench(name: str, **options) -> tuple[dict, str]:
    """Run a registered benchmark; returns (JSON-able result, human report). ``options`` (e.g. ``rig``) go to
    the benchmark function; only the ones given are passed, so each benchmark keeps its own defaults."""
    mod_name, fn_name, fmt_name = BENCHES[name]
    mod = importlib.import_module(mod_name)
    result = getattr(mod, fn_name)(**options)
    return result, getattr(mod, fmt_name)(result)
