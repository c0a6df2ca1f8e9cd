"""Several recordings of one rig judged together (issue 26): `daq diagnose A.h5 B.h5 --model M.toml`.

One model with shared parameters; each record keeps its own windows (fit and held out), its own noise level and
its own noise floor (MultiSession, StackedProblem). Of one record a MultiSession is that record's Session.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from daq.cli.main import main
from daq.config import load_rig
from daq.io.interchange import write_h5
from daq.models.diagnosis.compare import where_it_lives
from daq.models.diagnosis.diagnose import diagnose, fit_error
from daq.models.diagnosis.report import diagnosis_json
from daq.models.diagnosis.scoring import correlations
from daq.models.fit.multi_session import RECORD_KEY, MultiSession
from daq.models.fit.session import Session
from daq.models.spec import add_effect, rig_config_for, save_model, seed_model
from daq.ramps import ramp_table, seed_ramp
from daq.sim.effectset import parse_effect
from daq.sim.run import simulate

AMP = 0.05  # accel-sign hidden, weakly (the catalog's start is 0.15)


def quieter(cfg, factor: float):
    """The rig with its displacement and angle sensors ``factor`` times as noisy."""
    ch = {k: (c.model_copy(update={"noise_std": c.noise_std * factor}) if k in ("x1", "phi") else c)
          for k, c in cfg.channels.items()}
    return cfg.model_copy(update={"channels": ch})


def record(v0: float, tmax: float, duration: float, rate: float, seed: int, noise: float = 1.0, amp: float = AMP):
    cfg = load_rig("brake-2dof")
    return simulate(quieter(cfg, noise), effects=[parse_effect(f"accel-sign:amp={amp}")],
                    ramp=ramp_table(seed_ramp(v0, tmax, duration)), duration=duration, rate=rate, seed=seed)


@pytest.fixture(scope="module")
def brake_model():
    model = seed_model("brake-2dof")
    return model, rig_config_for(model)


@pytest.mark.slow
def test_one_record_is_its_session(brake_model):
    """A MultiSession of one record: the Session's windows, fits, errors, floor and diagnosis, number for number."""
    model, cfg = brake_model
    rec = record(0.17, 45.0, 8.0, 100.0, seed=3)
    one, multi = Session(rec, "a.h5", cfg), MultiSession([rec], ["a.h5"], cfg)
    assert np.array_equal(one.win.starts, multi.win.starts) and np.array_equal(one.win.held_out, multi.win.held_out)
    f, g = one.fit(model), multi.fit(model)
    assert f.values == g.values and f.fit.cost == g.fit.cost
    assert all(np.array_equal(f.ms_held[k], g.ms_held[k]) for k in f.ms_held)
    assert one.noise_floor(f) == multi.noise_floor(g)
    a = diagnosis_json(diagnose(one, model, base=f, workers=1), one)
    b = diagnosis_json(diagnose(multi, model, base=g, workers=1), multi)
    assert a["named"] == b["named"] and a["named"]  # (accel-sign at this strength is found in 8 s at 100 Hz)
    assert a == b  # every key and number; no per-record section for one record


def test_two_records_share_parameters_each_weighted_by_its_own_noise(brake_model):
    """Two ramps, the second twice as noisy (and declared so): one amplitude fitted for both, each window's error
    in its own record's noise units at every place a score reads it, each record its own held-out windows and floor."""
    model, cfg = brake_model
    recs = [record(0.17, 45.0, 8.0, 100.0, seed=7), record(0.30, 30.0, 8.0, 100.0, seed=8)]
    rng = np.random.default_rng(1)
    sigma = {k: math.sqrt(c.noise_std**2 + c.lsb**2 / 12.0) for k, c in cfg.channels.items() if k in ("x1", "phi")}
    for k, s in sigma.items():  # record B: its noise doubled (white, on top of the simulated one)
        recs[1].channels[k] = recs[1].channels[k] + rng.normal(0.0, math.sqrt(3.0) * s, recs[1].t.size)
    ms = MultiSession(recs, ["A", "B"], cfg)
    ms.parts[1].m.sigma = {k: 2.0 * v for k, v in ms.parts[1].m.sigma.items()}  # (at 100 Hz the data cannot say it)
    held = ms.win.record[ms.win.select(True)]  # the stacked held-out windows are each record's own
    assert [int(np.sum(held == r)) for r in range(2)] == [int(p.win.select(True).size) for p in ms.parts]
    assert all(p.win.select(True).size >= 3 for p in ms.parts)
    f = ms.fit(add_effect(model, "accel-sign"))
    assert f.values["effects.accel-sign.amp"] == pytest.approx(AMP, abs=0.01)
    # each window in its own record's units: the whole-session weighting is the records' own, side by side
    w = ms.weighted(f.ms_held, f.held.windows)
    views = [ms.part_fit(f, r) for r in range(2)]
    assert np.array_equal(w, np.concatenate([p.weighted(v.ms_held, v.held.windows) for p, v in views]))
    first = sum(v / ms.m.sigma[k] ** 2 for k, v in f.ms_held.items())  # (record A's noise for every window)
    on_b = ms.win.record[f.held.windows] == 1
    assert np.allclose(w[on_b], first[on_b] / 4.0) and np.array_equal(w[~on_b], first[~on_b])
    assert fit_error(ms, f) == pytest.approx(np.mean(np.concatenate(
        [p.weighted(v.ms_fit, v.fit.windows) for p, v in views])))
    floors = ms.noise_floor(f)
    own = [floors[f"x1{RECORD_KEY}{r}"] for r in range(2)]
    assert own[1] / own[0] == pytest.approx(2.0, rel=0.25)
    assert own[0] < floors["x1"] < own[1]
    for r, (p, v) in enumerate(views):  # the fit reaches each record's own floor on its held-out windows
        assert v.rms("x1") <= 1.5 * own[r]
    # what a diagnosis reads per window comes from the window's own record
    t = ms.window_t(ms.win.select(None))
    assert np.all(t[ms.win.record == 1] <= recs[1].t[-1]) and t[ms.win.record == 1].max() > 4.0
    assert "record" in {c["quantity"] for c in correlations(ms, f)}
    part, view = ms.where_view(f)
    held = ms.win.record[f.held.windows]
    assert part is ms.parts[int(np.argmax([w[held == r].sum() for r in range(2)]))]  # (the record with most error)
    assert set(where_it_lives(part, view)) >= {"by_cycle_phase", "loading", "motion", "cycles"}


def test_records_a_little_apart_in_rate_are_each_simulated_at_their_own(brake_model):
    """The daemon's second record of the closed-loop demo came at 997.464 Hz against the first's 999.994 (CI, a
    loaded machine), and here beside two busy processes at 999.918 against 1000.030 Hz, windows of 218 samples
    against 219. Records within RATE_TOLERANCE go together: their
    windows hold the same samples, and each record is stepped at its own rate, so the amplitude is found in both."""
    model, cfg = brake_model
    recs = [record(0.17, 45.0, 8.0, 100.0, seed=7), record(0.30, 30.0, 8.0, 99.7, seed=8)]
    ms = MultiSession(recs, ["A", "B"], cfg)
    assert ms.parts[1].m.rate == pytest.approx(99.7, rel=1e-6)
    assert ms.parts[0].win.length == ms.parts[1].win.length == ms.win.length
    pr = ms.problem(add_effect(model, "accel-sign"))
    assert [p.h * p.n_sub for p in pr.parts] == pytest.approx([1 / 100.0, 1 / 99.7], rel=1e-9)
    f = ms.fit(add_effect(model, "accel-sign"))
    assert f.values["effects.accel-sign.amp"] == pytest.approx(AMP, abs=0.01)


@pytest.mark.slow
def test_diagnose_two_recordings_from_the_command_line(tmp_path, capsys):
    """`daq diagnose A.h5 B.h5`: the weak hidden effect named, one amplitude for both records, and a per-record
    section. At 1 kHz each record's noise is read from its data: A's sensors are half as noisy as B's."""
    paths = []
    for i, (v0, tmax, noise) in enumerate(((0.17, 45.0, 0.5), (0.30, 30.0, 1.0))):
        paths.append(str(tmp_path / f"r{i}.h5"))
        write_h5(record(v0, tmax, 5.0, 1000.0, seed=7 + i, noise=noise), paths[-1])
    save_model(seed_model("brake-2dof"), tmp_path / "m.toml")
    assert main(["diagnose", *paths, "--model", str(tmp_path / "m.toml"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["named"] == ["accel-sign (relative)"] and d["missing_effect_found"] is True
    assert d["sequence"][0]["values"]["effects.accel-sign.amp"] == pytest.approx(AMP, abs=0.01)
    assert d["data"] == paths and [r["data"] for r in d["records"]] == paths
    a, b = d["records"]
    for r in (a, b):
        assert r["windows"]["held_out"] >= 3 and r["windows"]["fit"] >= 6 and r["samples"] == 5001
        assert r["error"] <= 1.3 * r["noise_floor"]  # the promised model reaches each record's own floor
    assert a["noise"]["sigma"]["x1"] < 0.7 * b["noise"]["sigma"]["x1"]
    assert a["noise_floor"] < 0.7 * b["noise_floor"]
    assert a["noise_floor"] < d["noise_floor"] < b["noise_floor"]


def test_records_that_do_not_go_together_are_one_line(tmp_path, capsys):
    """Another rate, another rig: one line naming the file and what differs (exit 2), before any fit."""
    save_model(seed_model("brake-2dof"), tmp_path / "m.toml")
    a, b, c = (str(tmp_path / n) for n in ("a.h5", "b.h5", "c.h5"))
    write_h5(record(0.17, 45.0, 3.0, 100.0, seed=1), a)
    write_h5(record(0.17, 45.0, 3.0, 250.0, seed=2), b)
    drum = load_rig("drum-pendulum")
    write_h5(simulate(drum, duration=2.0, rate=100.0, seed=3), c)
    for other, field in ((b, "rate"), (c, "rig")):
        assert main(["diagnose", a, other, "--model", str(tmp_path / "m.toml"), "--json"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"daq: error: {other}: {field}: "), err
