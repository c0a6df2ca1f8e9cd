"""Coverage of ``daq analyse rsf``'s standard errors (issue 27): records from the independent implementation
(tests/refsim/rsf.py: plain scipy, the textbook law, the slider's inertia), noise seeds, both laws, both
protocols, 100 Hz and 1 kHz.

    python tests/rsf_coverage.py [--seeds 20] [--json coverage.json]

For each (protocol, law, rate) one noise-free record is written; each seed adds white noise of NOISE and the
reduction fits the true law to every event. Coverage: the fraction of (event, seed) where |estimate - truth| is
within 1 and within 2 standard errors, for a, b and Dc (a Gaussian estimator: 68 % and 95 %). The reduction's
own path (daq.analysis.rsf.analysis.reduce_event), without the file I/O of the CLI (tested elsewhere).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import daq  # noqa: F401, I001 - before numpy: daq pins the BLAS kernels numpy loads (decision 46), as in the suite
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from refsim.rsf import RsfSlider, record, slide_hold_slide, velocity_steps  # noqa: E402

from daq.analysis.rsf.analysis import reduce_event  # noqa: E402
from daq.estimation.rsf_programme import events, load_point_travel, plateaus, programme_table  # noqa: E402

NOISE = 2e-4  # friction units: a press's load cell at ~1/100 of a's effect per e-fold
TRUTH = RsfSlider(a=0.010, b=0.014, dc=20e-6, mu0=0.6, v0=10e-6, k=3000.0, n=1.0, m=0.01)
PROTOCOLS = {
    "velocity steps": lambda: velocity_steps([10e-6, 100e-6, 10e-6, 30e-6, 3e-6], 300e-6),
    "slide-hold-slide": lambda: slide_hold_slide(10e-6, 200e-6, [3.0, 10.0, 30.0, 100.0]),
}
RATES = (1000.0, 100.0)
LAWS = ("aging", "slip")


def coverage(seeds: int, rates=RATES, protocols=tuple(PROTOCOLS), laws=LAWS) -> list[dict]:
    rows = []
    for proto in protocols:
        rt, rv = PROTOCOLS[proto]()
        for law in laws:
            truth = RsfSlider(**{**TRUTH.__dict__, "law": law})
            for rate in rates:
                t, mu_clean = record(truth, rt, rv, rate)
                vb = np.interp(t, rt, rv)
                plats = plateaus(vb)
                prt, prv = programme_table(t, plats)
                evs = events(t, plats)
                travel = load_point_travel(t, prt, prv)
                z = {"a": [], "b": [], "Dc": []}
                t0 = time.perf_counter()
                failed = 0
                for seed in range(seeds):
                    mu = mu_clean + np.random.default_rng(seed).normal(0.0, NOISE, mu_clean.size)
                    for ev in evs:
                        fit = reduce_event(ev, t, mu, travel, prt, prv, (law,), None)[0][law]
                        if not fit.ok:
                            failed += 1
                            continue
                        z["a"].append((fit.a.value - truth.a) / fit.a.se)
                        z["b"].append((fit.b.value - truth.b) / fit.b.se)
                        z["Dc"].append((fit.Dc_m.value - truth.dc) / fit.Dc_m.se)
                dt = time.perf_counter() - t0
                row = {"protocol": proto, "law": law, "rate_Hz": rate, "events": len(evs), "seeds": seeds,
                       "failed": failed, "ms_per_event": 1e3 * dt / max(seeds * len(evs), 1)}
                for p, zs in z.items():
                    za = np.abs(np.asarray(zs))
                    row[f"{p}_1se"] = float(np.mean(za <= 1.0)) if za.size else 0.0
                    row[f"{p}_2se"] = float(np.mean(za <= 2.0)) if za.size else 0.0
                    row[f"{p}_bias_se"] = float(np.mean(zs)) if za.size else 0.0
                rows.append(row)
                print(f"{proto:17s} {law:5s} {rate:6.0f} Hz: " + "  ".join(
                    f"{p} {row[p + '_1se']:.0%}/{row[p + '_2se']:.0%} (bias {row[p + '_bias_se']:+.2f} se)"
                    for p in z) + f"  {row['ms_per_event']:.0f} ms/event, {failed} failed", file=sys.stderr)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--json")
    a = ap.parse_args()
    rows = coverage(a.seeds)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
