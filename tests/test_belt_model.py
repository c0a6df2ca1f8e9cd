"""belt-ndof in the model loop (issue 14): paper 000's hybrid chain fitted window by window like the other rigs.

The physics is checked against an independent form of it: a spring-slider in the lab frame, integrated by
scipy with its own event logic (tests/refsim/slider.py, nothing from daq). The data side is checked where it
can fail: the stick clock a window starts with (noise must not cut a stick into pieces) and spikes repaired
before any derivative is taken, without touching clean records.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from daq.cli.main import main as daq
from daq.config import load_rig, rig_path
from daq.io.interchange import Recording, write_csv
from daq.models.data import rig_data, stuck_by_hysteresis
from daq.models.session import Session
from daq.models.spec import save_model, seed_model
from daq.physics import beltndof
from daq.physics.effects import E
from daq.sim.effectset import environment_vector
from daq.sim.rigs import make_sim
from daq.sim.run import simulate as simulate_rig

sys.path.insert(0, str(Path(__file__).resolve().parent))  # tests/ (for refsim)
from refsim.slider import Slider, simulate as slider_simulate  # noqa: E402

M, K, G = 0.05, 200.0, 9.81


def slider_rig(tmp_path: Path) -> Path:
    """The spring-slider of docs/examples/spring-slider.md as a user's belt-ndof rig file."""
    text = rig_path("belt-ndof").read_text()
    text = text.replace("mass_kg = 0.5", f"mass_kg = {M}").replace("normal_force_N = 4.905", f"normal_force_N = {M * G}")
    path = tmp_path / "slider-rig.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("b", [0.0, 0.05])
def test_the_belt_chain_equals_a_spring_slider_integrated_in_the_lab_frame(tmp_path, b):
    """One mass of paper 000's chain on a belt at V is a slider pulled through a spring by a driver at V: the
    model's event-detecting RK4 in the belt frame and scipy's RK45 with located events in the lab frame agree to
    a fraction of a micrometre over five stick-slip cycles, Dieterich aging of the static level included."""
    cfg = load_rig(slider_rig(tmp_path))
    t = np.arange(int(3.6 * 2000)) / 2000.0
    ref = slider_simulate(Slider(M, K, M * G, b=b), lambda _t: 4e-3, t)
    e = environment_vector(cfg)
    e[E.ST_LOG_GAIN], e[E.ST_TAU] = b / 1.33, 0.5
    sim = make_sim(cfg, e)
    s0 = sim.initial_state(4e-3)
    sim.hybrid[beltndof.H.MODE, 0], sim.hybrid[beltndof.H.STICK_T0, 0] = beltndof.STICK, 0.0
    x = sim.advance(s0, 0.0, 2.5e-5, 20, t.size, t, np.full(t.size, 4e-3)).states[:, 0]
    assert np.ptp(ref) > 2e-3  # several stick-slip cycles of ~2.3 mm
    assert np.max(np.abs(x - ref)) < 1e-7


def test_the_seed_model_on_its_own_simulation_sits_at_the_noise_floor(tmp_path):
    cfg = load_rig("belt-ndof")
    rec = simulate_rig(cfg, duration=8.0, seed=3)
    data = tmp_path / "belt.csv"
    write_csv(rec, data)
    model = seed_model("belt-ndof")
    s = Session.open(data, model)
    f = s.fit(model)
    floor = s.noise_floor(f)[s.primary]
    assert f.rms(s.primary) < 1.25 * floor, (f.rms(s.primary), floor)


def test_a_stick_is_not_cut_into_pieces_by_velocity_noise():
    rng = np.random.default_rng(0)
    v = rng.normal(0.0, 1.0, 2000)  # noise of unit level, and two real slips
    v[500:520] = -40.0
    v[1500:1530] = -30.0
    stuck = stuck_by_hysteresis(v, 4.0, 12.0)
    assert not stuck[500:520].any() and not stuck[1500:1530].any()
    assert stuck[:500].all() and stuck[520:1500].all() and stuck[1530:].all()
    assert (np.abs(v) < 4.0).mean() < 1.0  # a single threshold would cut it


