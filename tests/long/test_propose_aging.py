"""Case 1 of issue 26, from the command line: a spring-slider at one constant drive speed with logarithmic aging
hidden (tests/refsim/slider.py, Dieterich's form, which the catalog does not have). At one speed every stick lasts
as long as the last, so aging is only a higher static level: the first record leaves nothing or a tie. The
proposed programme must vary the stick times; run on the reference slider, both records together must name
stick-time and remove >= 70 % of the excess. Tens of minutes on 2 cores (slider fits are slow): `make acceptance`.

The records are interchange CSV (t, x1 = F/k, vb = the driver's programme), as a lab that logs its driver writes.

Passed on 2026-11-27 (24.7 min on 2 cores, another job beside it). First record: nothing named, 1.40 um on a
1.42 um floor. Rivals: stick-time (log) held at 0.05 (1.51 um, not told apart; at the generic 0.1 it is),
velocity strengthening, belt-speed (lag-ripple). Proposal: a constant 2 mm/s (half the speed, sticks twice as
long) for 60 s, predicted to decide stick-time and velocity strengthening; 1 proposed run against a 42-programme
protocol. Both records: stick-time named, margin +1.00 of the excess (5 % bound +0.80), 100 % of it removed, each
record at its floor (1.45 / 1.42 um, 1.47 / 1.42 um). Weaker than it reads: its *form* was named 'saturating' over
'log' (the hidden law) by +0.50 (5 % bound +0.36), which two stick lengths cannot support (the catalog says the
forms are told apart by sticks over two decades); the log form's fit starts at tau 0.05 s, a decade below the
slider's sticks, and likely ends short. What made it pass (before, stick-time was never a rival): start positions
estimated at 500 Hz, held strengths reached in steps, "ruled out" asking what naming asks (decision 36, amended).

Failed on 2026-11-28 (55c1394): the proposal a constant 12 mm/s, and both records together named nothing at 5.94 um
(4.2x the floor). Two faults, both mended on 2026-11-29. The proposal among the programmes deciding the same two
rivals was picked by the separation of a pair no programme decides (belt-speed's, 0.141 against 0.0; 2 mm/s at
92cc41e by the same noise); ``Scored.rank`` now ranks by the pairs decided (decision 36's note). And at 12 or 16 mm/s
the diagnosis never fitted stick-time: the model without it, fitted to both records, made up for the aging with
viscous damping and k_fall, and there stick-time's first-order step pointed below its bound, score 0; it is now
fitted when its score past the bound ranks (decision 15's note).

**Passes on 2026-11-29 (9.9 min on 2 cores, quiet).** First record: nothing named, 1.40 um on a 1.42 um floor. The
proposal: a constant 16 mm/s for 60 s (sticks a quarter as long), deciding stick-time (log) and velocity
strengthening (pairs at 65763 and 2503 noise units), 1 run against a 42-programme protocol. Both records:
stick-time named (saturating form), margin +0.99 over nothing more (5 % bound +0.84), 99 % of the excess removed,
each record at its floor (1.434 / 1.420 um, 1.450 / 1.417 um); its form undecided against the log form (+0.00):
two stick lengths cannot tell them apart, and the diagnosis says so and names the run that would.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np

from daq.cli.main import main as daq
from daq.ramps import load_ramp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/ (for refsim)
from refsim.slider import Slider, simulate as slider_simulate  # noqa: E402

M, K, G = 0.05, 200.0, 9.81
RATE = 500.0
V0 = 4e-3
FIRST_S = 40.0
AGING_B = 0.05


def write_csv(path: Path, rt: np.ndarray, rv: np.ndarray, seed: int) -> Path:
    """The reference slider driven by the programme (t, v), with the gauge's noise and quantiser."""
    t = np.arange(int(rt[-1] * RATE)) / RATE
    e = slider_simulate(Slider(M, K, M * G, b=AGING_B), lambda tt: float(np.interp(tt, rt, rv)), t)
    rng = np.random.default_rng(seed)
    f = np.round((K * e / (M * G) + rng.normal(0, 5e-4, t.size)) / 1e-3) * 1e-3
    np.savetxt(path, np.column_stack([t, f * M * G / K, np.interp(t, rt, rv)]), delimiter=",", header="t,x1,vb",
               comments="", fmt="%.10g")
    return path


def edit_rig(path: Path) -> None:
    """The user's slider, spring, load, driver, gauge rate and noise; their contact model knows no aging."""
    text = path.read_text()
    for old, new in [("mass_kg = 0.5", f"mass_kg = {M}"), ("normal_force_N = 4.905", f"normal_force_N = {M * G}"),
                     ('driven = "belt"', 'driven = "spring"'),
                     ("V0_m_per_s = 0.2", f"V0_m_per_s = {V0}"), ("rate_Hz = 250.0", f"rate_Hz = {RATE}"),
                     ("noise_std = 2e-5\nlsb = 1e-5", f"noise_std = {5e-4 * M * G / K:.3g}\nlsb = {1e-3 * M * G / K:.3g}")]:
        assert old in text, old
        text = text.replace(old, new, 1)
    text, n = re.subn(r"\nstick-time = \{[^}]*\}", "", text)
    assert n == 1
    path.write_text(text)


def run_json(capsys, *args: str) -> dict:
    capsys.readouterr()  # what was printed before is not this command's answer
    assert daq([*args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_aging_at_one_speed_is_found_by_the_run_the_proposal_asks_for(tmp_path, capsys):
    rig, model = tmp_path / "slider-rig.toml", tmp_path / "model.toml"
    assert daq(["rig", "init", "belt-ndof", "-o", str(rig)]) == 0
    edit_rig(rig)
    assert daq(["model", "init", str(rig), "-o", str(model)]) == 0
    first = write_csv(tmp_path / "run-1.csv", np.array([0.0, FIRST_S]), np.array([V0, V0]), seed=1)
    a = run_json(capsys, "diagnose", str(first), "--model", str(model), "--rig", str(rig))
    with capsys.disabled():
        print("first record:", a["summary"])
    assert not a["missing_effect_found"] or a["undecided"], a["summary"]
    prop = run_json(capsys, "propose", str(first), "--model", str(model), "--rig", str(rig),
                    "-o", str(tmp_path / "next.toml"))
    with capsys.disabled():
        print("proposal:", prop["programme"], prop["reason"], prop.get("decided_rivals"), f"of {prop['family_size']}")
    assert prop["programme"] is not None
    _, rt, rv = load_ramp(tmp_path / "next.toml")
    sliding = sorted({round(float(v), 9) for v in rv if v > 0})
    assert np.any(rv == 0) or max(sliding) / min(sliding) >= 1.5 or abs(sliding[0] / V0 - 1) >= 0.5  # stick times vary
    second = write_csv(tmp_path / "run-2.csv", rt, rv, seed=2)
    both = run_json(capsys, "diagnose", str(first), str(second), "--model", str(model), "--rig", str(rig))
    with capsys.disabled():
        print("both records:", both["summary"], [(r["error"], r["noise_floor"]) for r in both["records"]])
    named = [s["effect"] for s in both["sequence"]]
    assert both["missing_effect_found"] and named and named[0] == "stick-time", both["summary"]
    assert both["final_reduction"] >= 0.7, both["final_reduction"]
