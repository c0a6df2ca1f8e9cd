"""`daq demo --closed-loop` (daq/demo.py, run_closed_loop): the next experiment closed on the simulated rig through
the daemon. A belt lagging its command is invisible at one constant speed; the first record names nothing, the
proposal is a run the daemon runs as written, and both runs together name the lag with the error at the floor."""

from __future__ import annotations

import json

import pytest

from daq.cli.main import main as daq
from daq.demo import _how_it_fell
from daq.ramps import load_ramp


@pytest.mark.slow
def test_the_closed_loop_demo_finds_what_one_speed_cannot_show(tmp_path, capsys):
    out = tmp_path / "loop"
    assert daq(["demo", "--closed-loop", "--out", str(out)]) == 0
    printed = capsys.readouterr()
    summary = json.loads((out / "summary.json").read_text())
    first, last = summary["steps"][0], summary["steps"][-1]
    assert first["named"] == [] and first["proposal"]["rivals"][0] == "nothing more"
    # one proposed run decides on a quiet machine; on a loaded one the first pair may leave the lag's form and its
    # consistency undecided, and the loop's second proposal decides it (seen: seed 5 beside another demo and a
    # busy process, 94 % with z 1.1, then the lag named at 1.34x the floor): the loop doing its job, not a failure
    assert summary["proposed_runs"] in (1, 2) and len(summary["runs"]) == summary["proposed_runs"] + 1
    assert first["proposal"]["scored"] == first["proposal"]["family_size"]  # no budget cut: not the machine's speed
    _, rt, rv = load_ramp(out / "proposal-1" / "next.toml")  # the file the daemon ran, as written
    assert rv.max() - rv.min() > 0.01  # the speed changes: what one constant speed could not show
    assert (out / "proposal-1" / "next.png").stat().st_size > 20_000
    assert any(n.startswith("belt-speed") for n in last["named"]), last
    assert last["final_error"] <= 1.5 * last["noise_floor"] and last["final_error"] < 0.6 * last["error"], last
    assert "proposed run" in printed.out and "belt-speed" in printed.out
    assert "the proposed run showed what the first could not" in last["fell"] or "belt-speed" in last["fell"]


def test_a_question_left_standing_is_not_told_as_nothing_more():
    """How the loop tells what a proposed run decided (daq/demo.py, _how_it_fell): nothing named with the error at
    the floor is 'nothing more'; nothing named with an excess left is no answer at all (seen on a loaded machine:
    the lag explained 94 % of a 6.1x excess, not consistently, and the line said none of the rivals was there)."""
    question = {"rivals": ["nothing more", "belt-speed (lag-ripple)", "accel-sign (body)"]}
    at_floor = {"named": [], "undecided": [], "final_error": 5.5e-6, "noise_floor": 5.4e-6}
    left = {"named": [], "undecided": [], "final_error": 3.3e-5, "noise_floor": 5.4e-6}
    found = {"named": ["belt-speed (measured)"], "undecided": [], "final_error": 6.0e-6, "noise_floor": 5.4e-6}
    assert _how_it_fell(question, at_floor).startswith("the question fell to 'nothing more'")
    assert _how_it_fell(question, left) == ("the question did not fall: nothing is named, and the error stands at "
                                            "6.1x the noise floor")
    assert _how_it_fell(question, found).startswith("the question fell to belt-speed (lag-ripple)")
