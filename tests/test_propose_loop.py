"""The next experiment, closed through the command line on records of the independent reference simulator
(tests/refsim): record, `daq propose` (which diagnoses the record itself and says what that leaves standing), the
proposed ramp file run on the reference rig, `daq diagnose` of both records together (issue 26).

Each case counts the proposed runs it took beside what a fixed protocol costs: the rig's whole family of
programmes, one run each. The long cases (aging on a spring-slider, a brake tie) are in tests/long."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from refsim import make

from daq.cli.main import main as daq
from daq.models.spec import save_model, seed_model
from daq.ramps import constant_ramp, load_ramp, ramp_table, seed_ramp

RATE = 100.0


def refsim_record(path: Path, table: tuple[np.ndarray, np.ndarray], effects: list[str], seed: int) -> Path:
    """The reference brake run under a programme given as its (t, v) table (a ramp file's, read by daq.ramps)."""
    make.write(make.generate("brake-2dof", effects, rate=RATE, table=table, seed=seed), path)
    return path


def run_json(capsys, *args: str) -> dict:
    assert daq(list(args) + ["--json"]) == 0
    return json.loads(capsys.readouterr().out)


def close_loop(tmp: Path, capsys, first: Path, model: Path, effects: list[str], most: int = 2) -> tuple[int, dict, list]:
    """While the diagnosis leaves rivals standing, propose, run the proposal on the reference rig, diagnose every
    record together. Returns (proposed runs, the last diagnosis, the proposals). No `daq diagnose` of the first record
    alone: `daq propose` diagnoses it and its JSON says what that left standing (a separate diagnosis, unused, cost the
    two cases 27 CPU-s)."""
    records = [first]
    diagnosis: dict = {}
    proposals = []
    for k in range(most):
        ramp = tmp / f"next-{k + 1}.toml"
        prop = run_json(capsys, "propose", *map(str, records), "--model", str(model), "-o", str(ramp))
        assert len(prop["scored"]) == prop["family_size"]  # the whole family, so the proposal is not the machine's speed
        proposals.append(prop)
        if prop["programme"] is None:
            break
        _, rt, rv = load_ramp(ramp)  # the file as the daemon would read it
        records.append(refsim_record(tmp / f"run-{k + 2}.csv", (rt, rv), effects, seed=10 + k))
        diagnosis = run_json(capsys, "diagnose", *map(str, records), "--model", str(model))
        if not diagnosis["undecided"]:
            return k + 1, diagnosis, proposals
    return len(proposals), diagnosis, proposals


def test_the_reference_rigs_table_drive_is_its_seed_drive():
    """refsim runs a ramp file's table as it runs its own programme: the seed ramp given as a table gives the same
    record (same noise seed) to the integrator's tolerance."""
    own = make.generate("brake-2dof", [], rate=RATE, duration=3.0, seed=4, noise=False)
    rt, rv = ramp_table(seed_ramp(0.17, 45.0, 3.0))
    table = make.generate("brake-2dof", [], rate=RATE, table=(rt, rv), seed=4, noise=False)
    assert table["meta"]["drive"]["kind"] == "table"
    for k in ("x1", "phi"):
        np.testing.assert_allclose(table["channels"][k], own["channels"][k], atol=1e-7 + 1e-4 * np.ptp(own["channels"][k]))


@pytest.mark.slow
def test_null_nothing_hidden_the_proposed_run_still_names_nothing(tmp_path, capsys):
    """Case 3 of issue 26: a brake record at one constant speed, nothing hidden. The diagnosis names nothing; the
    proposal tests 'nothing more' against what the record cannot see, with a programme that changes the speed and is
    predicted to decide; run on the reference rig with nothing hidden, both records together still name nothing, each
    record's error at its own noise floor. One proposed run, against the family's every programme for a protocol."""
    model = tmp_path / "m.toml"
    save_model(seed_model("brake-2dof"), model)
    first = refsim_record(tmp_path / "run-1.csv", ramp_table(constant_ramp(0.17, 10.0)), [], seed=1)
    runs, d, props = close_loop(tmp_path, capsys, first, model, [], most=1)
    prop = props[0]
    print(f"null: {runs} proposed run(s) against a protocol of {prop['family_size']}; proposal {prop['programme']} "
          f"(z {prop['z']:.2f}, separation {prop['separation']:.1f}); {prop['reason']}")
    assert prop["reason"].startswith("nothing named; the record cannot see"), prop["reason"]  # the first diagnosis
    assert runs == 1 and prop["programme"] is not None and prop["decides"]
    _, rt, rv = load_ramp(tmp_path / "next-1.toml")
    assert np.ptp(rv) > 0.01 or abs(rv[0] - 0.17) > 0.01  # not the record's own programme again
    assert d["named"] == [] and not d["missing_effect_found"]
    assert [r["data"] for r in d["records"]] == [str(first), str(tmp_path / "run-2.csv")]
    for r in d["records"]:
        assert r["error"] <= 1.2 * r["noise_floor"], r


@pytest.mark.slow
def test_a_tie_on_a_short_record_falls_to_the_truth(tmp_path, capsys):
    """Case 2 of issue 26: 4 s of the brake's seed ramp with the reference rig's spring k1 2 % stiff. The record is
    too short to claim anything: a free k1, a free mass and accel-sign (body) each explain nearly all of the excess.
    The proposal must be predicted to decide between all three; run on the reference rig, both records together name
    k1, the truth, over its nearest rival, and the error falls to the floor. One proposed run."""
    model = tmp_path / "m.toml"
    save_model(seed_model("brake-2dof"), model)
    hidden = ["stiffness:k1=0.02"]
    first = refsim_record(tmp_path / "run-1.csv", ramp_table(seed_ramp(0.17, 45.0, 4.0)), hidden, seed=5)
    runs, d, props = close_loop(tmp_path, capsys, first, model, hidden, most=1)
    prop = props[0]
    print(f"tie: {runs} proposed run(s) against a protocol of {prop['family_size']}; proposal {prop['programme']} "
          f"(z {prop['z']:.2f}); {prop['reason']}; then named {d['named']}")
    assert "cannot decide" in prop["reason"] and {r["label"] for r in prop["rivals"]} >= {"mechanics.k1_N_per_m",
                                                                                          "mechanics.m_kg"}
    assert prop["decides"] and "mechanics.k1_N_per_m" in prop["decided_rivals"]
    assert runs == 1 and d["named"] == ["mechanics.k1_N_per_m"] and d["undecided"] == []
    assert d["final_reduction"] > 0.9
