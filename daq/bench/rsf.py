"""``daq bench rsf [--steps N]``: the rate-and-state reduction over an archive-sized batch of velocity steps.

The case (issue 27's goal: <= 50 ms a step on this machine): N velocity steps (default 10 000) in recordings of
STEPS_PER_FILE steps each, a spring-slider at RATE Hz with white noise, the load point cycling through SPEEDS with
SLIP of travel per plateau; written as HDF5 recordings (as the recorder or `daq import` leaves them), then reduced
by ``analyse_rsf`` with both laws and the stiffness fitted, the files shared among this machine's cores, as
``daq analyse rsf *.h5`` does. Timed: the reduction including reading every file. Baseline in the same run: one
forward simulation of one step's window (the physics cost of one model evaluation), so the ratio says how many
model evaluations a step costs. Correctness is part of the result: the median a, b, Dc against the truth.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from daq.analysis.rsf.analysis import analyse_rsf
from daq.config import config_text, load_rig
from daq.io.interchange import Recording, write_h5
from daq.physics.rsf import simulate

TRUTH = {"mu0": 0.6, "a": 0.010, "b": 0.014, "dc": 10e-6, "kp": 3000.0}  # kp = k/N [1/m], N = 1 N
SPEEDS = (10e-6, 30e-6, 100e-6, 30e-6)  # [m/s], cycled
SLIP = 100e-6  # [m] per plateau: 10 Dc
RISE = 0.01  # [s] each change
RATE = 200.0  # [Hz]
NOISE = 2e-4
STEPS_PER_FILE = 100
GOAL_MS = 50.0


def batch_programme(n_steps: int) -> tuple[np.ndarray, np.ndarray]:
    ts, vs = [0.0], [SPEEDS[0]]
    t = 0.0
    for k in range(n_steps + 1):
        v = SPEEDS[k % len(SPEEDS)]
        if k:
            t += RISE
            ts.append(t)
            vs.append(v)
        t += SLIP / v
        ts.append(t)
        vs.append(v)
    return np.asarray(ts), np.asarray(vs)


def write_batch(folder: Path, n_steps: int, progress=None) -> list[Path]:
    cfg = load_rig("belt-ndof")
    mech = cfg.mechanics.model_copy(update={"n_masses": 1, "stiffness_N_per_m": TRUTH["kp"], "normal_force_N": 1.0,
                                            "driven": "spring"})
    cfg = cfg.model_copy(update={"mechanics": mech})
    rig_text = config_text(cfg)
    paths = []
    n_files = math.ceil(n_steps / STEPS_PER_FILE)
    for k in range(n_files):
        steps = min(STEPS_PER_FILE, n_steps - k * STEPS_PER_FILE)
        rt, rv = batch_programme(steps)
        t = np.arange(0.0, rt[-1], 1.0 / RATE)
        mu, _ = simulate(t, rt, rv, mu0=TRUTH["mu0"], a=TRUTH["a"], b=TRUTH["b"], dc=TRUTH["dc"], kp=TRUTH["kp"],
                         v0=SPEEDS[0], law="aging")
        mu += np.random.default_rng(k).normal(0.0, NOISE, mu.size)
        vb = np.interp(t, rt, rv)
        rec = Recording("belt-ndof", t, {"x1": mu / TRUTH["kp"], "vb": vb, "vb_set": vb},
                        {"x1": "m", "vb": "m/s", "vb_set": "m/s"}, {"rig_config": rig_text})
        path = folder / f"steps-{k:04d}.h5"
        write_h5(rec, path)
        paths.append(path)
        if progress:
            progress(f"wrote {k + 1}/{n_files} recordings")
    return paths


def bench_rsf(steps: int = 10_000, progress=None) -> dict:
    with tempfile.TemporaryDirectory(prefix="daq-bench-rsf-") as tmp:
        paths = write_batch(Path(tmp), steps, progress)
        # baseline: one forward simulation of one step's window (compiled already by write_batch)
        rt, rv = batch_programme(2)
        t = np.arange(rt[1] / 2, rt[5], 1.0 / RATE)
        t0 = time.perf_counter()
        for _ in range(20):
            simulate(t, rt, rv, mu0=TRUTH["mu0"], a=TRUTH["a"], b=TRUTH["b"], dc=TRUTH["dc"], kp=TRUTH["kp"],
                     v0=SPEEDS[0], law="aging", rtol=1e-7)
        base_s = (time.perf_counter() - t0) / 20
        workers = os.cpu_count() or 1
        t0 = time.perf_counter()
        res, _ = analyse_rsf(paths, workers=workers, keep_curves=0,
                             on_file=(lambda k, n, what: progress(f"reduced {k}/{n} recordings")) if progress else None)
        secs = time.perf_counter() - t0
    evs = [ev for f in res.files for ev in f.events]
    est = {p: float(np.median([ev.fits["aging"].model_dump()[key]["value"] for ev in evs]))
           for p, key in (("a", "a"), ("b", "b"), ("dc", "Dc_m"))}
    ok = sum(ev.fits["aging"].ok for ev in evs)
    named = sum(ev.law == "aging" for ev in evs)
    return {
        "benchmark": "rsf",
        "case": f"{len(evs)} velocity steps in {len(paths)} recordings at {RATE:g} Hz, both laws, stiffness fitted, "
                f"{workers} workers",
        "steps": len(evs),
        "seconds": secs,
        "ms_per_step": 1e3 * secs / max(len(evs), 1),
        "goal_ms_per_step": GOAL_MS,
        "baseline_ms": 1e3 * base_s,
        "ratio_to_baseline": secs / max(len(evs), 1) / base_s,
        "fits_ok": ok,
        "aging_named": named,
        "median_estimates": est,
        "truth": {"a": TRUTH["a"], "b": TRUTH["b"], "dc": TRUTH["dc"]},
    }


def format_rsf(r: dict) -> str:
    m, tr = r["median_estimates"], r["truth"]
    return "\n".join([
        f"benchmark rsf: {r['case']}",
        f"  ours        {r['ms_per_step']:8.2f} ms a step ({r['seconds']:.1f} s for {r['steps']} steps; goal "
        f"{r['goal_ms_per_step']:g} ms)",
        f"  baseline    {r['baseline_ms']:8.3f} ms  (one forward simulation of one step's window)",
        f"  ratio       {r['ratio_to_baseline']:8.1f} x the baseline",
        f"  recovered   median a {m['a']:.5f} (truth {tr['a']}), b {m['b']:.5f} ({tr['b']}), Dc {m['dc']:.3e} m "
        f"({tr['dc']}); fits ok {r['fits_ok']}/{r['steps']}; aging named {r['aging_named']}/{r['steps']}",
    ])
