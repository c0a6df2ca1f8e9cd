"""``daq bench propose``: scoring the next experiment's candidates (issue 26: >= 50 programmes, goal <= 60 s).

The case: 20 s of the brake's seed ramp at 100 Hz (the project's simulator, accel-sign hidden at a weak 0.02), the
seed model as "nothing more" against two rivals, accel-sign and velocity strengthening, each fitted to the record
first (timed apart: that is the diagnosis's cost, not the proposal's). Timed: every programme of the brake's family
for runs of at most 40 s, each scored for every ordered pair of rivals (a predicted record per rival, its held-out
windows fitted for both), the budget unlimited so that all of them are scored, on every core (forked processes). Baseline in the same run
(decision 13): one forward simulation of the longest programme at the same rate, the unit a programme's score is
made of (a score costs a simulation per rival plus two held-out fits per pair).

Decision record: docs/decisions/0013-benchmarks-beside-same-run-baselines.md.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from daq.config import load_rig
from daq.io.interchange import write_recording
from daq.models.candidates import parse_candidate
from daq.models.design import proposal
from daq.models.fit.session import Session
from daq.models.spec import seed_model
from daq.ramps import ramp_table, seed_ramp
from daq.sim.effectset import parse_effect
from daq.sim.run import simulate

RIG = "brake-2dof"
RATE = 100.0
RECORD_S = 20.0
MAX_RUN_S = 40.0  # the proposal may be twice as long as the record
HIDDEN = "accel-sign:amp=0.02"
RIVALS = ("accel-sign", "velocity-strengthening")
GOAL_S = 60.0
MIN_PROGRAMMES = 50


def bench_propose(progress=None) -> dict:
    say = progress or (lambda msg: None)
    cfg = load_rig(RIG)
    ramp = ramp_table(seed_ramp(cfg.drive.V0_m_per_s, cfg.drive.Tmax_s, RECORD_S))
    with tempfile.TemporaryDirectory(prefix="daq-bench-propose-") as tmp:
        path = Path(tmp) / "record.h5"
        write_recording(simulate(cfg, effects=[parse_effect(HIDDEN)], ramp=ramp, duration=RECORD_S, rate=RATE,
                                 seed=7), path)
        model = seed_model(RIG)
        s = Session.open(path, model)
        t0 = time.perf_counter()
        rivals = proposal.rivals_for(s, model, [parse_candidate(c) for c in RIVALS], say)
        fit_s = time.perf_counter() - t0
        v0 = proposal.drive_speed(s)
        prop = proposal.propose(s, rivals, budget_s=1e9, max_run_s=MAX_RUN_S, v0=v0, say=say)
        longest = max((p.programme for p in prop.scored), key=lambda p: p.duration_s)
        b = rivals[0].fitted.problem.builder
        vals = {**b.base_values, **rivals[0].fitted.values}
        sims = []
        for _ in range(5):
            t1 = time.perf_counter()
            simulate(b.config(vals), e=b.effect_vector(vals), ramp=longest.table(), duration=longest.duration_s,
                     rate=RATE, noise=False)
            sims.append(time.perf_counter() - t1)
    one_sim = min(sims)
    n = len(prop.scored)
    return {
        "benchmark": "propose",
        "case": f"{RIG} seed ramp {RECORD_S:g} s at {RATE:g} Hz, {HIDDEN} hidden; rivals: {proposal.NOTHING}, "
                f"{', '.join(RIVALS)} ({len(rivals) * (len(rivals) - 1)} ordered pairs)",
        "programmes_scored": n,
        "family_size": prop.family_size,
        "seconds": prop.seconds,
        "seconds_per_programme": prop.seconds / n,
        "rival_fits_seconds": fit_s,
        "baseline": "one forward simulation of the longest programme at the same rate",
        "baseline_seconds": one_sim,
        "programme_in_simulations": prop.seconds / n / one_sim,
        "proposal": prop.best.programme.name,
        "decides": prop.best.decides,
        "z": prop.best.z,
        "separation": prop.best.separation,
        "cores": os.cpu_count(),
        "target": {"seconds_max": GOAL_S, "programmes_min": MIN_PROGRAMMES},
    }


def format_propose(r: dict) -> str:
    ok = r["seconds"] <= GOAL_S and r["programmes_scored"] >= MIN_PROGRAMMES
    return "\n".join([
        f"benchmark {r['benchmark']}: {r['case']}",
        f"  scored      {r['programmes_scored']} of {r['family_size']} programmes in {r['seconds']:.1f} s "
        f"({r['seconds_per_programme'] * 1e3:.0f} ms each); goal <= {GOAL_S:g} s for >= {MIN_PROGRAMMES}: "
        f"{'met' if ok else 'NOT met'}",
        f"  baseline    one forward simulation of the longest programme: {r['baseline_seconds'] * 1e3:.1f} ms; "
        f"a programme's score costs {r['programme_in_simulations']:.0f} of them",
        f"  untimed     the rivals' fits on the record: {r['rival_fits_seconds']:.1f} s",
        f"  proposal    {r['proposal']}: {'decides' if r['decides'] else 'does not decide'} "
        f"(z {r['z']:.2f}, separation {r['separation']:.1f} noise units)",
    ])
