"""`daq warm` (daq/models/fit/warm.py): the kernels compiled once into the on-disk cache, so that a later process loads them
instead of compiling them again beside the others."""

from __future__ import annotations

import os
import subprocess
import sys

PROBE = """
import sys
import daq
from numba.core.registry import CPUDispatcher
from daq.sim import rigs
from daq.models.fit.warm import warm_kernels
warm_kernels()
dispatchers = {id(d): d for d in rigs._rk4_cache.values()}
for name, module in list(sys.modules.items()):
    if name.startswith("daq."):
        dispatchers.update({id(v): v for v in vars(module).values() if isinstance(v, CPUDispatcher)})
ran = [d for d in dispatchers.values() if d.stats.cache_hits or d.stats.cache_misses]
compiled = sorted(d.__name__ for d in ran if d.stats.cache_misses)
print(len(ran), ",".join(compiled) or "-")
"""


def test_after_daq_warm_another_process_compiles_nothing_that_warm_ran():
    env = {**os.environ, "MPLBACKEND": "Agg"}
    warm = subprocess.run([sys.executable, "-m", "daq.cli.main", "warm"], capture_output=True, text=True, env=env,
                          timeout=300)
    assert warm.returncode == 0, warm.stderr
    for part in ("brake-2dof", "drum-pendulum", "belt-ndof", "rate-and-state slider", "kernels compiled or loaded"):
        assert part in warm.stderr, warm.stderr
    probe = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, timeout=300)
    assert probe.returncode == 0, probe.stderr
    ran, compiled = probe.stdout.split()
    # the same warm-up again in a new process: every kernel it runs comes from the cache, none is compiled
    assert int(ran) >= 10 and compiled == "-", probe.stdout
