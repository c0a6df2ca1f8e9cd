"""The loop from Python (daq/api: ``daq.compare``, ``daq.diagnose``, ``daq.propose``) is the command line's loop.

On one record, each step's result is the JSON the command prints with ``--json`` (wall times and the paths of
files written aside), its fields are attributes, and ``.figure()`` draws the command's figure. The command and the
Python step run one function (daq.api.loop's ``compared``, ``diagnosed``, ``proposed``) on the session each opens:
the command is run once, the object that function returned is held to the JSON it printed, and the Python step's
own part (opening the data and the model, passing the options on) is checked with that function answering at
once. ``import daq`` stays light: the steps load when first used.

The record: 10 s of the brake at a constant 0.17 m/s, 100 Hz, accel-sign hidden (tests/test_propose.py's set-up,
which keeps a diagnosis and a proposal to seconds).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

import daq
from daq.cli.main import main as daq_cli
from daq.config import load_rig
from daq.io.interchange import write_recording
from daq.models.spec import save_model, seed_model
from daq.ramps import constant_ramp, ramp_table
from daq.sim.effectset import parse_effect
from daq.sim.run import simulate

V0 = 0.17
# fields that differ between two runs of the same command: its wall time, and where this run wrote its files
RUN_FIELDS = {"seconds", "report", "output", "figure"}


def same_json(a: dict, b: dict) -> None:
    strip = lambda d: {k: v for k, v in d.items() if k not in RUN_FIELDS}  # noqa: E731
    assert strip(a) == strip(b)


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    folder = tmp_path_factory.mktemp("api")
    rec = simulate(load_rig("brake-2dof"), ramp=ramp_table(constant_ramp(V0, 10.0)), duration=10.0, rate=100.0,
                   seed=3, effects=[parse_effect("accel-sign")])
    write_recording(rec, folder / "a.h5")
    save_model(seed_model("brake-2dof"), folder / "m.toml")
    return folder


def cli_json(capsys, *args: str) -> dict:
    capsys.readouterr()
    assert daq_cli([*args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_import_daq_stays_light_and_names_the_loop():
    code = "import sys, daq; print('numpy' in sys.modules, sorted(n for n in daq.__all__ if n[0].islower()))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False ['compare', 'diagnose', 'propose']"
    assert daq.compare is daq.api.compare and daq.diagnose is daq.api.diagnose and daq.propose is daq.api.propose


@pytest.mark.slow
def test_compare_is_the_commands(record, capsys, tmp_path, monkeypatch):
    a, m = str(record / "a.h5"), str(record / "m.toml")
    kept = spy(monkeypatch, "compared")
    by_cli = cli_json(capsys, "compare", a, "--model", m, "--no-history", "--report", str(tmp_path / "cmp"))
    (cmp,) = kept
    same_json(cmp.json, by_cli)
    same_json(json.loads((tmp_path / "cmp" / "compare.json").read_text()), by_cli)
    # typed fields and every JSON field as an attribute
    assert cmp.error == by_cli["error"] and cmp.noise_floor == by_cli["noise_floor"] and cmp.error_unit == "m"
    assert cmp.excess == pytest.approx(by_cli["error"] - by_cli["noise_floor"])
    assert cmp.by_regime == by_cli["by_regime"] and cmp.worst_regime == by_cli["worst_regime"]
    assert "error" in dir(cmp) and "by_regime" in dir(cmp)
    with pytest.raises(AttributeError, match="no field"):
        cmp.no_such_field  # noqa: B018
    fig = cmp.figure(tmp_path / "again.png")
    assert fig.path.stat().st_size > 20_000 and fig._repr_png_()[:8] == b"\x89PNG\r\n\x1a\n"
    assert cmp.text.startswith(f"error {by_cli['error']:.4g} m on held-out windows")
    calls = asked(monkeypatch, "compared")
    assert daq.compare(a, m, report=tmp_path / "api", predict=True) == "answer"
    (source, model, _, kw), = calls
    assert (source, model, kw["report"], kw["predict"]) == (a, seed_model("brake-2dof").describe(), tmp_path / "api",
                                                            True)
    # a recording opened by daq.io.open: tests/test_tutorial.py (the tutorial's Python step on a daemon's recording)


def spy(monkeypatch, name: str) -> list:
    """daq.api.loop's ``name`` (diagnosed, proposed: what the command and the Python step both run) wrapped to keep
    each result it returns: the command's JSON is then checked against the very object the Python step returns."""
    from daq.api import loop

    real, kept = getattr(loop, name), []

    def wrapped(*a, **k):
        kept.append(real(*a, **k))
        return kept[-1]

    monkeypatch.setattr(loop, name, wrapped)
    return kept


def asked(monkeypatch, name: str) -> list:
    """daq.api.loop's ``name`` replaced by one that records what it was asked (the session's source, the model, the
    keywords) and answers ``"answer"``: the Python step's own part, opening the data and the model, without a run."""
    from daq.api import loop

    calls = []
    monkeypatch.setattr(loop, name, lambda s, m, *a, **k: calls.append((s.source, m.describe(), a, k)) or "answer")
    return calls


@pytest.mark.slow
def test_diagnose_is_the_commands(record, capsys, tmp_path, monkeypatch):
    a, m = str(record / "a.h5"), str(record / "m.toml")
    kept = spy(monkeypatch, "diagnosed")
    by_cli = cli_json(capsys, "diagnose", a, "--model", m)
    (d,) = kept
    same_json(d.json, by_cli)
    assert d.named == by_cli["named"] and d.summary == by_cli["summary"]
    assert d.missing_effect_found == by_cli["missing_effect_found"]
    assert d.final_reduction == by_cli["final_reduction"]
    if d.missing_effect_found:  # the step diagnose names, as `daq model add` takes it
        assert by_cli["summary"].endswith(f"daq model add MODEL {d.add_commands()[0]}.")
    assert d.figure(tmp_path / "d.png").path.stat().st_size > 20_000
    assert str(d) == by_cli["summary"]
    calls = asked(monkeypatch, "diagnosed")
    assert daq.diagnose(a, m, workers=1) == "answer"
    (source, model, _, kw), = calls
    assert (source, model, kw["workers"], kw["report"]) == (a, seed_model("brake-2dof").describe(), 1, None)


@pytest.mark.slow
def test_propose_is_the_commands(record, capsys, tmp_path, monkeypatch):
    a, m = str(record / "a.h5"), str(record / "m.toml")
    kept = spy(monkeypatch, "proposed")
    by_cli = cli_json(capsys, "propose", a, "--model", m, "--rival", "velocity-strengthening", "--max-run-s", "10",
                      "-o", str(tmp_path / "cli.toml"))
    (p,) = kept
    same_json(p.json, by_cli)
    assert p.programme == by_cli["programme"] and p.decides == by_cli["decides"] and p.z == by_cli["z"]
    assert (tmp_path / "cli.toml").read_text().endswith(p.ramp)
    assert (tmp_path / "cli.png").stat().st_size > 20_000 and p.figure(tmp_path / "again.png").path.exists()
    calls = asked(monkeypatch, "proposed")
    assert daq.propose(a, m, tmp_path / "api.toml", rival=["velocity-strengthening"], max_run_s=10) == "answer"
    (source, model, (given, out), kw), = calls
    assert (source, model, [c.label for c in given], out) == (a, seed_model("brake-2dof").describe(),
                                                              ["velocity-strengthening"], tmp_path / "api.toml")
    assert kw["max_run_s"] == 10 and kw["write"] is True
