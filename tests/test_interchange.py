"""Interchange files: CSV and HDF5 round trips, atomic writes, and one-line errors for bad CSVs."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from helpers import expect_error, expect_read_error, write

from daq.errors import InputError
from daq.io.interchange import (
    Recording,
    atomic_path,
    read_csv,
    read_h5,
    read_recording,
    write_csv,
    write_h5,
    write_recording,
)

N = 7


def make_recording() -> Recording:
    t = np.arange(N) * 1e-3
    channels = {
        "x1": np.array([0.0, 1e-6, -2.5e-6, 1.0 / 3.0, 12345.6789012345, -7.77e-12, 3.0e8]),
        "phi": np.sin(np.linspace(0.0, 1.0, N)),
        "vb": 0.17 * (1.0 - t / 45.0),
    }
    units = {"x1": "m", "phi": "rad", "vb": "m/s"}
    meta = {
        "source": "simulation",
        "seed": 42,
        "rate_Hz": 1000.0,
        "noise": True,
        "effects": {"accel-sign": {"amp": 0.15}},
        "ramp_table": [[0.0, 0.17], [45.0, 0.0]],
        "rig_config": 'rig = "brake-2dof"\n[mechanics]\nM_kg = 0.14027\n',
    }
    truth = {"x1": channels["x1"] * 0.5, "vrel": np.linspace(-1.0, 1.0, N)}
    return Recording("brake-2dof", t, channels, units, meta, truth)


def printed(x: np.ndarray) -> np.ndarray:
    """The values as write_csv prints them (9 significant digits)."""
    return np.array([float(f"{v:.9g}") for v in x])




def bad_csv(tmp_path: Path, text: str) -> tuple[Path, InputError]:
    path = write(tmp_path, "bad.csv", text)
    with pytest.raises(InputError) as info:
        read_csv(path)
    return path, info.value


# ---------------------------------------------------------------- CSV round trip


def test_csv_header_is_t_then_channels_in_order(tmp_path):
    path = tmp_path / "run.csv"
    write_recording(make_recording(), path)
    lines = path.read_text().splitlines()
    assert lines[0] == "t,x1,phi,vb"
    assert len(lines) == 1 + N
    assert lines[1].split(",")[0] == "0"


def test_csv_round_trip_to_printed_precision(tmp_path):
    rec = make_recording()
    path = tmp_path / "run.csv"
    write_recording(rec, path)
    back = read_recording(path)
    np.testing.assert_array_equal(back.t, printed(rec.t))
    assert list(back.channels) == ["x1", "phi", "vb"]
    for name, x in rec.channels.items():
        np.testing.assert_array_equal(back.channels[name], printed(x))
        np.testing.assert_allclose(back.channels[name], x, rtol=5e-9, atol=0)
    assert back.truth == {}
    assert back.rig is None and back.units == {} and back.meta == {}


def test_csv_with_truth_columns_round_trips_them_separately(tmp_path):
    rec = make_recording()
    path = tmp_path / "run.csv"
    write_recording(rec, path, truth_in_csv=True)
    assert path.read_text().splitlines()[0] == "t,x1,phi,vb,truth_x1,truth_vrel"
    back = read_csv(path)
    assert list(back.channels) == ["x1", "phi", "vb"]
    assert list(back.truth) == ["x1", "vrel"]
    for name, x in rec.truth.items():
        np.testing.assert_array_equal(back.truth[name], printed(x))


def test_csv_keeps_nan_samples_of_a_channel(tmp_path):
    rec = make_recording()
    rec.channels["phi"][3] = np.nan  # a dropout is data, not an error
    path = tmp_path / "run.csv"
    write_csv(rec, path)
    back = read_csv(path)
    assert np.isnan(back.channels["phi"][3])
    assert np.isnan(back.channels["phi"]).sum() == 1


def test_csv_reader_strips_header_spaces_and_skips_blank_lines(tmp_path):
    path = write(tmp_path, "hand.csv", " t , force \n0,1.5\n\n0.5,2.5\n1.0,-1\n")
    back = read_csv(path)
    assert back.t.tolist() == [0.0, 0.5, 1.0]
    assert list(back.channels) == ["force"]
    assert back.channels["force"].tolist() == [1.5, 2.5, -1.0]


# ---------------------------------------------------------------- HDF5 round trip


@pytest.mark.parametrize("suffix", [".h5", ".hdf5"])
def test_h5_round_trip_is_exact_with_units_and_meta(tmp_path, suffix):
    rec = make_recording()
    path = tmp_path / f"run{suffix}"
    write_recording(rec, path)
    back = read_recording(path)
    assert back.rig == "brake-2dof"
    np.testing.assert_array_equal(back.t, rec.t)
    assert list(back.channels) == sorted(rec.channels)  # h5py lists members alphabetically
    for name, x in rec.channels.items():
        np.testing.assert_array_equal(back.channels[name], x)
    assert back.units == rec.units
    for name, x in rec.truth.items():
        np.testing.assert_array_equal(back.truth[name], x)
    meta = back.meta
    assert meta["format"] == "friction-daq recording 1"
    assert meta["rig"] == "brake-2dof"
    assert meta["source"] == "simulation"
    assert meta["seed"] == 42
    assert meta["rate_Hz"] == 1000.0
    assert bool(meta["noise"]) is True
    assert meta["rig_config"] == rec.meta["rig_config"]
    assert json.loads(meta["effects"]) == rec.meta["effects"]  # dicts and lists are stored as JSON text
    assert json.loads(meta["ramp_table"]) == rec.meta["ramp_table"]


def test_h5_layout(tmp_path):
    rec = make_recording()
    path = tmp_path / "run.h5"
    write_h5(rec, path)
    with h5py.File(path, "r") as f:
        assert f["t"].dtype == np.float64 and f["t"].attrs["unit"] == "s"
        assert set(f["channels"]) == {"x1", "phi", "vb"}
        assert f["channels/vb"].attrs["unit"] == "m/s"
        assert f["channels/x1"].shape == (N,)
        assert set(f["truth"]) == {"x1", "vrel"}


def test_h5_without_truth_or_rig_or_units(tmp_path):
    t = np.linspace(0.0, 1.0, 5)
    rec = Recording(None, t, {"force": t * 2.0})
    path = tmp_path / "bare.h5"
    write_h5(rec, path)
    back = read_h5(path)
    assert back.rig is None and "rig" not in back.meta
    assert back.truth == {}
    assert back.units == {"force": ""}
    np.testing.assert_array_equal(back.channels["force"], t * 2.0)


def test_h5_keeps_nan_samples(tmp_path):
    rec = make_recording()
    rec.channels["vb"][0] = np.nan
    path = tmp_path / "run.h5"
    write_h5(rec, path)
    back = read_h5(path)
    assert np.isnan(back.channels["vb"][0])
    np.testing.assert_array_equal(back.channels["vb"][1:], rec.channels["vb"][1:])


def test_csv_and_h5_agree(tmp_path):
    rec = make_recording()
    write_recording(rec, tmp_path / "a.csv")
    write_recording(rec, tmp_path / "a.h5")
    c, h = read_recording(tmp_path / "a.csv"), read_recording(tmp_path / "a.h5")
    np.testing.assert_allclose(c.t, h.t, rtol=5e-9, atol=0)
    for name in rec.channels:
        np.testing.assert_allclose(c.channels[name], h.channels[name], rtol=5e-9, atol=0)


# ---------------------------------------------------------------- atomic writes


def listing(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


def wrong_length() -> Recording:
    rec = make_recording()
    rec.channels["phi"] = rec.channels["phi"][:-1]
    return rec


@pytest.mark.parametrize("name", ["run.csv", "run.h5"])
def test_wrong_length_channel_writes_nothing(tmp_path, name):
    with pytest.raises(ValueError, match="phi"):
        write_recording(wrong_length(), tmp_path / name)
    assert listing(tmp_path) == []


def test_wrong_length_truth_writes_nothing(tmp_path):
    rec = make_recording()
    rec.truth["vrel"] = np.zeros(N + 1)
    with pytest.raises(ValueError, match="vrel"):
        write_h5(rec, tmp_path / "run.h5")
    with pytest.raises(ValueError, match="vrel"):
        write_csv(rec, tmp_path / "run.csv", truth=True)
    assert listing(tmp_path) == []


def test_two_dimensional_channel_writes_nothing(tmp_path):
    rec = make_recording()
    rec.channels["xy"] = np.zeros((N, 2))
    for name in ("run.csv", "run.h5"):
        with pytest.raises(ValueError, match="xy"):
            write_recording(rec, tmp_path / name)
    assert listing(tmp_path) == []


def test_unsupported_suffix_writes_nothing(tmp_path):
    path = tmp_path / "run.txt"
    with pytest.raises(InputError) as info:
        write_recording(make_recording(), path)
    expect_error(info.value, str(path), "-o", ".h5", ".csv")
    assert listing(tmp_path) == []


def test_h5_failing_midway_removes_its_part_file(tmp_path):
    rec = make_recording()
    rec.meta["operator"] = None  # h5py cannot store None: fails after the temp file was created
    with pytest.raises(TypeError):
        write_h5(rec, tmp_path / "run.h5")
    assert listing(tmp_path) == []


def test_failed_write_leaves_the_old_file_untouched(tmp_path):
    path = tmp_path / "run.h5"
    write_h5(make_recording(), path)
    before = path.read_bytes()
    rec = make_recording()
    rec.meta["operator"] = None
    with pytest.raises(TypeError):
        write_h5(rec, path)
    assert path.read_bytes() == before
    assert listing(tmp_path) == ["run.h5"]
    csv_path = tmp_path / "run.csv"
    write_csv(make_recording(), csv_path)
    text = csv_path.read_text()
    with pytest.raises(ValueError):
        write_csv(wrong_length(), csv_path)
    assert csv_path.read_text() == text
    assert listing(tmp_path) == ["run.csv", "run.h5"]


def test_successful_write_replaces_and_leaves_no_part_file(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text("old contents\n")
    write_csv(make_recording(), path)
    assert path.read_text().startswith("t,x1,phi,vb\n")
    assert listing(tmp_path) == ["run.csv"]


def test_write_creates_missing_directories(tmp_path):
    path = tmp_path / "a" / "b" / "run.h5"
    write_recording(make_recording(), path)
    assert path.is_file()
    assert listing(path.parent) == ["run.h5"]


def test_atomic_path_uses_a_part_file_beside_the_target(tmp_path):
    target = tmp_path / "out.bin"
    with atomic_path(target) as tmp:
        assert tmp.parent == tmp_path
        assert tmp.name.startswith(".out.bin.") and tmp.name.endswith(".part")
        assert tmp.exists() and not target.exists()
        tmp.write_bytes(b"done")
    assert target.read_bytes() == b"done"
    assert listing(tmp_path) == ["out.bin"]


def test_atomic_path_discards_on_error(tmp_path):
    target = tmp_path / "out.bin"
    with pytest.raises(RuntimeError, match="midway"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("midway")
    assert listing(tmp_path) == []


# ---------------------------------------------------------------- bad CSV input


@pytest.mark.parametrize(("text", "field", "fragments"), [
    pytest.param("time,x\n0,1\n1,2\n", "t", ("first column", "'time'"), id="first_column_not_t"),
    pytest.param("t,x1,vb\n0,1,0.1\n0.5,2,0.1\n1,3,fast\n", "vb (line 4)", ("not a number", "'fast'"),
                 id="non_numeric_cell_names_column_and_line"),
    pytest.param("t,x\n0,1\n\n1,abc\n", "x (line 4)", ("'abc'",), id="non_numeric_line_number_counts_blank_lines"),
    pytest.param("t,x\n0,1\n1 s,2\n", "t (line 3)", ("'1 s'",), id="non_numeric_time"),
    pytest.param("t,x,y,x\n0,1,2,3\n1,2,3,4\n", "x", ("duplicate",), id="duplicate_column"),
    pytest.param("", "(header)", ("empty",), id="empty_file"),
])
def test_bad_csv_is_one_error_naming_the_column(tmp_path, text, field, fragments):
    path, err = bad_csv(tmp_path, text)
    expect_error(err, str(path), field, *fragments)


@pytest.mark.parametrize(("row", "count"), [("1", 1), ("1,2,3", 3)])
def test_ragged_row(tmp_path, row, count):
    path, err = bad_csv(tmp_path, f"t,x\n0,1\n{row}\n2,3\n")
    expect_error(err, str(path), "line 3", f"{count} fields, header has 2")


@pytest.mark.parametrize("rows", ["0,1\n1,2\n1,3\n", "0,1\n2,2\n1,3\n", "0,1\n", "", "0,1\nnan,2\n3,3\n",
                                  "0,1\n1,2\ninf,3\n"])
def test_t_not_strictly_increasing_or_too_few_rows(tmp_path, rows):
    path, err = bad_csv(tmp_path, "t,x\n" + rows)
    expect_error(err, str(path), "t", "strictly increasing")


def test_missing_csv(tmp_path):
    path = tmp_path / "absent.csv"
    expect_read_error(read_csv, path, "(file)", "No such file")


# ---------------------------------------------------------------- bad HDF5 input, unknown formats


def test_not_an_h5_file(tmp_path):
    path = write(tmp_path, "fake.h5", "t,x\n0,1\n")
    expect_read_error(read_h5, path, "(file)")  # one line naming the file


@pytest.mark.parametrize("missing", ["t", "channels"])
def test_h5_missing_dataset(tmp_path, missing):
    path = tmp_path / "partial.h5"
    with h5py.File(path, "w") as f:
        if missing != "t":
            f.create_dataset("t", data=np.arange(3.0))
        if missing != "channels":
            f.create_group("channels").create_dataset("x", data=np.arange(3.0))
    expect_read_error(read_h5, path, missing, "missing dataset")


def test_read_unknown_format(tmp_path):
    path = write(tmp_path, "run.mat", "")
    expect_read_error(read_recording, path, "(file)", "unsupported format")


def test_written_files_get_normal_permissions(tmp_path):
    """Atomic writes go through mkstemp (0600); the result must look like any other file (0666 & ~umask)."""
    import os

    umask = os.umask(0)
    os.umask(umask)
    path = tmp_path / "run.csv"
    write_csv(make_recording(), path)
    assert (path.stat().st_mode & 0o777) == (0o666 & ~umask)


def test_a_binary_file_named_csv_is_one_error_not_a_traceback(tmp_path):
    """An HDF5 (or MAT) file renamed .csv: the reader used to end in a UnicodeDecodeError traceback in `daq import`,
    `compare` and `diagnose` (issue 16); a NUL byte in a text cell is a bad number like any other."""
    path = tmp_path / "run.csv"
    path.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(range(256)) * 4)
    expect_read_error(read_csv, path, "(byte 0)", "not a UTF-8 text file", "binary")
    nul = tmp_path / "nul.csv"
    nul.write_bytes(b"t,x1\n0,1\n0.1,\x002\n")
    expect_read_error(read_csv, nul, "x1 (line 3)", "not a number")
