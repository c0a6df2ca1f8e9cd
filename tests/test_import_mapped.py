"""`daq import` of files as labs write them: MATLAB v5 and v7.3, text with its own names, TDMS groups,
through --time/--rate and --map CHANNEL=EXPR (a safe arithmetic parser, no eval); bad maps, times and files
give one line naming file and field, exit 2, and no output file."""

from __future__ import annotations

import json
import os
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

from daq.cli.main import main as daq
from daq.errors import InputError
from daq.io.expressions import Expression
from daq.io.interchange import read_recording
from daq.io.sources import read_source

N = 400
T = np.arange(N) / 200.0
F_OVER_MG = 0.4 + 0.1 * np.sin(2 * np.pi * T)


def run(*args: str | os.PathLike, capsys=None) -> tuple[int, str]:
    code = daq([str(a) for a in args])
    err = capsys.readouterr().err if capsys is not None else ""
    return code, err


# -- the expression parser -------------------------------------------------------------------------------

def ev(text: str, env: dict, size: int = 3) -> np.ndarray:
    return Expression.parse(text, list(env), "f.mat", "--map x1").evaluate(env, size)


def test_arithmetic_precedence_functions_and_constants():
    a, b = np.array([1.0, 2.0, 3.0]), np.array([4.0, 5.0, 6.0])
    np.testing.assert_allclose(ev("a + b * 2 ** 2 / 4 - -1", {"a": a, "b": b}), a + b + 1)
    np.testing.assert_allclose(ev("sqrt(abs(-a)) + sin(pi/2) + max(a, 2)", {"a": a}),
                               np.sqrt(a) + 1 + np.maximum(a, 2))
    np.testing.assert_allclose(ev("5e-5", {}), [5e-5] * 3)  # a constant becomes a constant channel
    np.testing.assert_allclose(ev("(a % 2) * 3", {"a": a}), (a % 2) * 3)


def test_names_that_are_not_identifiers():
    env = {"run/x1": np.array([1.0, 2.0, 3.0]), "run": np.array([10.0, 10.0, 10.0]),
           "s.force": np.array([2.0, 4.0, 6.0]), "Force (N)": np.array([1.0, 1.0, 1.0])}
    np.testing.assert_allclose(ev("run/x1*1e-3", env), env["run/x1"] * 1e-3)  # the file's name wins
    np.testing.assert_allclose(ev("s.force / 2", env), [1.0, 2.0, 3.0])
    np.testing.assert_allclose(ev("`Force (N)`*9.81", env), [9.81] * 3)
    np.testing.assert_allclose(ev("run*2", env), [20.0] * 3)  # a prefix alone is its own variable


@pytest.mark.parametrize("text, fragment", [
    ("__import__('os').remove('x')", "not allowed"),
    ("a.real", "not allowed"),
    ("a[0]", "not allowed"),
    ("open('x')", "call of 'open'"),
    ("lambda: 1", "not allowed"),
    ("a if a else a", "not allowed"),
    ("a < 1", "not allowed"),
    ("'text'", "not allowed"),
    ("a ^ 2", "operator BitXor"),
    ("True", "not allowed"),
])
def test_forbidden_constructs_are_refused_before_anything_runs(text, fragment):
    with pytest.raises(InputError) as info:
        Expression.parse(text, ["a"], "f.mat", "--map x1")
    msg = str(info.value)
    assert "f.mat" in msg and "--map x1" in msg and fragment in msg, msg


def test_syntax_error_and_missing_variable_name_the_map():
    with pytest.raises(InputError) as info:
        Expression.parse("a *", ["a"], "f.mat", "--map x1")
    assert "syntax error" in str(info.value) and "--map x1" in str(info.value)
    with pytest.raises(InputError) as info:
        ev("F_over_mg * 2", {"Fmg": np.ones(3)})
    assert "no variable 'F_over_mg'" in str(info.value) and "Fmg" in str(info.value)


# -- readers ---------------------------------------------------------------------------------------------

