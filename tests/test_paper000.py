"""Paper 000 (belt-ndof) identification: recovery of the simulated rig's true friction law.

The recordings are simulated with the rig's own physics (daq.sim.run.simulate), so the
true law is known: the config's [friction] table (f_s0 = 1.33, alpha_drop = 4, f_k0 = 1,
k_fall = 0.3, w_min = 0.8, k_rise = 0.05) and the seed effects (d = 0.05, accel-sign
amp = 0.1, stick-time gain 0.3 / tau 0.5 s, force-rate gain 0.1 / q0 2 N/s). Records are
short (5-12 s at 250 Hz) and simulated once per module.

Tolerances. The output-error fit's own standard deviations on these records are
0.2-0.4 % (f_k0, k_fall, w_min), 0.2 % (alpha_drop), 0.1 % (k_rise) and 5e-5 (amp),
0.4 % (f_s0), ~1 % (gains, tau); what remains is model error of the windows (start
state from the stick line, smoothed neighbours) which we measured at <= 1.5 % across
seeds. The tolerances below are 3-5 % relative (0.005 absolute on amp): wide enough
for another seed, tight enough that the equation-error estimates (the paper's least
squares, biased by the transitions: amp 0.106, alpha_drop 4.25-4.33, k_fall 0.285)
would fail several of them.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from daq.analysis.paper000.belt_law import belt_law
from daq.analysis.paper000.equation_error import LAW, friction_points
from daq.analysis.paper000.poincare import poincare
from daq.analysis.paper000.preparation import find_sticks, prepare
from daq.cli.main import main
from daq.config import load_rig, parse_rig
from daq.errors import InputError
from daq.io.interchange import Recording, read_recording, write_recording
from daq.ramps import constant_ramp, ramp_table
from daq.sim.effectset import EffectRequest
from daq.sim.run import simulate

TRUE_LAW = {"alpha_drop": 4.0, "f_k0": 1.0, "k_fall": 0.3, "w_min": 0.8, "k_rise": 0.05, "amp": 0.1}
TRUE_STATIC = {"f_s0": 1.33, "stick_time_gain": 0.3, "stick_time_tau_s": 0.5, "force_rate_gain": 0.1}
REL_TOL = {"alpha_drop": 0.05, "f_k0": 0.03, "k_fall": 0.05, "w_min": 0.03, "k_rise": 0.05}
AMP_TOL = 0.005
STATIC_REL_TOL = {"f_s0": 0.02, "stick_time_gain": 0.05, "stick_time_tau_s": 0.05, "force_rate_gain": 0.05}


def _cfg(n: int = 1, stiffness: float = 200.0):
    d = load_rig("belt-ndof").model_dump()
    d["mechanics"]["n_masses"] = n
    d["mechanics"]["stiffness_N_per_m"] = stiffness
    return parse_rig(d, "test")


def _sim(n: int, vb: float, duration: float, seed: int, stiffness: float = 200.0, effects=()):
    cfg = _cfg(n, stiffness)
    return simulate(cfg, ramp=ramp_table(constant_ramp(vb, duration)), duration=duration, seed=seed,
                    effects=list(effects))


def _runs(recs):
    return [prepare(r, f"sim{k}") for k, r in enumerate(recs)]


# the identification set: four belt speeds on the config's rig, two on a softer spring (K = 50 N/m)
# so that stick time and force rate vary independently (with one spring they are tied to s)
SPEEDS = [(200.0, 0.1), (200.0, 0.2), (200.0, 0.3), (200.0, 0.45), (50.0, 0.1), (50.0, 0.2)]


@pytest.fixture(scope="module")
def seed_recs():
    return [_sim(1, vb, 6.0, seed=k, stiffness=K) for k, (K, vb) in enumerate(SPEEDS)]


@pytest.fixture(scope="module")
def law_analysis(seed_recs):
    return belt_law(_runs(seed_recs))


@pytest.mark.slow
def test_kinetic_law_recovered_by_output_error(law_analysis):
    res = law_analysis.result
    for k, tol in REL_TOL.items():
        est = res.law[k].value
        assert abs(est - TRUE_LAW[k]) <= tol * TRUE_LAW[k], (k, est)
        assert res.law[k].std > 0
    assert abs(res.law["amp"].value - TRUE_LAW["amp"]) <= AMP_TOL
    # the windows are fitted to the noise: rms in units of the position noise near 1
    assert 0.8 < res.law_rms_noise_units < 1.3
    # the recordings reach beyond w_min, so k_rise is measured, not extrapolated
    assert max(r.w_max for r in res.recordings) > 1.5 * TRUE_LAW["w_min"]


@pytest.mark.slow
def test_equation_error_is_biased_where_output_error_is_not(law_analysis):
    """The SPEC's hint, measured: the paper's least squares on twice-differentiated positions
    misses the branch amplitude by several of its own standard deviations; output error does not."""
    res = law_analysis.result
    ee, oe = res.equation_error["amp"], res.law["amp"]
    assert abs(ee.value - TRUE_LAW["amp"]) > 3 * ee.std
    assert abs(oe.value - TRUE_LAW["amp"]) < abs(ee.value - TRUE_LAW["amp"]) / 3


@pytest.mark.slow
def test_static_law_recovered(law_analysis):
    res = law_analysis.result
    assert res.static is not None
    for k, tol in STATIC_REL_TOL.items():
        assert abs(res.static[k].value - TRUE_STATIC[k]) <= tol * TRUE_STATIC[k], (k, res.static[k])
    ts = np.array([e.t_s_s for e in res.episodes if e.t_s_s is not None])
    assert ts.min() < 0.15 and ts.max() > 1.5  # the stick times span the adhesion time constant
    # one mass on a constant belt: the force rate at break-away is K S (paper 000, eq. 4)
    for e in res.episodes:
        rec = res.recordings[e.recording]
        K = SPEEDS[e.recording][0]
        assert e.delta_N_per_s == pytest.approx(K * rec.belt_speed_m_per_s, rel=1e-6)


def test_stick_detection_and_transition_bias(seed_recs):
    """Detected sticks match the simulator's modes; friction from derivatives is biased only near transitions."""
    rec = seed_recs[1]
    run = prepare(rec, "sim")
    sticks = [find_sticks(run, 0)]
    det = np.zeros(rec.t.size, bool)
    for st in sticks[0]:
        det[st.start:st.end + 1] = True
    true_stuck = rec.truth["stuck_1"] > 0.5
    assert np.mean(det != true_stuck) < 0.05  # the detected ends are late by a few samples of ~125 per cycle
    pts = friction_points(run, sticks)
    idx = np.searchsorted(run.t, pts.t)
    true_f = -rec.truth["friction_force_1"][idx] / run.mech.normal_force_N
    err = pts.f - true_f
    kept_rms = float(np.sqrt(np.mean(err[pts.kept] ** 2)))
    near_rms = float(np.sqrt(np.mean(err[~pts.kept] ** 2)))
    assert kept_rms < 0.04  # noise only: 2e-5 m through a 7-sample cubic second derivative
    assert abs(float(np.mean(err[pts.kept]))) < 0.01
    assert near_rms > 2 * kept_rms  # the transitions are where the bias lives


