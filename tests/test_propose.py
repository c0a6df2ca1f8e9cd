"""`daq propose` (daq/models/design/proposal.py): the run under which rival explanations of a record differ most.

A brake record at one constant belt speed cannot tell velocity strengthening (friction rising with speed) from a
higher friction level: the proposal must be a programme that changes the speed, must predict that it decides, and
must score the record's own programme (a hold at its speed) below it. Invariants: a rival equal to the truth is
never separated, and the truth's own predicted record sits at the noise level."""

from __future__ import annotations

import json

import numpy as np
import pytest

from daq.cli.main import main as daq
from daq.config import load_rig
from daq.io.interchange import write_recording
from daq.models.candidates import parse_candidate
from daq.models.design import proposal
from daq.models.design.programmes import family
from daq.models.fit.session import Session
from daq.models.spec import load_model, save_model, seed_model
from daq.ramps import constant_ramp, load_ramp, ramp_table
from daq.sim.run import simulate

V0 = 0.17


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    """10 s of the brake at a constant 0.17 m/s, 100 Hz, nothing hidden; the seed model beside it."""
    folder = tmp_path_factory.mktemp("propose")
    rec = simulate(load_rig("brake-2dof"), ramp=ramp_table(constant_ramp(V0, 10.0)), duration=10.0, rate=100.0, seed=3)
    write_recording(rec, folder / "a.h5")
    save_model(seed_model("brake-2dof"), folder / "m.toml")
    return folder


@pytest.mark.slow
def test_a_record_at_one_speed_gets_a_run_that_changes_the_speed(record, capsys):
    out = record / "next.toml"
    assert daq(["propose", str(record / "a.h5"), "--model", str(record / "m.toml"), "--rival",
                "velocity-strengthening", "--max-run-s", "10", "-o", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert len(result["scored"]) == result["family_size"]  # a budget cut would make the proposal the machine's speed
    ramp, rt, rv = load_ramp(out)  # a ramp file the daemon runs as it is
    assert ramp is not None and ramp.name == result["programme"]
    assert (out.with_suffix(".png")).stat().st_size > 20_000
    assert json.loads(out.with_suffix(".json").read_text())["programme"] == result["programme"]
    # the rival the record cannot see: held at a strength the record leaves standing, not fitted to neutral
    rival = next(r for r in result["rivals"] if r["label"] == "velocity-strengthening")
    assert rival["held_at_generic_strength"] == "effects.velocity-strengthening.D"
    assert rival["values"] == {} or "effects.velocity-strengthening.D" not in rival["values"]
    nothing = next(r for r in result["rivals"] if r["label"] == proposal.NOTHING)
    assert rival["error_on_record"] < 1.2 * nothing["error_on_record"]
    # the proposal changes the speed, decides, and beats the record's own programme by far
    assert np.ptp(rv) > 0.01 or abs(rv[0] - V0) > 0.01, result["programme"]
    assert result["decides"] and result["z"] >= 2.33
    scored = {s["programme"]: s for s in result["scored"]}
    own = scored[f"hold {V0:g} m/s for 10 s"]
    assert result["separation"] > 3 * own["separation"], (result["separation"], own)
    assert result["scored"] and len(result["scored"]) == result["family_size"] >= 20
    assert {p["truth"] for p in result["pairs"]} == {proposal.NOTHING, "velocity-strengthening"}


@pytest.mark.slow
def test_a_rival_equal_to_the_truth_is_never_separated_and_the_truth_sits_at_its_noise(record):
    model = load_model(record / "m.toml")
    s = Session.open(record / "a.h5", model)
    nothing = proposal.Rival(proposal.NOTHING, s.fit(model))
    twin = proposal.Rival("the same model", nothing.fitted)
    progs = family(s.cfg, V0, 10.0)
    for prog in (progs[0], progs[-1]):
        rec = proposal.predicted(s, nothing, prog)
        pair = proposal.score_pair(s, nothing, twin, rec)
        assert pair.z == 0.0 and pair.separation == 0.0 and pair.n_held >= 5
        # the truth on its own predicted record: mean square error at the record's noise level (start values fitted)
        p = Session(rec, "(predicted)", s.cfg, max_windows=proposal.MAX_WINDOWS, window_s=(s.win.length - 1) / s.m.rate)
        p.m.sigma = dict(s.m.sigma)
        cold, ms = p.held_out(p.problem(model), nothing.fitted.values)
        per_sigma2 = np.mean(p.weighted(ms, p.win.select(True))) / len(ms)
        assert 0.5 < per_sigma2 < 1.5, per_sigma2
        # scored, the start fits begin at the states the truth's own simulation passed through (not the data's
        # estimate): the same optimum (the CPU it saves over a family: `daq bench propose`)
        truth = proposal._TruthRecord(s, nothing, rec)
        assert truth.near is not None and truth.near.shape == cold.start_values.shape
        warm, ms_warm = p.held_out(p.problem(model), nothing.fitted.values, near=truth.near)
        hw = p.win.select(True)
        np.testing.assert_allclose(p.weighted(ms_warm, hw), p.weighted(ms, hw), rtol=1e-3)
        np.testing.assert_allclose(p.weighted(truth.ms, hw), p.weighted(ms, hw), rtol=1e-3)
        assert warm.success and abs(warm.cost - cold.cost) <= 1e-4 * cold.cost, (warm.cost, cold.cost)


def test_bad_proposals_are_one_line(record, capsys):
    args = [str(record / "a.h5"), "--model", str(record / "m.toml")]
    for extra, field in ((["--rival", "nosuch", "-o", str(record / "x.toml")], "--rival"),
                         (["--rival", "velocity-strengthening", "-o", str(record / "x.csv")], "-o"),
                         (["--rival", "velocity-strengthening", "--budget", "0", "-o", str(record / "x.toml")],
                          "--budget")):
        assert daq(["propose", *args, *extra]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and field in err, err
    assert not (record / "x.toml").exists()
    assert parse_candidate("velocity-strengthening").label == "velocity-strengthening"
