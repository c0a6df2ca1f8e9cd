"""Issue 27's acceptance through the user's path: a press record with rate-and-state friction, each law, whose model
lacks it; and a record too weak to tell the laws apart. About 3-8 minutes a case on this 2-core machine, so outside
`make test`: `make acceptance`.

The records: tests/refsim/rsf.py (plain scipy, the textbook law, a 10 g slider's inertia, nothing from daq),
a = 0.010, b = 0.014, Dc = 20 um, k = 3000 N/m, N = 1 N, friction noise 2e-4; the load point alternating between
10 and 100 um/s, 60 um (3 Dc) a plateau, 21 plateaus (72 s) at 1 kHz, so the transients fill the record and at
least 7 windows are held out (a 32 s record held out 4: the consistency test could not pass, and diagnose said
so). The tie: steps of 1.3x (both laws are the same to first order about steady sliding; at 1 kHz both fit to the
noise floor, 6.69e-8 and 6.79e-8 m on 6.81e-8, and a form that reaches the floor leaves nothing to prefer by).

The path: `rig init` + edit (one 10 g slider, 3000 N/m, 1 N, a constant friction level and no seed effects) ->
`import --map` (x1 from mu, vb from the programme column) -> `model init` -> `compare` -> `diagnose` ->
`model add` (what it names, in its form) -> `compare`.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from daq.cli.main import main as daq

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/ (for refsim and test_rsf)
from test_rsf import users_rsf_case  # noqa: E402


def path(tmp_path: Path, law: str, ratio: float, seed: int) -> tuple[dict, dict, dict]:
    h5, rig = users_rsf_case(tmp_path, law, 1000.0, seed, ratio=ratio, plateaus=21)
    model = tmp_path / "model.toml"
    assert daq(["model", "init", str(rig), "-o", str(model)]) == 0
    assert daq(["compare", str(h5), "--model", str(model), "--no-history", "--report", str(tmp_path / "c0")]) == 0
    assert daq(["diagnose", str(h5), "--model", str(model), "--report", str(tmp_path / "d")]) == 0
    d = json.loads((tmp_path / "d" / "diagnose.json").read_text())
    c0 = json.loads((tmp_path / "c0" / "compare.json").read_text())
    c1 = {}
    if d["best"]:
        assert daq(["model", "add", str(model), d["best"], "--form", d["best_form"]]) == 0
        assert daq(["compare", str(h5), "--model", str(model), "--no-history", "--report", str(tmp_path / "c1")]) == 0
        c1 = json.loads((tmp_path / "c1" / "compare.json").read_text())
    return c0, d, c1


@pytest.mark.parametrize("law", ["aging", "slip"])
def test_each_law_is_named_and_the_error_falls(tmp_path, law):
    c0, d, c1 = path(tmp_path, law, 10.0, 7)
    assert d["best"] == "rate-and-state" and d["best_form"] == law, (d["best"], d["best_form"], d["summary"])
    (v,) = d["margins"]
    assert v["decided"] and v["form_decided"], v
    removed = (c0["error"] - c1["error"]) / (c0["error"] - c0["noise_floor"])
    assert removed >= 0.7, removed


def test_steps_too_small_to_tell_the_laws_apart_say_so(tmp_path):
    c0, d, c1 = path(tmp_path, "aging", 1.3, 8)
    if d["best"]:  # named: then its law must be left open, and what it delivers must hold
        assert d["best"] == "rate-and-state", d["summary"]
        (v,) = d["margins"]
        assert not v["form_decided"] and "form is undecided" in d["summary"], d["summary"]
        assert "a run that does: velocity steps up and down" in d["summary"] and v["forms_told_apart_by"]
        assert (c0["error"] - c1["error"]) / (c0["error"] - c0["noise_floor"]) >= 0.7
    else:  # or nothing named at all: never a law the record cannot support
        assert "rate-and-state (slip)" not in d["summary"]