@pytest.mark.slow
def test_accel_sign_off_gives_no_branch_difference_and_flat_static_limit():
    off = [EffectRequest("accel-sign", {"amp": 0.0}), EffectRequest("stick-time", {"gain": 0.0}),
           EffectRequest("force-rate", {"gain": 0.0})]
    recs = [_sim(1, vb, 5.0, seed=10 + k, effects=off) for k, vb in enumerate((0.2, 0.45))]
    res = belt_law(_runs(recs), windows_per_mass=4).result
    assert abs(res.law["amp"].value) < AMP_TOL
    for k in ("f_k0", "k_fall", "w_min"):
        assert abs(res.law[k].value - TRUE_LAW[k]) <= REL_TOL[k] * TRUE_LAW[k], (k, res.law[k])
    # without stick-time and force-rate every break-away happens at f_s0
    fs = np.array([e.f_s for e in res.episodes])
    assert np.all(np.abs(fs - 1.33) < 0.01)
    assert res.static["stick_time_gain"].value < 0.02 and res.static["force_rate_gain"].value < 0.01
    assert any("not all determined" in w for w in res.warnings)  # two belt speeds: two conditions


@pytest.mark.slow
def test_two_masses_law_recovered():
    """Every mass of a chain rides the same belt with the same law: pooled over both contacts."""
    recs = [_sim(2, vb, 5.0, seed=20 + k) for k, vb in enumerate((0.2, 0.3))]
    res = belt_law(_runs(recs), windows_per_mass=3).result
    assert {e.mass for e in res.episodes} == {1, 2}
    # chains fit less reliably than one mass (neighbours' start states, micro-slips): over four seeds of
    # this set-up the kinetic parameters came within 2.5 % but once k_fall within 6.5 %, hence 8 %
    for k in ("f_k0", "k_fall", "w_min", "alpha_drop"):
        assert abs(res.law[k].value - TRUE_LAW[k]) <= 0.08 * TRUE_LAW[k], (k, res.law[k])
    assert abs(res.law["amp"].value - TRUE_LAW["amp"]) <= 2 * AMP_TOL
    assert res.law_rms_noise_units < 1.15  # at the noise: no "local minimum" warning
    assert any("chain of masses" in w for w in res.warnings)  # the static law is not claimed here


