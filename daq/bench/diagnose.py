"""``daq bench diagnose``: a 600 000-sample recording diagnosed against the whole catalog.

The case: brake-2dof, the seed ramp stretched to 600 s (V0 = 0.17 m/s, Tmax = 600 s)
at 1 kHz = 600 001 samples with realistic sensor noise and a hidden `stick-time`;
the seed model lacks seven catalog effects, each refitted (two starts, continuation)
and scored on held-out windows. Baseline in the same run: one forward simulation
of the whole record (the physics cost of touching every sample once), so the ratio
says how many whole-record simulations a diagnosis costs. Correct recovery is part
of the result (`recovered`), never traded for speed.
"""

from __future__ import annotations

import time

from daq.config import load_rig
from daq.models.diagnose import diagnose
from daq.models.session import Session
from daq.models.spec import seed_model
from daq.ramps import ramp_table, seed_ramp
from daq.sim.effectset import parse_effect
from daq.sim.run import simulate

DURATION = 600.0
RATE = 1000.0
HIDDEN = "stick-time"


def bench_diagnose() -> dict:

    cfg = load_rig("brake-2dof")
    ramp = ramp_table(seed_ramp(cfg.drive.V0_m_per_s, DURATION))
    rec = simulate(cfg, effects=[parse_effect(HIDDEN)], ramp=ramp, duration=DURATION, rate=RATE, seed=5)
    t0 = time.perf_counter()
    simulate(cfg, effects=[parse_effect(HIDDEN)], ramp=ramp, duration=DURATION, rate=RATE, seed=6, noise=False)
    base_s = time.perf_counter() - t0
    model = seed_model("brake-2dof")
    t0 = time.perf_counter()
    session = Session(rec, "bench", cfg)
    d = diagnose(session, model)
    secs = time.perf_counter() - t0
    j = d.as_json(session)
    return {
        "benchmark": "diagnose",
        "case": f"brake-2dof, seed ramp over {DURATION:g} s at {RATE:g} Hz, hidden {HIDDEN}, seed model, whole catalog",
        "samples": int(rec.t.size),
        "seconds": secs,
        "goal_seconds": 10.0,
        "baseline_seconds": base_s,
        "ratio_to_baseline": secs / base_s,
        "candidates": len(j["candidates"]),
        "windows": j["windows"],
        "recovered": bool(j["missing_effect_found"] and j["best"] == HIDDEN),
        "best": j["best"],
        "reduction": j["candidates"][0]["reduction"] if j["candidates"] else None,
    }


def format_diagnose(r: dict) -> str:
    return "\n".join([
        f"benchmark diagnose: {r['case']}",
        f"  ours        {r['seconds']:8.2f} s for {r['samples']} samples, {r['candidates']} candidate effects "
        f"(goal {r['goal_seconds']:g} s)",
        f"  baseline    {r['baseline_seconds']:8.2f} s  (one forward simulation of the whole record)",
        f"  ratio       {r['ratio_to_baseline']:8.1f} x the baseline",
        f"  recovered   {r['recovered']} (best: {r['best']}, reduction {r['reduction']:.2f}); windows {r['windows']}",
    ])
