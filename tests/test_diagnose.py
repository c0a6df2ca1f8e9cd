"""Diagnose finds the hidden effect, and the whole loop works from the command line on a foreign CSV.

The full recovery table (every hidden effect of the issue at 1 kHz and 100 Hz) is
`python -m daq.models.diagnosis.recovery`; these tests run the cases that exercise the
hardest paths within the suite's time budget.
"""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from daq.config import load_rig
from daq.models.candidates import Candidate, candidates_for
from daq.models.diagnosis.diagnose import diagnose, fit_extensions, users_fit
from daq.models.diagnosis.report import diagnosis_json
from daq.models.diagnosis.scoring import MIN_T, own_share, passes, score, windows_needed, z_attainable
from daq.models.diagnosis.screening import Column, Linearisation, gain_past_bound, predicted_gain
from daq.models.diagnosis.selection import PAIR_TOP, SCREEN_TIE, further_down, pairs_to_fit, past_bound, to_fit
from daq.models.diagnosis.verdict import delivered_fit
from daq.models.fit.session import Session
from daq.models.spec import remove_effect, save_model, seed_model
from daq.sim.effectset import parse_effect
from daq.sim.run import simulate


def daq(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "daq.cli", *args], capture_output=True, text=True, cwd=cwd)


def foreign_csv(path, rec):
    """Written the way a lab export would be: units in brackets, CRLF, t offset, shuffled columns, an extra one."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\r\n")
        w.writerow(["t [s]", "vb [m/s]", "phi [rad]", "x1 [m]", "bridge_excitation [V]"])
        for i in range(rec.t.size):
            w.writerow([f"{rec.t[i] + 100.0:.4f}", f"{rec.channels['vb'][i]:.5f}", f"{rec.channels['phi'][i]:.6e}",
                        f"{rec.channels['x1'][i]:.7f}", "10.000"])


@pytest.mark.slow
def test_loop_from_the_command_line_on_a_csv_no_code_of_ours_wrote(tmp_path):
    rec = simulate(load_rig("brake-2dof"), effects=[parse_effect("accel-sign")], rate=1000.0, seed=11, duration=12.0)
    foreign_csv(tmp_path / "lab.csv", rec)
    assert daq("model", "init", "brake-2dof", "-o", "m.toml", cwd=tmp_path).returncode == 0
    r = daq("diagnose", "lab.csv", "--model", "m.toml", "--rig", "brake-2dof", "--json", "--report", "diag",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["missing_effect_found"] is True
    assert d["candidates"][0]["effect"] == "accel-sign"
    assert d["candidates"][0]["reduction"] >= 0.7
    assert (tmp_path / "diag" / "diagnose.png").stat().st_size > 10_000
    assert daq("model", "add", "m.toml", "accel-sign", "-o", "m2.toml", cwd=tmp_path).returncode == 0
    before = json.loads(daq("compare", "lab.csv", "--model", "m.toml", "--rig", "brake-2dof", "--json",
                            cwd=tmp_path).stdout)
    r = daq("compare", "lab.csv", "--model", "m2.toml", "--rig", "brake-2dof", "--json", "--report", "cmp", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    after = json.loads(r.stdout)
    for res in (before, after):
        assert res["error_unit"] == "m" and res["noise_floor"] > 0
        assert {"stick/creep", "slip, accelerating", "slip, decelerating"} <= set(res["by_regime"])
        assert set(res["by_signal"]) == {"x1", "phi"}
    excess_before = before["error"] - before["noise_floor"]
    excess_after = after["error"] - after["noise_floor"]
    assert excess_after <= 0.3 * excess_before
    assert after["parameters"]["effects.accel-sign.amp"]["value"] == pytest.approx(0.15, abs=0.02)
    for fig in ("compare.png", "spectrogram.png"):
        assert (tmp_path / "cmp" / fig).stat().st_size > 10_000
    r = daq("history", "-o", "h.png", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert len(r.stdout.strip().splitlines()) == 2 and (tmp_path / "h.png").stat().st_size > 5_000


@pytest.mark.slow
def test_bad_input_is_one_line_and_exit_2(tmp_path):
    (tmp_path / "m.toml").write_text('rig = "brake-2dof"\nlaw = "brake-eq7"\n[effects.stick-time]\ngain = "x"\n')
    (tmp_path / "d.csv").write_text("t,x1,phi\n0,0,0\n0.001,0,0\n")
    r = daq("diagnose", "d.csv", "--model", "m.toml", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0
    assert "m.toml: effects.stick-time.gain" in r.stderr
    assert daq("model", "init", "brake-2dof", "-o", "ok.toml", cwd=tmp_path).returncode == 0
    r = daq("compare", "d.csv", "--model", "ok.toml", "--report", "rep", cwd=tmp_path)
    assert r.returncode == 2 and "d.csv: vb: missing column" in r.stderr
    assert not (tmp_path / "rep").exists() and not (tmp_path / "daq-history.jsonl").exists()
    for workers in ("0", "-3"):
        r = daq("diagnose", "d.csv", "--model", "ok.toml", "--workers", workers, "--report", "rep", cwd=tmp_path)
        assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "--workers" in r.stderr, r.stderr
        assert not (tmp_path / "rep").exists()


@pytest.mark.slow
@pytest.mark.parametrize("rig, hidden, rate", [("drum-pendulum", "bearing-friction", 1000.0),
                                               ("brake-2dof", "temperature", 100.0),
                                               ("brake-2dof", "stick-time", 100.0)])
def test_hidden_effect_is_ranked_first_and_removes_most_of_the_excess(rig, hidden, rate):
    cfg = load_rig(rig)
    # drum 14 s / 42 windows: recovered 0.95 and 0.97 on seeds 21 and 5 (20 s / 60 windows: 0.98), 30 % cheaper.
    # stick-time at 100 Hz is the weakest trace of the table: the seed run (45 s, 90 windows), where it is
    # found on seeds 3, 5, 7, 11, 21 with reductions 0.61-0.89 (0.83 on this seed)
    duration, windows = {"drum-pendulum": (14.0, 42), "stick-time": (45.0, 90)}.get(
        rig if rig == "drum-pendulum" else hidden, (20.0, 60))
    rec = simulate(cfg, effects=[parse_effect(hidden)], rate=rate, seed=21, duration=duration)
    s = Session(rec, "sim", cfg, max_windows=windows)
    d = diagnose(s, seed_model(rig))
    assert d.found, d.summary
    assert d.candidates[0].effect == hidden
    assert d.candidates[0].reduction >= 0.7


@pytest.mark.slow
def test_seed_model_without_normal_load_gets_it_back_and_clean_data_gets_nothing():
    cfg = load_rig("brake-2dof")
    rec = simulate(cfg, rate=1000.0, seed=22, duration=15.0)
    s = Session(rec, "sim", cfg, max_windows=45)
    d = diagnose(s, remove_effect(seed_model("brake-2dof"), "normal-load"))
    assert d.found and d.candidates[0].effect == "normal-load" and d.candidates[0].reduction >= 0.7
    d = diagnose(s, seed_model("brake-2dof"), base=None)
    assert not d.found, d.summary
    j = diagnosis_json(d, s)
    assert j["missing_effect_found"] is False and j["sequence"] == []
    # every candidate is listed once: each lacking catalog effect in each of its forms, and the mechanics
    labels = sorted(c["label"] for c in j["candidates"])
    assert labels == sorted(c.label for c in candidates_for(seed_model("brake-2dof")))
    assert len(labels) == 16 and "stick-time (log)" in labels and "mechanics.k1_N_per_m" in labels


def test_the_screening_cut_does_not_fall_between_near_equal_predictions():
    """Three phenomena get fits by their predicted gains, and so does any other within SCREEN_TIE of the third."""
    k1, m = Candidate("mechanics", "k1_N_per_m"), Candidate("mechanics", "m_kg")
    body, rel = Candidate("effect", "accel-sign", "body"), Candidate("effect", "accel-sign", "relative")
    belt, vs = Candidate("effect", "belt-speed", "measured"), Candidate("effect", "velocity-strengthening")
    gains = {k1: 1.35e5, body: 1.11e5, rel: 2.0e4, belt: 7.42e4, vs: 6.11e4, m: 3.69e4}
    assert to_fit(gains, first=True) == [k1, body, rel, belt, vs]  # vs: 0.82 of the third; m: 0.497, below 0.5...
    gains[m] = 1.01 * SCREEN_TIE * gains[belt]
    assert to_fit(gains, first=True) == [k1, body, rel, belt, vs, m]  # ...and just above it, a fit
    # the cut counts phenomena, not forms, and a phenomenon below `worth` is not fitted however close it is
    assert to_fit({k1: 10.0, body: 9.0, rel: 9.0, belt: 8.0, vs: 7.0}, first=False, worth=7.5) == [k1, body, rel, belt]


def test_when_no_single_passes_the_phenomena_ranked_next_are_fitted_before_pairs():
    """further_down: the next FIT_PHENOMENA phenomena by predicted gain, none of those already fitted (in any form),
    each worth a fit; the aging slider's screening of 2026-11-29 as the case (stick-time fourth at 352)."""
    belt, lag = Candidate("effect", "belt-speed", "measured"), Candidate("effect", "belt-speed", "lag-ripple")
    temp, rs = Candidate("effect", "temperature", "linear"), Candidate("effect", "rate-and-state", "aging")
    sat, log = Candidate("effect", "stick-time", "saturating"), Candidate("effect", "stick-time", "log")
    vs, fr, mass = (Candidate("effect", "velocity-strengthening"), Candidate("effect", "force-rate"),
                    Candidate("mechanics", "m_kg"))
    gains = {belt: 30300.0, lag: 100.0, temp: 24300.0, rs: 23400.0, sat: 352.0, log: 20.0, vs: 331.0, fr: 40.0,
             mass: 2.0}
    chosen = to_fit(gains, first=True)
    assert chosen == [belt, lag, temp, rs]  # stick-time, fourth, is not among them
    lines: list[str] = []
    assert further_down(gains, chosen, 3.3, lines.append) == [sat, log, vs, fr]  # both forms of stick-time
    assert "stick-time (saturating) 352" in lines[0]
    assert further_down(gains, chosen, 50.0, lines.append) == [sat, log, vs]  # force-rate is not worth a fit there
    assert further_down(gains, list(gains), 3.3, lines.append) == [] and len(lines) == 2  # nothing left: nothing said