# ----------------------------------------------------------------------------- Poincaré


@pytest.fixture(scope="module")
def poincare_recs():
    return {1: _sim(1, 0.2, 10.0, seed=31), 2: _sim(2, 0.4, 12.0, seed=32), 3: _sim(3, 0.2, 12.0, seed=33)}


def test_one_mass_stick_slip_is_period_one(poincare_recs):
    """One mass: every cycle passes through the stick, where the state is pinned to the belt (x' = s) and
    the break-away happens at the same force, so the section map has a single attracting fixed point."""
    rec = poincare_recs[1]
    a = poincare(prepare(rec, "sim"))
    r = a.result
    assert r.classification == "period-1" and r.period == 1
    assert r.distinct_points == 1
    # the period equals the simulator's stick-slip period (from its stick starts) within 1 %
    stuck = rec.truth["stuck_1"]
    starts = rec.t[1:][np.diff(stuck) > 0.5]
    true_period = float(np.median(np.diff(starts[starts > r.skip_s])))
    assert r.period_s == pytest.approx(true_period, rel=0.01)
    # one crossing per cycle after the transient
    assert abs(r.points_steady - (rec.t[-1] - r.skip_s) / true_period) <= 1.5


def test_two_masses_period_two_and_three_masses_irregular(poincare_recs):
    r2 = poincare(prepare(poincare_recs[2], "sim")).result
    assert r2.classification == "period-2" and r2.distinct_points == 2
    assert r2.distance_by_k["1"] > 10 * r2.tolerance  # alternate crossings really differ
    # the section mass can be either; the whole state is periodic, so both see period 2
    assert poincare(prepare(poincare_recs[2], "sim"), mass=1).result.classification == "period-2"
    r3 = poincare(prepare(poincare_recs[3], "sim")).result
    assert r3.classification == "irregular" and r3.period is None
    assert min(r3.distance_by_k.values()) > 10 * r3.tolerance
    assert r3.distinct_points > 0.8 * r3.points_steady


def test_constructed_period_three_trajectory():
    """The pure function on a constructed trajectory: amplitudes cycling through three values."""
    t = np.arange(0, 30, 1 / 250)
    amp = np.array([1.0, 1.3, 0.8])
    phase = 2 * math.pi * 1.0 * t
    cyc = np.floor(phase / (2 * math.pi)).astype(int)
    x = 0.02 * amp[cyc % 3] * np.sin(phase)
    rec = Recording("belt-ndof", t, {"x1": x, "vb": np.full(t.size, 0.2)})
    r = poincare(prepare(rec, "constructed")).result
    assert r.classification == "period-3" and r.period_s == pytest.approx(3.0, rel=1e-3)


# ----------------------------------------------------------------------------- CLI


@pytest.mark.slow
def test_cli_end_to_end(tmp_path, capsys, seed_recs, poincare_recs):
    files = []
    for k in (1, 3):
        p = tmp_path / f"run{k}.h5"
        write_recording(seed_recs[k], p)
        files.append(str(p))
    rep = tmp_path / "law"
    assert main(["analyse", "belt-law", *files, "--windows", "3", "--json", "--report", str(rep)]) == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("law", "equation_error", "static", "episodes", "points", "recordings", "mechanics", "warnings"):
        assert key in out
    assert set(out["law"]) == set(LAW) and abs(out["law"]["amp"]["value"] - 0.1) < 0.01
    for name in ("belt-law.png", "belt-static.png", "belt-law.json"):
        assert (rep / name).stat().st_size > 1000
    p2 = tmp_path / "two.h5"
    write_recording(poincare_recs[2], p2)
    rep2 = tmp_path / "pc"
    assert main(["analyse", "poincare", str(p2), "--mass", "2", "--json", "--report", str(rep2)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["classification"] == "period-2" and out["mass"] == 2 and out["n_masses"] == 2
    assert (rep2 / "poincare.png").stat().st_size > 1000


def test_cli_bad_input(tmp_path, capsys):
    missing = tmp_path / "nope.h5"
    rep = tmp_path / "rep"
    assert main(["analyse", "belt-law", str(missing), "--report", str(rep)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(missing) in err[0]
    assert not rep.exists()
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x2,vb\n" + "".join(f"{i * 0.004},{0.0},{0.2}\n" for i in range(300)))
    assert main(["analyse", "poincare", str(bad), "--report", str(rep)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "x1" in err[0]
    assert not rep.exists()
    with pytest.raises(InputError) as exc:
        prepare(read_recording(bad), str(bad))
    assert (exc.value.source, exc.value.field) == (str(bad), "x1")
