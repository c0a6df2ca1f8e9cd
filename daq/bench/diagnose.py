"""``daq bench diagnose [--rig RIG]``: a long recording diagnosed against the whole catalog.

The cases (one per rig; realistic sensor noise, the seed model, every catalog candidate screened and the
most promising refitted and scored on held-out windows):

- brake-2dof: the seed ramp stretched to 600 s (V0 = 0.17 m/s, Tmax = 600 s) at 1 kHz = 600 001 samples,
  hidden `stick-time`.
- belt-ndof (issue 14): one mass, 750 000 samples at 2 kHz (a 375 s record), the belt stepping between
  0.2 and 0.1 m/s every 25 s (a velocity-stepping test, so the record holds two regimes), hidden
  `velocity-strengthening` (the belt seed model already carries stick-time, accel-sign and force-rate).

Baseline in the same run: one forward simulation of the whole record (the physics cost of touching every
sample once), so the ratio says how many whole-record simulations a diagnosis costs. Correct recovery is
part of the result (`recovered`), never traded for speed. The windows are an evenly spaced subset (Session's
max_windows); the belt record is compared as block means of 6 samples, one per model step (decision 23:
before it, the belt case did not finish in 47 min; after it, 49.6 s on this 2-core machine, 2026-11-25).
"""

from __future__ import annotations

import time

import numpy as np

from daq.config import load_rig
from daq.errors import InputError
from daq.models.diagnosis.diagnose import diagnose
from daq.models.diagnosis.report import diagnosis_json
from daq.models.fit.session import Session
from daq.models.spec import seed_model
from daq.ramps import ramp_table, seed_ramp
from daq.sim.effectset import parse_effect
from daq.sim.run import simulate

CASES = {  # rig -> duration [s], rate [Hz], goal [s], hidden effect (one the rig's seed model lacks)
    "brake-2dof": (600.0, 1000.0, 10.0, "stick-time"),
    "belt-ndof": (374.9995, 2000.0, 60.0, "velocity-strengthening"),  # 750 000 samples
}
BELT_SPEEDS = (0.2, 0.1)  # [m/s], alternating...
BELT_SEGMENT = 25.0  # ...every this many seconds
BELT_CHANGE = 0.2  # [s] each change (the rig's max_accel is 1 m/s^2)


def belt_steps(duration: float) -> tuple[np.ndarray, np.ndarray]:
    """The velocity-stepping programme of the belt case as a (t, v) table."""
    t, v = [0.0], [BELT_SPEEDS[0]]
    k = 1
    while k * BELT_SEGMENT < duration:
        t += [k * BELT_SEGMENT, k * BELT_SEGMENT + BELT_CHANGE]
        v += [v[-1], BELT_SPEEDS[k % 2]]
        k += 1
    t.append(duration + 1.0)
    v.append(v[-1])
    return np.asarray(t), np.asarray(v)


def bench_diagnose(rig: str = "brake-2dof", progress=None) -> dict:
    if rig not in CASES:
        raise InputError("--rig", rig, f"no diagnose benchmark for this rig (have: {', '.join(CASES)})")
    duration, rate, goal, hidden = CASES[rig]
    cfg = load_rig(rig)
    if rig == "brake-2dof":
        ramp = ramp_table(seed_ramp(cfg.drive.V0_m_per_s, duration))
        drive = f"seed ramp over {duration:g} s"
    else:
        ramp = belt_steps(duration)
        drive = (f"one mass, belt stepping {BELT_SPEEDS[0]:g} <-> {BELT_SPEEDS[1]:g} m/s every {BELT_SEGMENT:g} s, "
                 f"{duration:.0f} s")
    rec = simulate(cfg, effects=[parse_effect(hidden)], ramp=ramp, duration=duration, rate=rate, seed=5)
    t0 = time.perf_counter()
    simulate(cfg, effects=[parse_effect(hidden)], ramp=ramp, duration=duration, rate=rate, seed=6, noise=False)
    base_s = time.perf_counter() - t0
    model = seed_model(rig)
    t0 = time.perf_counter()
    session = Session(rec, "bench", cfg)
    d = diagnose(session, model, progress=progress)
    secs = time.perf_counter() - t0
    j = diagnosis_json(d, session)
    return {
        "benchmark": "diagnose",
        "rig": rig,
        "case": f"{rig}, {drive} at {rate:g} Hz, hidden {hidden}, seed model, whole catalog",
        "samples": int(rec.t.size),
        "seconds": secs,
        "goal_seconds": goal,
        "baseline_seconds": base_s,
        "ratio_to_baseline": secs / base_s,
        "candidates": len(j["candidates"]),
        "windows": j["windows"],
        "recovered": bool(j["missing_effect_found"] and j["best"] == hidden),
        "best": j["best"],
        "reduction": j["final_reduction"],
    }


def format_diagnose(r: dict) -> str:
    w = r["windows"]
    return "\n".join([
        f"benchmark diagnose: {r['case']}",
        f"  ours        {r['seconds']:8.2f} s for {r['samples']} samples, {r['candidates']} candidate effects "
        f"(goal {r['goal_seconds']:g} s)",
        f"  baseline    {r['baseline_seconds']:8.2f} s  (one forward simulation of the whole record)",
        f"  ratio       {r['ratio_to_baseline']:8.1f} x the baseline",
        f"  recovered   {r['recovered']} (best: {r['best']}, {r['reduction']:.0%} of the excess removed); "
        f"windows: {w['fit']} fit + {w['held_out']} held out of {w['length_s']:.3g} s",
    ])
