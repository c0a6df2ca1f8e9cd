"""Issue 14's acceptance, from the command line: a lab's spring-slider record with a hidden effect, through the user's
whole path. Outside `make test` (10-minute budget): `make acceptance`. About 5 minutes on this 2-core machine before
rate-and-state joined the catalog (2026-11-26); since, its singles cost minutes each on this 90 s record. On 2026-11-29
(beside other work, about 3x the load) the diagnosis took 35 min: the screening ranked stick-time fourth (352 against
23400-30300), no single of the three first passed, the phenomena ranked next were fitted before pairs
(selection.further_down), stick-time (log) named, margin +0.95 over nothing more (5 % bound +0.67), 98 % promised;
the last `compare` (cut by a 40-minute timeout, run by hand on the test's files) 23.1 -> 1.87 um on a 1.42 um floor,
98 % of the excess. Before that rule the diagnosis had not ended in 24 min (pairs of the three first). Passed start
to end the same day at 83a1b33 in 2562 s, the first 23 min of it at nice 15 behind the recovery table; the rest
(the singles, the pairs, the promise, the last compare) 21 min on the then quiet machine: about 25-30 min in all.
Since the step judges a short single on the fit the user will get (diagnose.users_fit, decision 15's note): stick-time
(log) 98 % in the step where its own fit gave 76 %, no pairs, the same conclusion; 953 s start to end, quiet machine.

The record: a slider (50 g) pulled over a fixed track through a 200 N/m spring by a driver stepping between 4 and
2 mm/s every 10 s (a velocity-stepping test, 90 s at 500 Hz), written by tests/refsim/slider.py (lab frame, scipy,
nothing from daq) with static friction that ages as Dieterich's logarithm of the time at rest, f_s = f_s0 +
b ln(1 + t_stick / tau), b = 0.05: a form the catalog does not have (its stick-time is saturating or a
multiplicative log of a state variable). The file is what a lab's MATLAB script saves: ``t`` and the spring force
normalised by the slider's weight, ``F_over_mg``, with gauge noise, a 1e-3 quantiser and 0.3 % impulsive spikes.

Why velocity steps and 90 s: at one constant speed every stick lasts as long and aging is only a higher static
level (nothing to find); at 4 <-> 1 mm/s the slow sticks outlast a window, so most slow windows hold no slip and
the few that do (2 of 11 held out in 40 s) cannot make a consistent case (the diagnosis says so: decision 22).

The path: `rig init` + edit (mass, load, drive speed, rate, the gauge's noise in metres, and no stick-time in the
user's contact model) -> `import --map` (x1 from F/mg, the driver's programme as arithmetic of t) -> `model init` ->
`compare` -> `diagnose` -> `model add` (what it names, in its form) -> `compare`. Passes when stick-time is named
first, nothing else from the catalog is claimed, and the error falls by >= 70 % of its excess over the noise floor.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import scipy.io

from daq.cli.main import main as daq

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/ (for refsim)
from refsim.slider import Slider, simulate as slider_simulate  # noqa: E402

M, K, G = 0.05, 200.0, 9.81
RATE = 500.0
SPEEDS = (4e-3, 2e-3, 4e-3, 2e-3, 4e-3, 2e-3, 4e-3, 2e-3, 4e-3)  # [m/s] per segment
SEGMENT = 10.0  # [s]
AGING_B = 0.05


def drive_expr() -> str:
    """The driver's programme as `daq import --map` arithmetic of t: 1 ms ramps between the segments."""
    terms = [f"{SPEEDS[0]:g}"]
    for j in range(1, len(SPEEDS)):
        terms.append(f"{SPEEDS[j] - SPEEDS[j - 1]:+g}*min(1, max(0, (t - {j * SEGMENT:g})*1000))")
    return " ".join(terms)


def drive(t: float) -> float:
    v = SPEEDS[0]
    for j in range(1, len(SPEEDS)):
        v += (SPEEDS[j] - SPEEDS[j - 1]) * min(1.0, max(0.0, (t - j * SEGMENT) * 1000.0))
    return v


def write_mat(path: Path) -> None:
    t = np.arange(int(SEGMENT * len(SPEEDS) * RATE)) / RATE
    e = slider_simulate(Slider(M, K, M * G, b=AGING_B), drive, t)
    rng = np.random.default_rng(1)
    f = K * e / (M * G) + rng.normal(0, 5e-4, t.size)
    f = np.round(f / 1e-3) * 1e-3
    spikes = rng.choice(t.size, int(0.003 * t.size), replace=False)
    f[spikes] += rng.choice([-1, 1], spikes.size) * rng.uniform(0.1, 0.3, spikes.size)
    scipy.io.savemat(path, {"t": t, "F_over_mg": f})


def edit_rig(path: Path) -> None:
    """What the user edits in `daq rig init`'s copy: their slider, spring, load, driver, gauge rate and noise."""
    text = path.read_text()
    for old, new in [("mass_kg = 0.5", f"mass_kg = {M}"), ("normal_force_N = 4.905", f"normal_force_N = {M * G}"),
                     ('driven = "belt"', 'driven = "spring"'),
                     ("V0_m_per_s = 0.2", "V0_m_per_s = 4e-3"), ("rate_Hz = 250.0", f"rate_Hz = {RATE}"),
                     ("noise_std = 2e-5\nlsb = 1e-5", f"noise_std = {5e-4 * M * G / K:.3g}\nlsb = {1e-3 * M * G / K:.3g}")]:
        assert old in text, old
        text = text.replace(old, new, 1)
    text, n = re.subn(r"\nstick-time = \{[^}]*\}", "", text)  # their contact model knows no aging
    assert n == 1
    path.write_text(text)


def run_json(tmp_path: Path, *args: str) -> dict:
    assert daq([*args, "--report", str(tmp_path / args[0])]) == 0
    return json.loads((tmp_path / args[0] / f"{args[0]}.json").read_text())


def test_hidden_aging_in_a_users_matlab_slider_record_is_named_and_the_error_falls(tmp_path):
    mat, rig, h5 = tmp_path / "slider.mat", tmp_path / "slider-rig.toml", tmp_path / "slider.h5"
    model = tmp_path / "model.toml"
    write_mat(mat)
    assert daq(["rig", "init", "belt-ndof", "-o", str(rig)]) == 0
    edit_rig(rig)
    assert daq(["import", str(mat), "--rig", str(rig), "--map", f"x1=F_over_mg*{M}*{G}/{K}",
                "--map", f"vb={drive_expr()}", "-o", str(h5)]) == 0
    assert daq(["model", "init", str(rig), "-o", str(model)]) == 0
    assert "stick-time" not in model.read_text()
    before = run_json(tmp_path, "compare", str(h5), "--model", str(model), "--no-history")
    e0, f0 = before["error"], before["noise_floor"]
    assert e0 > 5 * f0, (e0, f0)  # the aging shows
    assert before["outliers"]["x1"] > 0  # the spikes were found and repaired
    d = run_json(tmp_path, "diagnose", str(h5), "--model", str(model))
    assert d["missing_effect_found"], d["summary"]
    named = [s["effect"] for s in d["sequence"]]
    assert named[0] == "stick-time" and set(named) == {"stick-time"}, named
    for s in d["sequence"]:
        assert daq(["model", "add", str(model), s["effect"], *(["--form", s["form"]] if s["form"] else [])]) == 0
    after = run_json(tmp_path, "compare", str(h5), "--model", str(model), "--no-history")
    removed = (e0 - after["error"]) / (e0 - f0)
    assert removed >= 0.7, (e0, after["error"], f0, removed)
