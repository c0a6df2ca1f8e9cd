"""A fit that fails numerically is reported and the work goes on (issue 59, decision 50).

Faults are injected below the fits, where they arise on real records: numpy's linear algebra raising
``LinAlgError`` ("SVD did not converge") inside every fit of one candidate, and the simulation returning NaN inside
every fit of another. The diagnosis must still end in a complete JSON with those candidates marked failed and the
hidden effect named; compare must say it in one line and exit 2; an archive job must store the record's result as
failed with its reason and complete. The guards themselves (a forward difference across a diverging simulation, a
singular or non-finite system) are tested on the functions that hold them.
"""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest
from helpers import make_recordings
from recovery_table import RAMPS, _run
from refsim import make as refsim

from daq import demo
from daq.cli.main import main as daq
from daq.config import load_rig
from daq.errors import NumericalFailure
from daq.io.archive import Catalog
from daq.io.interchange import write_recording
from daq.models.archive.jobs import match_models, run_diagnoses
from daq.models.candidates import candidates_for
from daq.models.fit import linalg, lm
from daq.models.fit.session import Session
from daq.models.fit.shooting import Problem
from daq.models.spec import save_model, seed_model
from daq.physics.catalog import VB_TAU_MIN
from daq.ramps import constant_ramp, ramp_table
from daq.sim.run import simulate

LINALG = "temperature"  # the phenomenon whose every fit meets a failing LAPACK
NAN = "velocity-strengthening"  # the phenomenon whose every fit meets a simulation that returns NaN
_MODE: list[str] = []  # the fault of the fit in progress (this process's; forked workers inherit the patches)


def _fault_for(model) -> str | None:
    free = model.free_names()
    if any(n.startswith(f"effects.{LINALG}.") for n in free):
        return "linalg"
    if any(n.startswith(f"effects.{NAN}.") for n in free):
        return "nan"
    return None


@pytest.fixture
def faults(monkeypatch):
    """Every fit of a model with LINALG free meets numpy's LinAlgError in each solve, inverse, least squares and
    pseudo-inverse (so the retries fail too); every fit of a model with NAN free simulates NaN."""
    fit_warm, shoot = Session._fit_warm, Problem.shoot

    def faulty_fit(self, model, *a, **k):
        _MODE.append(_fault_for(model) or "")
        try:
            return fit_warm(self, model, *a, **k)
        finally:
            _MODE.pop()

    def faulty_shoot(self, *a, **k):
        shot = shoot(self, *a, **k)
        if _MODE and _MODE[-1] == "nan":
            shot.pred = {key: np.full_like(v, np.nan) for key, v in shot.pred.items()}
        return shot

    def raising(real):
        def f(*a, **k):
            if _MODE and _MODE[-1] == "linalg":
                raise np.linalg.LinAlgError("SVD did not converge in Linear Least Squares")
            return real(*a, **k)
        return f

    monkeypatch.setattr(Session, "_fit_warm", faulty_fit)
    monkeypatch.setattr(Problem, "shoot", faulty_shoot)
    for name in ("solve", "inv", "lstsq", "pinv"):
        monkeypatch.setattr(np.linalg, name, raising(getattr(np.linalg, name)))


