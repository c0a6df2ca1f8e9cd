"""The command line as a user meets it: real processes, real files."""

from __future__ import annotations

import json
import subprocess
import sys

import h5py
import numpy as np


def daq(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "daq.cli", *args], capture_output=True, text=True, cwd=cwd)


def test_rig_list_names_all_three():
    r = daq("rig", "list")
    assert r.returncode == 0
    for rig in ("belt-ndof", "brake-2dof", "drum-pendulum"):
        assert rig in r.stdout


def test_rig_show_json_has_modes_and_channels():
    r = daq("rig", "show", "brake-2dof", "--json")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert set(info["channels"]) == {"x1", "phi", "vb", "vb_set", "temp"}
    f1, f2 = info["linear_modes_hz"]["springs_only"]
    assert 8.0 < f1 < 8.5 and 11.2 < f2 < 11.6


def test_sim_csv_and_h5_with_figure(tmp_path):
    csv = tmp_path / "run.csv"
    r = daq("sim", "brake-2dof", "--duration", "3", "-o", str(csv))
    assert r.returncode == 0, r.stderr
    header = csv.read_text().splitlines()[0].split(",")
    assert header[0] == "t" and {"x1", "phi", "vb"} <= set(header)
    assert (tmp_path / "run.png").stat().st_size > 10_000
    h5 = tmp_path / "run.h5"
    r = daq("sim", "drum-pendulum", "--duration", "2", "--effect", "bearing-friction", "--no-figure", "-o", str(h5))
    assert r.returncode == 0, r.stderr
    with h5py.File(h5) as f:
        assert f["channels/phi"].attrs["unit"] == "rad"
        assert f["t"].shape == (2001,)
        assert "bearing-friction" in json.loads(f.attrs["effects"])
        assert np.all(np.isfinite(f["channels/thrust"][()]))


def test_bad_input_one_line_exit_2_no_file(tmp_path):
    out = tmp_path / "bad.csv"
    for args in (["--effect", "nosuch"], ["--effect", "geometric:weight=abc"], ["--effect", "bearing-friction"]):
        r = daq("sim", "belt-ndof" if args[1] == "bearing-friction" else "brake-2dof", *args, "-o", str(out))
        assert r.returncode == 2, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1
        assert r.stderr.startswith("daq: error: --effect:")
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []
