"""A user's own rig: `daq rig init` writes an editable copy of a built-in rig; every command that takes a rig
takes its path; the model file keeps it; a bad value is one line naming the file and field."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from daq.cli.main import main as daq
from daq.models.spec import load_model


def run(capsys, *args) -> tuple[int, str, str]:
    code = daq([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


def test_rig_init_writes_a_commented_copy_that_loads(tmp_path, capsys):
    out = tmp_path / "my-rig.toml"
    code, _, err = run(capsys, "rig", "init", "belt-ndof", "-o", out)
    assert code == 0, err
    text = out.read_text()
    assert text.startswith("# Your own rig") and 'rig = "belt-ndof"' in text
    code, _, err = run(capsys, "rig", "init", "belt-ndof", "-o", out)  # never overwrites silently
    assert code == 2 and "--force" in err and str(out) in err
    assert run(capsys, "rig", "init", "belt-ndof", "-o", out, "--force")[0] == 0


def test_edited_mass_moves_the_eigenfrequency_as_physics_says(tmp_path, capsys):
    """One mass on a spring: f = sqrt(k/m)/(2 pi); four times the mass halves it."""
    out = tmp_path / "heavy.toml"
    assert run(capsys, "rig", "init", "belt-ndof", "-o", out)[0] == 0
    _, shown, _ = run(capsys, "rig", "show", out, "--json")
    before = json.loads(shown)
    m, k = before["mechanics"]["mass_kg"], before["mechanics"]["stiffness_N_per_m"]
    assert before["linear_modes_hz"]["chain"][0] == pytest.approx(math.sqrt(k / m) / (2 * math.pi), rel=1e-9)
    edit(out, f"mass_kg = {m}", f"mass_kg = {4 * m}")
    _, shown, _ = run(capsys, "rig", "show", out, "--json")
    after = json.loads(shown)
    assert after["mechanics"]["mass_kg"] == 4 * m
    assert after["linear_modes_hz"]["chain"][0] == pytest.approx(before["linear_modes_hz"]["chain"][0] / 2, rel=1e-9)


def test_the_model_file_keeps_the_users_rig(tmp_path, capsys):
    rig = tmp_path / "stiff.toml"
    assert run(capsys, "rig", "init", "brake-2dof", "-o", rig)[0] == 0
    model = tmp_path / "m.toml"
    assert run(capsys, "model", "init", rig, "-o", model)[0] == 0
    m = load_model(model)
    assert m.rig == "brake-2dof" and Path(m.rig_config) == rig.resolve()
    builtin = tmp_path / "b.toml"
    assert run(capsys, "model", "init", "brake-2dof", "-o", builtin)[0] == 0
    assert load_model(builtin).rig_config is None


@pytest.mark.parametrize("old, new, field", [
    ("mass_kg = 0.5", "mass_kg = -0.5", "mass_kg"),
    ("n_masses = 1", "n_masses = 4", "n_masses"),
    ("stiffness_N_per_m = 200.0", 'stiffness_N_per_m = "stiff"', "stiffness_N_per_m"),
])
def test_bad_values_in_a_user_rig_one_line_exit_2(tmp_path, capsys, old, new, field):
    rig = tmp_path / "bad-rig.toml"
    assert run(capsys, "rig", "init", "belt-ndof", "-o", rig)[0] == 0
    edit(rig, old, new)
    for args in (("rig", "show", rig), ("sim", rig, "--duration", "1", "-o", tmp_path / "s.csv"),
                 ("model", "init", rig, "-o", tmp_path / "m.toml")):
        code, _, err = run(capsys, *args)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and "bad-rig.toml" in lines[0] and field in lines[0], (args, err)
    assert not (tmp_path / "s.csv").exists() and not (tmp_path / "m.toml").exists()
