"""Benchmarks: each prints its figure beside a baseline measured in the same run.

``sim``: the 45 s brake-2dof seed run at 1 kHz output, after warm-up, against a
plain scipy ``solve_ivp`` (RK45, rtol 1e-6, atol 1e-9) of the very same equation
code run with numba disabled (NUMBA_DISABLE_JIT=1 in a child process), so the
baseline is the same equations in plain Python, not a second copy.

Decision record: docs/decisions/0013-benchmarks-beside-same-run-baselines.md.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np
from scipy.integrate import solve_ivp

from daq.config import load_rig
from daq.physics import brake2dof
from daq.physics.contact import N_AUX
from daq.ramps import ramp_table, seed_ramp
from daq.sim.effectset import effect_vector
from daq.sim.rigs import make_sim
from daq.sim.run import simulate

SEED_DURATION = 45.0
SEED_RATE = 1000.0


def _seed_setup():

    cfg = load_rig("brake-2dof")
    e, _ = effect_vector(cfg)
    sim = make_sim(cfg, e)
    rt, rv = ramp_table(seed_ramp(cfg.drive.V0_m_per_s, cfg.drive.Tmax_s))
    return cfg, sim, rt, rv


def run_kernel(duration: float = SEED_DURATION) -> tuple[float, np.ndarray]:
    """One timed integration of the seed case; returns (seconds, states)."""
    cfg, sim, rt, rv = _seed_setup()
    n_sub = int(round(1.0 / SEED_RATE / cfg.integrator.dt_s))
    h = 1.0 / SEED_RATE / n_sub
    n_out = int(duration * SEED_RATE) + 1
    s0 = sim.initial_state(float(rv[0]))
    t0 = time.perf_counter()
    c = sim.advance(s0, 0.0, h, n_sub, n_out, rt, rv)
    return time.perf_counter() - t0, c.states


def solve_ivp_baseline(duration: float) -> dict:
    """Plain solve_ivp of the same rhs (call with NUMBA_DISABLE_JIT=1)."""


    cfg, sim, rt, rv = _seed_setup()
    s0 = sim.initial_state(float(rv[0]))
    ds = np.empty(s0.size)
    aux = np.empty(N_AUX)
    p, e = sim.p, sim.e

    def fun(t, y):
        brake2dof.rhs(t, y, p, e, rt, rv, ds, aux)
        return ds.copy()

    t_eval = np.arange(int(duration * SEED_RATE) + 1) / SEED_RATE
    t0 = time.perf_counter()
    sol = solve_ivp(fun, (0.0, t_eval[-1]), s0, method="RK45", rtol=1e-6, atol=1e-9, t_eval=t_eval)
    el = time.perf_counter() - t0
    return {"seconds": el, "nfev": int(sol.nfev), "success": bool(sol.success),
            "x1": sol.y[0].tolist(), "duration": duration}


def run_end_to_end() -> float:
    """The whole `simulate()` call: integration, instruments (noise, quantisation, hold), metadata."""

    cfg = load_rig("brake-2dof")
    t0 = time.perf_counter()
    simulate(cfg, duration=SEED_DURATION, rate=SEED_RATE)
    return time.perf_counter() - t0


def bench_sim(repeat: int = 5, baseline_duration: float = SEED_DURATION) -> dict:
    run_kernel(1.0)  # warm-up: compile or load the cache
    run_end_to_end()
    times = [run_kernel()[0] for _ in range(repeat)]
    e2e = min(run_end_to_end() for _ in range(repeat))
    _, states = run_kernel()
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    code = ("import json,sys; from daq.bench.sim import solve_ivp_baseline; "
            f"print(json.dumps(solve_ivp_baseline({baseline_duration!r})))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    base = json.loads(out.stdout.strip().splitlines()[-1])
    base_s = base["seconds"] * SEED_DURATION / base["duration"]  # scaled if run shorter
    x1_ref = np.asarray(base.pop("x1"))
    horizon = int(min(5.0, base["duration"]) * SEED_RATE)
    dev = float(np.max(np.abs(states[:horizon, 0] - x1_ref[:horizon])))
    best = min(times)
    return {
        "benchmark": "sim",
        "case": "brake-2dof seed run, 45 s, 1 kHz output, RK4 dt 0.5 ms",
        "seconds": best,
        "seconds_median": float(np.median(times)),
        "realtime_factor": SEED_DURATION / best,
        "end_to_end_seconds": e2e,
        "baseline": "scipy solve_ivp RK45 rtol=1e-6 atol=1e-9, same equations, numba disabled",
        "baseline_seconds": base_s,
        "baseline_measured_duration_s": base["duration"],
        "baseline_nfev": base["nfev"],
        "speedup_vs_solve_ivp": base_s / best,
        "max_abs_dev_x1_first_5s_m": dev,
        "target": {"seconds_max": 0.045, "realtime_factor_min": 1000, "speedup_min": 100},
    }


def format_sim(r: dict) -> str:
    lines = [f"benchmark {r['benchmark']}: {r['case']}"]
    if r["benchmark"] == "sim":
        lines += [
            f"  ours        {r['seconds'] * 1e3:8.1f} ms  (median {r['seconds_median'] * 1e3:.1f} ms)"
            f"  realtime x{r['realtime_factor']:.0f}",
            f"  + sensors   {r['end_to_end_seconds'] * 1e3:8.1f} ms  (whole simulate(): noise, quantisation, metadata)",
            f"  solve_ivp   {r['baseline_seconds'] * 1e3:8.1f} ms  ({r['baseline_nfev']} rhs calls)",
            f"  ratio       {r['speedup_vs_solve_ivp']:8.1f} x faster than the baseline",
            f"  agreement   max |x1 - x1_solve_ivp| over the first 5 s = {r['max_abs_dev_x1_first_5s_m']:.2e} m",
        ]
    return "\n".join(lines)
