"""`daq demo --closed-loop` (daq/demo.py, run_closed_loop): the next experiment closed on the simulated rig through
the daemon. A belt lagging its command is invisible at one constant speed; the first record names nothing, the
proposal is a run the daemon runs as written, and both runs together name the lag with the error at the floor."""

from __future__ import annotations

import json

import pytest

from daq.cli.main import main as daq
from daq.ramps import load_ramp


@pytest.mark.slow
def test_the_closed_loop_demo_finds_what_one_speed_cannot_show(tmp_path, capsys):
    out = tmp_path / "loop"
    assert daq(["demo", "--closed-loop", "--out", str(out)]) == 0
    printed = capsys.readouterr()
    summary = json.loads((out / "summary.json").read_text())
    first, last = summary["steps"][0], summary["steps"][-1]
    assert first["named"] == [] and first["proposal"]["rivals"][0] == "nothing more"
    assert summary["proposed_runs"] == 1 and len(summary["runs"]) == 2
    assert first["proposal"]["scored"] == first["proposal"]["family_size"]  # no budget cut: not the machine's speed
    _, rt, rv = load_ramp(out / "proposal-1" / "next.toml")  # the file the daemon ran, as written
    assert rv.max() - rv.min() > 0.01  # the speed changes: what one constant speed could not show
    assert (out / "proposal-1" / "next.png").stat().st_size > 20_000
    assert any(n.startswith("belt-speed") for n in last["named"]), last
    assert last["final_error"] <= 1.5 * last["noise_floor"] and last["final_error"] < 0.6 * last["error"], last
    assert "proposed run" in printed.out and "belt-speed" in printed.out
    assert "the proposed run showed what the first could not" in last["fell"] or "belt-speed" in last["fell"]