def write_mat_v73(path: Path, arrays: dict[str, np.ndarray], struct: dict[str, np.ndarray] | None = None) -> Path:
    """As MATLAB writes v7.3: HDF5, column-major (a 1xN vector stored as shape (N, 1)... transposed), a
    MATLAB_class on every dataset, structs as groups, and a char array that is not data."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for name, x in arrays.items():
            ds = f.create_dataset(name, data=np.asarray(x, dtype=float).reshape(1, -1))
            ds.attrs["MATLAB_class"] = np.bytes_("double")
        if struct:
            g = f.create_group("meas")
            g.attrs["MATLAB_class"] = np.bytes_("struct")
            for name, x in struct.items():
                ds = g.create_dataset(name, data=np.asarray(x, dtype=float).T)  # n x k in MATLAB -> (k, n)
                ds.attrs["MATLAB_class"] = np.bytes_("double")
        c = f.create_dataset("operator", data=np.frombuffer(b"a\x00n\x00n\x00", dtype=np.uint16).reshape(-1, 1))
        c.attrs["MATLAB_class"] = np.bytes_("char")
    with open(path, "r+b") as fh:  # MATLAB's 128-byte text header in the user block
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(116, b" "))
    return path


def test_mat_v5_structs_matrices_scalars(tmp_path):
    path = tmp_path / "rec.mat"
    scipy.io.savemat(path, {"t": T.reshape(-1, 1), "F_over_mg": F_OVER_MG, "gain": 2.5,
                            "s": {"a": T * 2, "m": np.column_stack([T, -T])}, "note": "run 3"})
    src = read_source(path)
    assert src.kind == "mat-v5"
    np.testing.assert_allclose(src.variables["t"], T)
    np.testing.assert_allclose(src.variables["s.a"], T * 2)
    np.testing.assert_allclose(src.variables["s.m_2"], -T)
    assert src.scalars == {"gain": 2.5} and "note" in src.skipped


def test_mat_v73_is_read_through_hdf5_transposed_back(tmp_path):
    path = write_mat_v73(tmp_path / "rec.mat", {"t": T, "F_over_mg": F_OVER_MG},
                         struct={"pair": np.column_stack([T, 2 * T])})
    src = read_source(path)
    assert src.kind == "mat-v7.3"
    np.testing.assert_allclose(src.variables["F_over_mg"], F_OVER_MG)
    np.testing.assert_allclose(src.variables["meas.pair_2"], 2 * T)
    assert src.skipped == {"operator": "MATLAB char"}


def test_text_whitespace_header_with_units_and_gaps(tmp_path):
    path = tmp_path / "rec.txt"
    lines = ["% exported by the lab's logger", "time Force (N) disp [mm]"]
    lines += [f"{t:.4f} {10 * f:.3f} {'NaN' if i == 5 else f'{t * 3:.4f}'}" for i, (t, f) in
              enumerate(zip(T, F_OVER_MG))]
    path.write_text("\n".join(lines) + "\n")
    src = read_source(path)
    assert list(src.variables) == ["time", "Force", "disp"] and src.units == {"Force": "N", "disp": "mm"}
    assert np.isnan(src.variables["disp"][5]) and src.variables["disp"][6] == pytest.approx(T[6] * 3, abs=1e-4)


def test_text_without_header_gets_numbered_columns(tmp_path):
    path = tmp_path / "rec.tsv"
    path.write_text("\n".join(f"{f}\t{2 * f}" for f in F_OVER_MG) + "\n")
    src = read_source(path)
    assert list(src.variables) == ["col1", "col2"]
    np.testing.assert_allclose(src.variables["col2"], 2 * F_OVER_MG)


# -- daq import through the command line -----------------------------------------------------------------

def test_import_mat_with_maps_stores_channels_map_and_kept_variables(tmp_path, capsys):
    """The spring-slider record of issue 14: t and F/mg only; x1 derived from the spring force, vb constant."""
    src = tmp_path / "slider.mat"
    scipy.io.savemat(src, {"t": T, "F_over_mg": F_OVER_MG, "mass": 0.2})
    out = tmp_path / "slider.h5"
    code, err = run("import", src, "--rig", "belt-ndof", "--map", "x1=F_over_mg*mass*9.81/200",
                    "--map", "vb=5e-5", "-o", out, capsys=capsys)
    assert code == 0, err
    rec = read_recording(out)
    np.testing.assert_allclose(rec.t, T)
    np.testing.assert_allclose(rec.channels["x1"], F_OVER_MG * 0.2 * 9.81 / 200)
    np.testing.assert_allclose(rec.channels["vb"], 5e-5)
    np.testing.assert_allclose(rec.channels["F_over_mg"], F_OVER_MG)  # unmapped variables are kept
    with h5py.File(out) as f:
        assert json.loads(f.attrs["import_map"]) == {"x1": "F_over_mg*mass*9.81/200", "vb": "5e-5"}
        assert f.attrs["import_time"] == "t" and f.attrs["source_format"] == "mat-v5"
        assert json.loads(f.attrs["import_scalars"]) == {"mass": 0.2}


def test_import_v73_with_rate_and_text_with_time_expression(tmp_path, capsys):
    v73 = write_mat_v73(tmp_path / "r73.mat", {"pos_mm": 1e3 * F_OVER_MG})
    out = tmp_path / "a.h5"
    code, err = run("import", v73, "--rig", "belt-ndof", "--rate", "200", "--map", "x1=pos_mm/1000",
                    "--map", "vb=0.05", "-o", out, capsys=capsys)
    assert code == 0, err
    rec = read_recording(out)
    np.testing.assert_allclose(rec.t, T, atol=1e-12)
    np.testing.assert_allclose(rec.channels["x1"], F_OVER_MG)

    txt = tmp_path / "r.csv"
    txt.write_text("time_ms,x1,vb\n" + "\n".join(f"{1e3 * t:.3f},{f},{0.05}" for t, f in zip(T, F_OVER_MG)))
    out2 = tmp_path / "b.h5"
    code, err = run("import", txt, "--rig", "belt-ndof", "--time", "time_ms/1000", "-o", out2, capsys=capsys)
    assert code == 0, err
    rec = read_recording(out2)
    np.testing.assert_allclose(rec.t, T, atol=1e-9)
    np.testing.assert_allclose(rec.channels["x1"], F_OVER_MG)  # a column already named as the channel


def test_import_tdms_map_over_group_channel_names(tmp_path, capsys):
    path = tmp_path / "r.tdms"
    props = {"wf_increment": 1 / 200.0, "wf_start_offset": 0.0}
    with TdmsWriter(path) as w:
        w.write_segment([RootObject(), GroupObject("rig"), ChannelObject("rig", "pos", 1e3 * F_OVER_MG, props),
                         ChannelObject("rig", "belt", np.full(N, 0.05), props)])
    out = tmp_path / "t.h5"
    code, err = run("import", path, "--rig", "belt-ndof", "--map", "x1=rig/pos*1e-3", "--map", "vb=rig/belt",
                    "-o", out, capsys=capsys)
    assert code == 0, err
    rec = read_recording(out)
    np.testing.assert_allclose(rec.t, T)
    np.testing.assert_allclose(rec.channels["x1"], F_OVER_MG)
    assert "rig.pos" in rec.channels  # kept, '/' -> '.'


@pytest.mark.parametrize("options, field, fragment", [
    (["--map", "x1=F_over_mgg*2", "--map", "vb=1"], "--map x1", "no variable 'F_over_mgg'"),
    (["--map", "x1=F_over_mg*", "--map", "vb=1"], "--map x1", "syntax error"),
    (["--map", "x1=__import__('os').getcwd()", "--map", "vb=1"], "--map x1", "not allowed"),
    (["--map", "x1", "--map", "vb=1"], "--map x1", "CHANNEL=EXPR"),
    (["--map", "t=F_over_mg", "--map", "vb=1"], "--map t", "cannot be a channel name"),
    (["--map", "x1=F_over_mg"], "vb", "missing column required"),
    (["--time", "tt", "--map", "x1=F_over_mg", "--map", "vb=1"], "--time tt", "strictly increasing"),
    (["--rate", "-5", "--map", "x1=F_over_mg", "--map", "vb=1"], "--rate", "> 0"),
])
def test_bad_maps_and_times_one_line_exit_2_no_file(tmp_path, capsys, options, field, fragment):
    src = tmp_path / "bad.mat"
    tt = T.copy()
    tt[50] = tt[49]  # a time vector that stalls
    scipy.io.savemat(src, {"t": T, "tt": tt, "F_over_mg": F_OVER_MG})
    out = tmp_path / "out.h5"
    code, err = run("import", src, "--rig", "belt-ndof", *options, "-o", out, capsys=capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert str(src) in lines[0] and field in lines[0] and fragment in lines[0], lines[0]
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["bad.mat"]


def test_bad_files_one_line_exit_2(tmp_path, capsys):
    garbage = tmp_path / "g.mat"
    garbage.write_bytes(b"MATLAB 5.0 MAT-file" + bytes(range(256)) * 4)
    code, err = run("import", garbage, "--rig", "belt-ndof", "--rate", "100", "-o", tmp_path / "o.h5",
                    capsys=capsys)
    assert code == 2 and "g.mat" in err and "(file)" in err and len(err.strip().splitlines()) == 1, err
    ragged = tmp_path / "r.txt"
    ragged.write_text("a b\n1 2\n3\n")
    code, err = run("import", ragged, "--rig", "belt-ndof", "--rate", "100", "-o", tmp_path / "o.h5",
                    capsys=capsys)
    assert code == 2 and "line 3" in err, err
    words = tmp_path / "w.txt"
    words.write_text("a b\n1 2\n3 fast\n")
    code, err = run("import", words, "--rig", "belt-ndof", "--rate", "100", "-o", tmp_path / "o.h5",
                    capsys=capsys)
    assert code == 2 and "b (line 3)" in err and "'fast'" in err, err
    assert not (tmp_path / "o.h5").exists()


def test_a_rig_file_with_a_negative_mass_names_file_and_field(tmp_path, capsys):
    rig = tmp_path / "my-rig.toml"
    text = (Path(__file__).resolve().parents[1] / "rig_configs" / "belt-ndof.toml").read_text()
    assert "mass_kg = 0.5" in text
    rig.write_text(text.replace("mass_kg = 0.5", "mass_kg = -0.5", 1))
    src = tmp_path / "s.mat"
    scipy.io.savemat(src, {"t": T, "F_over_mg": F_OVER_MG})
    code, err = run("import", src, "--rig", rig, "--map", "x1=F_over_mg", "--map", "vb=1", "-o",
                    tmp_path / "o.h5", capsys=capsys)
    assert code == 2 and "my-rig.toml" in err and "mass_kg" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "o.h5").exists()
