"""The recovery table of issue 5 on our own simulator: each hidden effect, one at a time, in the catalog's form.

The table of issue 13 (data we did not write the catalog for: an independent reference simulator, other
forms, pairs, off-catalog, a rig off its config, judged through `model add` + `compare`) is
tests/recovery_table.py.

    python -m daq.models.diagnosis.recovery [--rate 1000] [--rate 100] [--json table.json]

Cases: accel-sign, stick-time, force-rate, temperature, belt-speed hidden in brake-2dof;
bearing-friction and temperature hidden in drum-pendulum; the seed brake model with
normal-load removed (data with none hidden); and data with no hidden effect on both
rigs (expect: none found). Each case is a fresh simulation with realistic sensor noise
(brake: 45 s seed ramp; drum: 30 s), diagnosed with the default settings. Takes tens
of minutes; the test suite runs a subset (tests/test_diagnose.py).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from daq.config import load_rig
from daq.sim.effectset import parse_effect
from daq.sim.run import simulate

from ..fit.session import Session
from ..spec import remove_effect, seed_model
from .diagnose import diagnose
from .report import diagnosis_json

CASES = [("brake-2dof", e, None) for e in ("accel-sign", "stick-time", "force-rate", "temperature", "belt-speed")] + [
    ("drum-pendulum", "bearing-friction", None), ("drum-pendulum", "temperature", None),
    ("brake-2dof", None, "normal-load"), ("brake-2dof", None, None), ("drum-pendulum", None, None)]


def run_case(rig: str, hidden: str | None, removed: str | None, rate: float, seed: int = 7) -> dict:

    cfg = load_rig(rig)
    rec = simulate(cfg, effects=[parse_effect(hidden)] if hidden else [], rate=rate, seed=seed,
                   duration=45.0 if rig == "brake-2dof" else 30.0)
    model = seed_model(rig)
    if removed:
        model = remove_effect(model, removed)
    t0 = time.perf_counter()
    s = Session(rec, "sim", cfg)
    d = diagnose(s, model)
    j = diagnosis_json(d, s)
    expected = hidden or removed
    fitted = [c for c in j["candidates"] if c["reduction"] is not None]
    top = fitted[0]
    second = fitted[1] if len(fitted) > 1 else {"effect": "-", "reduction": float("nan")}
    ok = (j["missing_effect_found"] and j["best"] == expected and j["final_reduction"] >= 0.7) if expected else \
        not j["missing_effect_found"]
    return {"rig": rig, "hidden": hidden or (f"(seed model without {removed})" if removed else "none"),
            "rate_Hz": rate, "found": j["missing_effect_found"], "ranked_first": top["effect"],
            "reduction": j["final_reduction"] if j["missing_effect_found"] else top["reduction"],
            "consistency_z": top["consistency_z"], "second": second["effect"], "second_reduction": second["reduction"],
            "error": j["error"], "noise_floor": j["noise_floor"], "fitted": top["values"], "pass": bool(ok),
            "sequence": [x["label"] for x in j["sequence"]], "seconds": time.perf_counter() - t0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m daq.models.diagnosis.recovery", description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, action="append")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    rows = []
    print("| rig | hidden | rate | found | ranked first | reduction | z | runner-up | error / floor | pass |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for rate in args.rate or [1000.0, 100.0]:
        for rig, hidden, removed in CASES:
            r = run_case(rig, hidden, removed, rate)
            rows.append(r)
            print(f"| {r['rig']} | {r['hidden']} | {r['rate_Hz']:g} Hz | {r['found']} | {r['ranked_first']} | "
                  f"{r['reduction']:.2f} | {r['consistency_z']:.1f} | {r['second']} ({r['second_reduction']:.2f}) | "
                  f"{r['error']:.3g} / {r['noise_floor']:.3g} | {'yes' if r['pass'] else 'NO'} |", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)
    return 0 if all(r["pass"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