def test_spikes_are_repaired_and_counted_and_clean_records_untouched():
    cfg = load_rig("belt-ndof")
    rec = simulate_rig(cfg, duration=4.0, seed=1)
    rd = rig_data(cfg)
    clean = rd.prepare(rec, "clean")
    assert clean.outliers == {}
    x = rec.channels["x1"].copy()
    idx = np.array([100, 400, 401 + 5, 777])
    x[idx] += np.array([3e-3, -2e-3, 4e-3, 1e-3])  # 50-200 noise levels
    spiky = Recording(rec.rig, rec.t, {**rec.channels, "x1": x}, rec.units, rec.meta)
    m = rd.prepare(spiky, "spiky")
    assert sorted(m.outliers["x1"].tolist()) == sorted(idx.tolist())
    assert np.max(np.abs(m.outputs["x1"] - clean.outputs["x1"])) < 10 * clean.sigma["x1"]


def test_quantisation_steps_of_a_noise_free_creep_are_not_spikes():
    """A slow creep read through a coarse quantiser: third differences mostly 0, so the data's noise estimate is 0;
    the instrument's declared noise is the floor, and no step is taken for a spike (22 of 2000 were)."""
    rd = rig_data(load_rig("belt-ndof"))
    t = np.arange(2000) / 250.0
    x = np.round(2e-5 * t / 1e-5) * 1e-5
    y, idx = rd._despike("x1", x)
    assert idx.size == 0 and np.array_equal(y, x)


def test_belt_model_files_round_trip(tmp_path):
    path = tmp_path / "m.toml"
    save_model(seed_model("belt-ndof"), path)
    assert "pwl-000" in path.read_text()


def test_a_users_spring_slider_far_from_the_config_law_converges_from_the_data(tmp_path):
    """The user's path on a lab-frame record (a MATLAB file holding t and F/mg only, noise and quantisation):
    rig file edited -> import --map (the driver's speed steps as arithmetic of t) -> model init -> compare. The
    contact is nothing like the config's law (f_s0 0.62, f_k0 0.45 against 1.33, 1.0); from the config's values
    alone the fit stopped at 1061 um against a 2.4 um floor. The law's levels guessed from the data (the spring
    force at the end of each stick, and over the slips) are a start of their own, reported in the JSON."""
    t = np.arange(16 * 500) / 500.0
    steps = "4e-3 - 3e-3*min(1, max(0, (t - 8)*1000))"

    def drive(tt: float) -> float:
        return 4e-3 - 3e-3 * min(1.0, max(0.0, (tt - 8) * 1000))

    e = slider_simulate(Slider(M, K, M * G, f_s0=0.62, f_k0=0.45, k_fall=0.1, b=0.0), drive, t)
    rng = np.random.default_rng(2)
    f_over_mg = np.round((K * e / (M * G) + rng.normal(0, 5e-4, t.size)) / 1e-3) * 1e-3
    scipy.io.savemat(tmp_path / "slider.mat", {"t": t, "F_over_mg": f_over_mg})
    rig = slider_rig(tmp_path)
    rig.write_text(rig.read_text().replace("noise_std = 2e-5\nlsb = 1e-5", f"noise_std = {5e-4 * M * G / K:.3g}\n"
                                           f"lsb = {1e-3 * M * G / K:.3g}", 1).replace("rate_Hz = 250.0", "rate_Hz = 500.0"))
    h5, model = tmp_path / "slider.h5", tmp_path / "model.toml"
    assert daq(["import", str(tmp_path / "slider.mat"), "--rig", str(rig), "--map", f"x1=F_over_mg*{M}*{G}/{K}",
                "--map", f"vb={steps}", "-o", str(h5)]) == 0
    assert daq(["model", "init", str(rig), "-o", str(model)]) == 0
    assert daq(["compare", str(h5), "--model", str(model), "--no-history", "--report", str(tmp_path / "cmp")]) == 0
    res = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert abs(res["start_from_data"]["friction.f_s0"] - 0.62) < 0.05
    assert abs(res["start_from_data"]["friction.f_k0"] - 0.45) < 0.05
    law = {k: res["parameters"][f"friction.{k}"]["value"] for k in ("f_s0", "f_k0", "k_fall")}
    assert law == pytest.approx({"f_s0": 0.62, "f_k0": 0.45, "k_fall": 0.1}, rel=0.03), law
    fast = next(v["error"] for k, v in res["by_regime"].items() if k.startswith("belt speed 4-4"))
    assert fast < 1.5 * res["noise_floor"], (fast, res["noise_floor"])
    # 32 of 34 windows sit at the floor; two held-out ones (the one holding the driver's step, one after a 0.9 s
    # stick) keep ~50 um after one slip: cause not found yet (decision 21); the record within 10x, not 300x
    assert res["error"] < 10.0 * res["noise_floor"], (res["error"], res["noise_floor"])