def test_a_structural_switch_has_its_pairs_however_its_single_ranks():
    """pairs_to_fit: pairs of different phenomena among the PAIR_TOP best singles (every form fitted of each), and
    a structural switch's phenomenon always, ranked where it may (seen: the belt's measured drive 5th alone, pushed
    out of the pairs by a spring, and the pair it belonged to, 96 % of the excess, never fitted). Best predicted
    first; a fourth phenomenon that is no switch stays out."""
    rng = np.random.default_rng(5)
    r = rng.normal(size=(6, 40))
    lin = Linearisation(r, rng.normal(size=(6, 40, 2)), rng.normal(size=(6, 40, 1)), 0.5 * float(np.sum(r * r)))
    mass, body, rel = (Candidate("mechanics", "m_kg"), Candidate("effect", "accel-sign", "body"),
                       Candidate("effect", "accel-sign", "relative"))
    spring, drive = Candidate("mechanics", "k1_N_per_m"), Candidate("effect", "belt-speed", "measured")
    temp = Candidate("effect", "temperature", "linear")
    order = [mass, rel, body, spring, temp, drive]  # the singles by score, best first
    cols = {c: Column(c, rng.normal(size=r.shape), 0, switch=c is drive) for c in order}
    scored = [types.SimpleNamespace(cands=(c,)) for c in order]
    pairs = pairs_to_fit(lin, cols, scored)
    assert PAIR_TOP == 3
    names = {frozenset(c.label for c in p) for p in pairs}
    assert {frozenset({"accel-sign (body)", "belt-speed (measured)"}),
            frozenset({"accel-sign (relative)", "mechanics.m_kg"}),
            frozenset({"mechanics.m_kg", "mechanics.k1_N_per_m"})} <= names
    assert len(pairs) == 9 and not any(temp in p for p in pairs)  # 3 phenomena (4 forms) + the switch: 5 + 4 pairs
    assert all(a.phenomenon != b.phenomenon for a, b in pairs)
    gains = [predicted_gain(lin, [cols[a], cols[b]]) for a, b in pairs]
    assert gains == sorted(gains, reverse=True)
    cols[drive] = Column(drive, cols[drive].c, 0)  # no switch: the drive, 6th, has no pairs
    assert not any(drive in p for p in pairs_to_fit(lin, cols, scored))


def test_a_strength_whose_first_order_step_crosses_its_bound_is_fitted_when_its_score_past_it_ranks():
    """The score test holds a one-sided strength (stick-time's gain >= 0) at its bound when the linear step would take
    it below: predicted gain 0. Past the bound its score is the two-sided one (the same column, either sign); a
    candidate whose score past the bound would be among those fitted is fitted too (selection.past_bound), one whose
    step points inward is left to the score test as it was."""
    rng = np.random.default_rng(3)
    r = rng.normal(size=(6, 40))
    jg = rng.normal(size=(6, 40, 2))
    jv = rng.normal(size=(6, 40, 1))
    lin = Linearisation(r, jg, jv, 0.5 * float(np.sum(r * r)))
    stick = Candidate("effect", "stick-time", "log")
    # a column along the residual: the cost falls as the strength goes *down* (c . r > 0, step -b/s < 0)
    out = Column(stick, r + 0.3 * rng.normal(size=r.shape), +1)
    two_sided = Column(stick, out.c, 0)
    assert predicted_gain(lin, [out]) == 0.0 < gain_past_bound(lin, out)
    assert gain_past_bound(lin, out) == pytest.approx(predicted_gain(lin, [two_sided]), rel=1e-9)
    inward = Column(stick, -out.c, +1)  # the same column pointing inward: the score test has it, nothing past
    assert gain_past_bound(lin, inward) == 0.0 < predicted_gain(lin, [inward])
    assert gain_past_bound(lin, Column(stick, out.c, +1, switch=True)) == 0.0
    # among fitted phenomena by that score, it is fitted; below the cut, not
    vs, belt = Candidate("effect", "velocity-strengthening"), Candidate("effect", "belt-speed", "measured")
    lines: list[str] = []
    big = gain_past_bound(lin, out)
    gains = {vs: 2 * big, belt: 3 * big, stick: 0.0}
    assert past_bound(lin, {vs: None, belt: None, stick: out}, gains, True, 3.3, [belt, vs], lines.append) == [stick]
    assert "stick-time (log)" in lines[0]
    few = {**gains, Candidate("mechanics", "m_kg"): 8 * big, Candidate("mechanics", "k1_N_per_m"): 9 * big}
    chosen = to_fit(few, first=True)
    assert past_bound(lin, {stick: out}, few, True, 3.3, chosen, lines.append) == []  # fourth of four, and < tie


