"""The numerical kernels compiled into the on-disk numba cache once, before anything runs them (``daq warm``).

Why: a kernel is compiled by the first process that calls it and written to the cache (daq/physics/__init__.py says
where; a new directory for every edit of the compiled sources). The first run after an edit or a fresh checkout pays
it, and where several processes start at once (the suite's two workers and their forked pools, a daemon with its
simulated bench and estimator, Dask workers) each compiles the same kernels side by side, racing on the cache files
(numba#4807). Compiled once here, in one process, every later process loads them. Measured on the 2-core machine,
2026-11-29: 24 s with an empty cache (the three rigs' integrators and contact tails, the estimator's filters and
inverse dynamics, the rate-and-state slider), 2 s with a full one (decision 48). A user effect is compiled in each
process that fits it (daq/models/user_effects.py) and is not warmed here.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from daq.config import load_rig
from daq.estimation.core import FrictionEstimator
from daq.estimation.rigmodels import rig_model
from daq.physics import rsf
from daq.sim.run import simulate

from ..candidates import candidates_for
from ..spec import seed_model
from .session import Session

RIGS = ("brake-2dof", "drum-pendulum", "belt-ndof")
WARM_S = 2.0  # seconds of a simulated record (at 100 Hz) each rig's kernels are run on


def warm_rig(rig: str) -> None:
    """The kernels a simulation, a fit and the online estimator of ``rig`` run: its integrator, the start states of
    every catalog effect a diagnosis may add (each candidate's model simulated on one window), the estimator's
    filters and inverse dynamics."""
    cfg = load_rig(rig)
    rec = simulate(cfg, duration=WARM_S, rate=100.0, seed=0)
    model = seed_model(rig)
    session = Session(rec, "numba warm-up", cfg)
    window = session.win.select(True)[:1]
    for cand in candidates_for(model):
        problem = session.problem(cand.apply(model, "warm"))
        problem.scaled(dict(problem.builder.base_values), window, None)
    fe = FrictionEstimator(rig_model(cfg), 1000.0)
    n = fe.n_taps + 8
    fe.process(np.arange(n) * 1e-3, np.zeros((len(fe.inputs), n)) + 1e-3)


def warm_rsf() -> None:
    """The rate-and-state slider (daq analyse rsf, the reference for the belt rig's law)."""
    t = np.linspace(0.0, 1.0, 11)
    rsf.simulate(t, np.array([0.0, 1.0]), np.array([1e-5, 1e-5]), mu0=0.6, a=0.01, b=0.015, dc=1e-5, kp=1e3, v0=1e-6)


def warm_kernels(progress: Callable[[str], None] = lambda msg: None) -> dict[str, float]:
    """Every part warmed, in turn; seconds each (an empty cache: compiling; a full one: loading)."""
    seconds: dict[str, float] = {}
    parts: list[tuple[str, Callable[[], None]]] = [(rig, lambda rig=rig: warm_rig(rig)) for rig in RIGS]
    parts.append(("rate-and-state slider", warm_rsf))
    for name, part in parts:
        t0 = time.perf_counter()
        part()
        seconds[name] = time.perf_counter() - t0
        progress(f"{name}: {seconds[name]:.1f} s")
    return seconds
