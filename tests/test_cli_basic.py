"""The command line as a user meets it: real processes, real files.

Each command path runs in a real process at least once (``daq_process``); the refusals of bad input, which stop
before any work, call the same ``main(argv)`` in this process (``daq``), saving the ~1.5 s start-up of each.
"""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
from helpers import daq, daq_process

from daq.cli.demo import free_folder


def test_rig_list_names_all_three():
    r = daq_process("rig", "list")
    assert r.returncode == 0
    for rig in ("belt-ndof", "brake-2dof", "drum-pendulum"):
        assert rig in r.stdout


def test_rig_show_json_has_modes_and_channels():
    r = daq_process("rig", "show", "brake-2dof", "--json")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert set(info["channels"]) == {"x1", "phi", "vb", "vb_set", "temp"}
    f1, f2 = info["linear_modes_hz"]["springs_only"]
    assert 8.0 < f1 < 8.5 and 11.2 < f2 < 11.6


@pytest.mark.slow
def test_sim_csv_and_h5_with_figure(tmp_path):
    csv = tmp_path / "run.csv"
    r = daq_process("sim", "brake-2dof", "--duration", "3", "-o", str(csv))
    assert r.returncode == 0, r.stderr
    header = csv.read_text().splitlines()[0].split(",")
    assert header[0] == "t" and {"x1", "phi", "vb"} <= set(header)
    assert (tmp_path / "run.png").stat().st_size > 10_000
    h5 = tmp_path / "run.h5"
    r = daq_process("sim", "drum-pendulum", "--duration", "2", "--effect", "bearing-friction", "--no-figure", "-o",
                    str(h5))
    assert r.returncode == 0, r.stderr
    with h5py.File(h5) as f:
        assert f["channels/phi"].attrs["unit"] == "rad"
        assert f["t"].shape == (2001,)
        assert "bearing-friction" in json.loads(f.attrs["effects"])
        assert np.all(np.isfinite(f["channels/thrust"][()]))


def test_bad_input_one_line_exit_2_no_file(tmp_path, capsys):
    out = tmp_path / "bad.csv"
    for args in (["--effect", "nosuch"], ["--effect", "geometric:weight=abc"], ["--effect", "bearing-friction"]):
        code = daq(["sim", "belt-ndof" if args[1] == "bearing-friction" else "brake-2dof", *args, "-o", str(out)])
        err = capsys.readouterr().err
        assert code == 2, (args, err)
        assert len(err.strip().splitlines()) == 1
        assert err.startswith("daq: error: --effect:")
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_sim_with_ramp_file_and_limits(tmp_path, capsys):
    ramp = tmp_path / "ramp.toml"
    ramp.write_text('start_m_per_s = 0.05\n[[segment]]\nkind = "hold"\nduration_s = 1.0\n'
                    '[[segment]]\nkind = "linear"\nduration_s = 1.0\nto_m_per_s = 0.1\n')
    out = tmp_path / "r.csv"
    r = daq_process("sim", "brake-2dof", "--ramp", str(ramp), "--no-figure", "-o", str(out))
    assert r.returncode == 0, r.stderr
    from daq.io.interchange import read_csv

    rec = read_csv(out)
    assert rec.t[-1] == 2.0  # duration taken from the ramp
    np.testing.assert_allclose(rec.channels["vb_set"][rec.t <= 1.0], 0.05, atol=1e-9)
    np.testing.assert_allclose(rec.channels["vb_set"][-1], 0.1, atol=1e-9)
    too_fast = tmp_path / "fast.toml"
    too_fast.write_text('start_m_per_s = 0.0\n[[segment]]\nkind = "linear"\nduration_s = 0.1\nto_m_per_s = 0.4\n')
    assert daq(["sim", "brake-2dof", "--ramp", str(too_fast), "-o", str(tmp_path / "f.csv")]) == 2
    assert capsys.readouterr().err.strip() == (f"daq: error: {too_fast}: acceleration: 4 m/s^2 at t=0 s exceeds the "
                                               "rig limit 0.5 m/s^2")
    assert not (tmp_path / "f.csv").exists()


@pytest.mark.slow
def test_sim_custom_rig_file_three_masses(tmp_path, capsys):
    import tomllib

    import tomli_w

    from daq.config import CONFIG_DIR

    data = tomllib.loads((CONFIG_DIR / "belt-ndof.toml").read_text())
    data["mechanics"]["n_masses"] = 3
    cfg = tmp_path / "belt3.toml"
    cfg.write_text(tomli_w.dumps(data))
    out = tmp_path / "b.h5"
    r = daq_process("sim", str(cfg), "--duration", "3", "--no-figure", "-o", str(out))
    assert r.returncode == 0, r.stderr
    with h5py.File(out) as f:
        assert {"x1", "x2", "x3", "vb", "vb_set", "temp"} == set(f["channels"])
        assert len(json.loads(f.attrs["modes_hz"])["chain"]) == 3
    data["mechanics"]["n_masses"] = 4
    cfg.write_text(tomli_w.dumps(data))
    assert daq(["sim", str(cfg), "-o", str(out.with_name("c.h5"))]) == 2
    assert "mechanics.n_masses" in capsys.readouterr().err


def test_bench_sim_contract_keys():
    """The benchmark's JSON keys and its agreement with the solve_ivp baseline (short baseline here)."""
    from daq.bench.sim import bench_sim

    r = bench_sim(repeat=1, baseline_duration=1.0)
    assert r["realtime_factor"] > 0 and r["speedup_vs_solve_ivp"] > 0
    assert r["max_abs_dev_x1_first_5s_m"] < 5e-5  # same equations, two integrators: microns apart
    assert r["baseline_nfev"] > 1000


def test_a_second_demo_goes_to_the_next_free_folder(tmp_path):
    """`make demo` twice runs twice: the default report folder moves on, the first report is kept."""
    base = str(tmp_path / "out" / "demo")
    assert free_folder(base) == base  # nothing there yet (or a folder without a recording)
    (tmp_path / "out" / "demo").mkdir(parents=True)
    assert free_folder(base) == base
    (tmp_path / "out" / "demo" / "recording.h5").write_bytes(b"")
    assert free_folder(base) == base + "-2"
    (tmp_path / "out" / "demo-2").mkdir()
    (tmp_path / "out" / "demo-2" / "recording.h5").write_bytes(b"")
    assert free_folder(base) == base + "-3"


def test_bench_rig_option_is_checked_before_any_work(capsys):
    """`daq bench diagnose --rig` knows its cases; other benchmarks take no rig; one line, exit 2 each (the first
    as a real process: nothing of the benchmark's start-up may print before the error)."""
    r = daq_process("bench", "diagnose", "--rig", "drum-pendulum")
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "drum-pendulum" in r.stderr, r.stderr
    for args, field in ((["sim", "--rig", "belt-ndof"], "--rig"), (["archive", "--records", "0"], "--records"),
                        (["sim", "--records", "3"], "--records")):
        code = daq(["bench", *args])
        err = capsys.readouterr().err
        assert code == 2, err
        assert len(err.strip().splitlines()) == 1 and field in err, err