@pytest.mark.slow
def test_a_missing_normal_load_is_fitted_however_the_score_test_ranks_it():
    """The brake's seed model without normal-load at 100 Hz, noise seed 8. Normal-load enters at a fixed weight (the
    load is followed, or it is not), yet screening read it as a derivative: its secant from off to 0.8 ranked it
    5th of the phenomena (0.45 of the third), it was never fitted, and the diagnosis named a stiffer spring and a
    heavier block, neither in the data (the recovery row that failed on another machine, issue 30; on noise seeds
    2 and 5 too). As a structural switch it is fitted in every step."""
    cfg = load_rig("brake-2dof")
    rec = simulate(cfg, rate=100.0, seed=8, duration=45.0)
    s = Session(rec, "sim", cfg)
    lines = []
    d = diagnose(s, remove_effect(seed_model("brake-2dof"), "normal-load"), progress=lines.append)
    fitted = next(x for x in lines if x.startswith("screened")).split("; fitting ")[1]
    assert "normal-load" in fitted.split(", "), fitted
    j = diagnosis_json(d, s)
    assert j["named"] == ["normal-load"] and j["undecided"] == [], d.summary
    assert j["final_reduction"] >= 0.9


def test_a_short_single_is_judged_on_the_fit_the_user_will_get(brake_cfg):
    """diagnose.users_fit: a passing single whose own fit stopped short (here cut at 2 iterations from the base fit)
    is fitted as `model add` + `compare` will fit it; that fit's score replaces the short one, and it is the very fit
    the promise then reads (delivered_fit returns it from the session: no second fit)."""
    rec = simulate(brake_cfg, effects=[parse_effect("accel-sign")], rate=100.0, seed=3, duration=20.0)
    s = Session(rec, "sim", brake_cfg, max_windows=40)
    model = seed_model("brake-2dof")
    base = s.fit(model)
    floor = s.noise_floor(base)[s.primary]
    cand = Candidate("effect", "accel-sign", "relative")
    short = score(base, base, s.fit(cand.apply(model), warm=base, max_iter=2), (cand,), floor, s)
    again = users_fit(s, model, base, base, short, (), floor, lambda msg: None)
    assert again is not None and again.cands == (cand,) and passes(again), short.step_reduction
    assert again.step_reduction > short.step_reduction and again.step_reduction >= 0.8, (short.step_reduction,
                                                                                        again.step_reduction)
    assert delivered_fit(s, model, [cand]) is again.fitted
    # a single the user's path fits no better is left as it was
    assert users_fit(s, model, base, base, again, (), floor, lambda msg: None) is None


def test_a_candidate_does_not_take_the_credit_for_iterations_its_base_fit_lacked(brake_cfg):
    """Nothing hidden, the model's fit stopped after 2 iterations far from its optimum: a candidate fitted from
    there converges and passes the step gates, but the model without it at that fit's values does as well, so
    it is not taken (the demo's false second claims, 3 runs of 9, came from an unconverged round-2 fit)."""
    rec = simulate(brake_cfg, rate=1000.0, seed=4, duration=12.0)
    # least squares: with Huber's stage (decision 26) a 2-iteration fit gets 2 more and is no longer far from its
    # optimum (6.9 um against the candidate's 6.0), and this is about the gate, not the loss
    s = Session(rec, "sim", brake_cfg, max_windows=30, loss="squares")
    m = seed_model("brake-2dof")
    m.friction["mu0"].value = 0.42
    m.friction["beta"].value = 0.55
    short = s.fit(m, max_iter=2, converge=False)
    assert not short.fit.success
    floor = s.noise_floor(short)["x1"]
    cand = Candidate("effect", "bearing-friction")
    sc = score(short, short, fit_extensions(s, short, [(cand,)], workers=1)[(cand,)], (cand,), floor, s)
    assert passes(sc), sc  # the step gates alone would take it
    assert not own_share(s, short, short, sc, floor)
    assert sc.fit_only and sc.error_neutral < 1.2 * sc.error < short.rms("x1")
    # a fit whose other values the model cannot run without the candidate (its error a NaN there, as the press
    # record's base model at the slip law's fit) needs the candidate: it earns its step
    sc.fitted.values["friction.mu0"] = float("nan")
    assert own_share(s, short, short, sc, floor) and math.isnan(sc.error_neutral)


def test_the_fewest_held_out_windows_that_can_pass_the_consistency_gate():
    """The summary's 'too few held-out windows' is arithmetic of the Wilcoxon test: n windows all improving give
    p = 2^-n, so the z a record can reach at most is isf(2^-n); checked against scipy's own exact test."""
    from scipy import stats

    n = windows_needed()
    assert z_attainable(n) >= MIN_T > z_attainable(n - 1)
    for k in (n - 1, n):
        p = stats.wilcoxon(np.arange(1.0, k + 1), alternative="greater").pvalue
        assert z_attainable(k) == pytest.approx(stats.norm.isf(p), rel=1e-9)