def _quiet(*args: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = daq(list(args))
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def aging(tmp_path_factory):
    """A short brake record (100 Hz, the recovery table's ramp C) with Dieterich aging hidden, and the seed model."""
    tmp = tmp_path_factory.mktemp("failures")
    V0, Tmax, duration = RAMPS["C"]
    rec = refsim.generate("brake-2dof", ["stick-log:b=0.3,theta=0.05"], rate=100.0, seed=3, V0=V0, Tmax=Tmax,
                          duration=duration)
    data = tmp / "aging.csv"
    refsim.write(rec, data)
    model = tmp / "seed.toml"
    _run("model", "init", "brake-2dof", "-o", str(model))
    return data, model


@pytest.mark.slow
def test_a_diagnosis_goes_on_past_failed_fits_and_names_the_hidden_effect(aging, faults, tmp_path):
    data, model = aging
    code, out, err = _quiet("diagnose", str(data), "--model", str(model), "--rig", "brake-2dof", "--json",
                            "--report", str(tmp_path / "report"))
    assert code == 0, err
    assert "Traceback" not in err
    d = json.loads(out)
    assert d["missing_effect_found"] and d["named"] and d["named"][0].startswith("stick-time"), d["summary"]
    failed = {c["label"]: c["failed"] for c in d["candidates"] if c.get("failed")}
    assert any(k.startswith(LINALG) for k in failed) and any(k.startswith(NAN) for k in failed), failed
    for label, why in failed.items():
        assert ("SVD did not converge" in why) if label.startswith(LINALG) else ("not finite" in why), (label, why)
    assert all(not c.get("failed") for c in d["candidates"] if c["label"].startswith("stick-time")), d["candidates"]
    listed = {tuple(f["extended_by"]) for f in d["failed"]}
    assert {(k,) for k in failed} <= listed, (failed, d["failed"])
    assert "failed numerically" in d["summary"]
    assert (tmp_path / "report" / "diagnose.png").stat().st_size > 10_000


@pytest.mark.slow
def test_compare_of_a_model_whose_fit_fails_is_one_line_exit_2(aging, faults, tmp_path):
    data, model = aging
    for effect, words in ((NAN, "not finite"), (LINALG, "SVD did not converge")):
        m = tmp_path / f"with-{effect}.toml"
        assert _quiet("model", "add", str(model), effect, "-o", str(m))[0] == 0
        code, out, err = _quiet("compare", str(data), "--model", str(m), "--rig", "brake-2dof", "--json",
                                "--no-history")
        assert code == 2 and out == "", (code, out, err)
        errors = [line for line in err.splitlines() if line.startswith("daq: error:")]  # (after compare's progress)
        assert len(errors) == 1 and err.strip().splitlines()[-1] == errors[0], err
        assert errors[0].startswith(f"daq: error: {data}: the fit failed: ") and words in errors[0], err
        assert "Traceback" not in err


@pytest.mark.slow
def test_an_archive_job_stores_a_failed_fit_as_failed_and_completes(tmp_path, faults):
    data = make_recordings(tmp_path / "data", [("brake-2dof", 6.0, 1), ("brake-2dof", 6.0, 2)])
    good = seed_model("brake-2dof")
    bad = next(c for c in candidates_for(good) if c.phenomenon == NAN).apply(good, f"model add {NAN}")
    with Catalog(tmp_path / "cat.sqlite") as cat:
        cat.scan(data)
        pairs = match_models(cat.rows(), [bad], lambda m: None)
        rep = run_diagnoses(cat, pairs, serial=True, say=lambda m: None)
    assert len(rep.rows) == 2 and rep.failed == 2, rep
    for r in rep.rows:
        assert r.failure and "not finite" in r.failure and r.path in r.failure, r.failure
    with Catalog(tmp_path / "cat.sqlite") as cat:  # stored as failed: asked again, it is the stored failure
        pairs = match_models(cat.rows(), [bad], lambda m: None)
        again = run_diagnoses(cat, pairs, serial=True, say=lambda m: None)
    assert [r.failure for r in again.rows] == [r.failure for r in rep.rows]


# --------------------------------------------------------------------------- the guards


def test_linear_algebra_retries_and_fails_in_words():
    A = np.array([[1.0, 1.0], [1.0, 1.0]])  # singular: the minimum-norm solution
    x = linalg.solve(A, np.array([2.0, 2.0]), "test")
    assert np.allclose(A @ x, [2.0, 2.0]) and np.all(np.isfinite(x))
    stack = np.stack([np.eye(2), A])
    assert np.all(np.isfinite(linalg.inverse(stack, "test")))
    with pytest.raises(NumericalFailure, match="the step: the normal equations are not finite"):
        linalg.solve(np.array([[np.nan, 0.0], [0.0, 1.0]]), np.ones(2), "the step")
    with pytest.raises(NumericalFailure, match=r"gain\): the normal equations are not finite"):
        lm.parameter_gain(np.full((1, 1), np.inf), np.zeros((2, 1, 1)), np.ones((2, 1, 1)), np.ones(1), np.ones((2, 1)))


def test_a_difference_across_a_diverging_simulation_is_taken_from_the_other_side():
    """Window 1 diverges (NO_PREDICTION) for any step up of the parameter; its column comes from the step down,
    window 2 diverges both ways and says nothing (0), window 0 is the plain forward difference."""
    def resid(th: np.ndarray) -> np.ndarray:
        t = float(th[0])
        z = np.array([[2.0 * t, t], [3.0 * t, 0.0], [t * t, 1.0]])
        if t > 1.0:
            z[1] = lm.NO_PREDICTION
        if t != 1.0:
            z[2] = lm.NO_PREDICTION
        return z
    th = np.array([1.0])
    col = lm.difference(resid, resid(th), 1e-6, lambda h: th + h)
    assert col[0] == pytest.approx([2.0, 1.0], rel=1e-6)
    assert col[1] == pytest.approx([3.0, 0.0], rel=1e-6)
    assert np.all(col[2] == 0.0) and np.all(np.isfinite(col))


def test_residuals_are_capped_so_no_difference_overflows():
    """A simulation that diverged to 1e300 (finite) is capped at NO_PREDICTION, as a NaN is: a forward difference of
    it over a step of 1e-12 is finite (it overflowed to inf before, decision 50)."""
    capped = lm.capped(np.array([1e300, -np.inf, np.nan, 3.0]))
    assert list(capped) == [lm.NO_PREDICTION, -lm.NO_PREDICTION, lm.NO_PREDICTION, 3.0]
    assert np.isfinite((capped - 0.0) / 1e-12).all()


def test_a_command_that_ends_in_a_traceback_is_logged_for_the_suites_scan(tmp_path, monkeypatch, aging):
    """The scan the suite ends with (conftest.pytest_sessionfinish) reads what daq.cli.main logs: here a diagnosis
    made to raise a bare ValueError (a defect: the containment above catches it inside fits, not here)."""
    from helpers import logged_tracebacks

    from daq.cli import main as cli

    log = tmp_path / "tracebacks.jsonl"
    monkeypatch.setenv(cli.TRACEBACK_LOG, str(log))  # (not the suite's own log: this one is meant to be found)
    monkeypatch.setattr(Session, "open", classmethod(lambda cls, *a, **k: (_ for _ in ()).throw(ValueError("boom"))))
    data, model = aging
    with pytest.raises(ValueError, match="boom"):
        _quiet("diagnose", str(data), "--model", str(model), "--json")
    (entry,) = logged_tracebacks(log)
    assert entry["command"] == "diagnose" and entry["type"] == "ValueError" and "boom" in entry["traceback"]
    assert entry["argv"][:2] == ["diagnose", str(data)]


def test_a_lag_shorter_than_the_stable_step_is_the_shortest_lag():
    """The drive's lag (belt-speed, lag-ripple) under VB_TAU_MIN predicts as VB_TAU_MIN does, finite: at the brake's
    0.5 ms step RK4 on (v_cmd - v_lag)/tau diverges for tau < 0.18 ms (0.1 ms gave NaN in a third of a 5-window
    batch, passing through 1e300 on the way: decision 50)."""
    cfg = load_rig("brake-2dof")
    s = Session(simulate(cfg, duration=3.0, rate=1000.0, seed=0), "lag", cfg)
    base = seed_model("brake-2dof")
    model = next(c for c in candidates_for(base) if c.label == "belt-speed (lag-ripple)").apply(base)
    pr = s.problem(model)
    w = s.win.select(False)[:5]

    def predicted(tau: float) -> np.ndarray:
        return pr.shoot({**pr.builder.base_values, "effects.belt-speed.tau": tau}, w, None).pred["x1"]

    short, shortest = predicted(1e-5), predicted(VB_TAU_MIN)
    assert np.all(np.isfinite(short)) and np.array_equal(short, shortest)
    assert not np.array_equal(predicted(2 * VB_TAU_MIN), shortest)  # above it, the lag is the fit's


@pytest.mark.slow
def test_a_proposal_leaves_out_a_rival_whose_fit_fails(tmp_path, faults, capsys):
    """Two rivals asked for, one of whose fits fails in its linear algebra: the proposal is made with the other,
    and says which was left out and why."""
    cfg = load_rig("brake-2dof")
    write_recording(simulate(cfg, ramp=ramp_table(constant_ramp(0.17, 10.0)), duration=10.0, rate=100.0, seed=3),
                    tmp_path / "a.h5")
    save_model(seed_model("brake-2dof"), tmp_path / "m.toml")
    code = daq(["propose", str(tmp_path / "a.h5"), "--model", str(tmp_path / "m.toml"), "--rival",
                "accel-sign:relative", "--rival", f"{LINALG}:linear", "--max-run-s", "10", "-o", str(tmp_path / "next.toml"),
                "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    result = json.loads(out)
    assert {r["label"] for r in result["rivals"]} == {"nothing more", "accel-sign (relative)"}, result["rivals"]
    assert f"the rival {LINALG} (linear) is left out: its fit failed:" in err and "SVD did not converge" in err, err


def test_a_demo_whose_recording_does_not_finish_says_so_in_one_line(tmp_path, monkeypatch, capsys):
    """A ramp the simulated rig's interlocks stop (a machine too busy for its clock) or a bench that stops
    answering ended `daq demo` in a traceback (drivers.motor.MotorUnavailable, seen beside a loaded machine):
    one line and exit 1 instead, and a DaqError of any command the same."""
    def aborted(*a, **k):
        raise RuntimeError("ramp aborted: watchdog: no speed reading for 0.5 s")

    monkeypatch.setattr(demo, "run_sim_ramp", aborted)
    assert daq(["demo", "--out", str(tmp_path / "demo")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("daq: error: the demo's recording did not finish (ramp aborted: watchdog") and \
        "Traceback" not in "\n".join(err), err