def test_a_record_whose_every_window_got_worse_weighs_by_its_change_not_minus_infinity():
    """Every window worse gives Wilcoxon's p = 1 exactly, whose z is -inf; in several records' combined z that
    outweighed any other record (the closed-loop demo, 2026-11-29: a lag at constant speed, 12 windows 0.6 noise
    variances worse each, sank the decelerating run's z 3.67 and the lag was not taken). The z comes from the other
    tail instead: the mirror image of the same windows improving, so a record weighs by the change it carries."""
    from daq.models.diagnosis.scoring import consistency

    worse = -np.linspace(0.5, 0.7, 12)
    assert consistency(worse) == pytest.approx(-consistency(-worse), rel=1e-12) == pytest.approx(-z_attainable(12))
    gained = np.linspace(50.0, 200.0, 13)
    record = np.repeat([0, 1], [12, 13])
    both = consistency(np.concatenate([worse, gained]), record)
    w = np.array([np.abs(worse).sum(), gained.sum()])
    assert both == pytest.approx(w @ [-z_attainable(12), z_attainable(13)] / np.linalg.norm(w), rel=1e-12)
    assert both >= MIN_T and consistency(worse) < 0 < consistency(gained)


@pytest.mark.slow
def test_serial_and_parallel_fits_are_the_same_fits(brake_cfg, monkeypatch):
    """Issue 25: 'one worker instead of two' may not change a conclusion, so it may not change a fit: the pool's
    extension fits equal the serial ones to the bit (nfev and success too: the pool had returned 0 and True), and
    a model's own fit through the chain of what `model add` left at neutral equals it with the joint path in a
    forked process or not."""
    rec = simulate(brake_cfg, effects=[parse_effect("accel-sign")], rate=100.0, seed=5, duration=12.0)
    s = Session(rec, "sim", brake_cfg, max_windows=30)
    model = seed_model("brake-2dof")
    base = s.fit(model)
    assert s.fit(model) is base  # a session fits the same model once
    tasks = [(Candidate("effect", "accel-sign", "relative"),), (Candidate("mechanics", "k1_N_per_m"),)]
    serial = fit_extensions(s, base, tasks, workers=1)
    pool = fit_extensions(s, base, tasks, workers=2)
    for t in tasks:
        a, b = serial[t], pool[t]
        assert a.values == b.values and a.fit.cost == b.fit.cost
        assert (a.fit.nfev, a.fit.success, a.fit.message) == (b.fit.nfev, b.fit.success, b.fit.message)
        assert all(np.array_equal(a.ms_held[k], b.ms_held[k]) for k in a.ms_held)
        assert np.array_equal(a.fit.start_values, b.fit.start_values)
    extended = model
    for (c,) in tasks:
        extended = c.apply(extended, "model add")
    forked = s.fit(extended)
    monkeypatch.setattr("daq.models.fit.forked.can_fork", lambda: False)
    s._own_fits.clear()
    alone = s.fit(extended)
    assert alone is not forked and alone.values == forked.values and alone.fit.cost == forked.fit.cost
    assert all(np.array_equal(alone.ms_held[k], forked.ms_held[k]) for k in alone.ms_held)


LOADED_DEMO = Path(__file__).resolve().parent / "data" / "loaded-demo"


@pytest.mark.slow
def test_a_passing_switch_brings_its_phenomenons_other_forms_to_a_fit(tmp_path):
    """Two closed-loop demo records made on a loaded machine (tests/data/loaded-demo/README.md): the belt lags
    its command. The score test ranks the lag's own form far below the cut; the measured-drive switch, fitted in
    every step, passes with part of the excess. A switch that passes says its phenomenon is there, so the
    phenomenon's other forms get their fits: the lag is named, with the error near the floor, and the measured
    drive stands as the form it was told apart from. Before, the measured drive was named at 2.1x the floor."""
    model = tmp_path / "seed.toml"
    save_model(seed_model("brake-2dof"), model)
    r = daq("diagnose", str(LOADED_DEMO / "run-1.h5"), str(LOADED_DEMO / "run-2.h5"), "--model", str(model), "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    lag = next(c for c in d["candidates"] if c["label"] == "belt-speed (lag-ripple)")
    top = sorted((c for c in d["candidates"] if c.get("predicted_gain") is not None),
                 key=lambda c: -c["predicted_gain"])
    assert lag not in top[:3]  # the screening alone would not have fitted it
    assert d["named"] == ["belt-speed (lag-ripple)"] and d["undecided"] == []
    assert d["final_error"] <= 1.5 * d["noise_floor"]
    forms = d["margins"][0]["forms"]
    assert [f["rival"] for f in forms] == ["belt-speed (measured)"] and forms[0]["decided"]
