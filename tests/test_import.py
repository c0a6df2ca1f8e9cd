"""Import of interchange CSV and LabVIEW TDMS files into the run format, export back to CSV, and bad input."""

from __future__ import annotations

import tomllib
from pathlib import Path

import h5py
import numpy as np
import pytest
from nptdms import ChannelObject, GroupObject, RootObject, TdmsFile, TdmsWriter

from daq.errors import InputError
from daq.io.importer import export_csv, import_file, is_si, required_channels
from daq.io.interchange import FORMAT_RUN, read_csv, read_recording
from daq.io.runfile import RunWriter
from daq.io.stream_format import StreamMeta, make_block

N = 200
COLS = ["x1", "phi", "vb", "vb_set", "temp", "extra"]
BRAKE_UNITS = {"x1": "m", "phi": "rad", "vb": "m/s", "vb_set": "m/s", "temp": "degC"}


def columns() -> dict[str, np.ndarray]:
    """Interchange columns with values that print exactly in 9 significant digits."""
    k = np.arange(N)
    return {"t": k * 0.001 + 10.0, "x1": np.round(1e-3 * np.sin(k / 7.0), 9),
            "phi": np.round(0.01 * np.cos(k / 5.0), 9), "vb": np.round(0.17 - k * 1e-5, 9),
            "vb_set": 0.17 - k * 1e-5, "temp": 22.0 + k * 0.25, "extra": k.astype(float)}


def write_csv_file(path: Path, cols: dict[str, np.ndarray], header: list[str] | None = None) -> Path:
    names = list(cols)
    lines = [",".join(header or names)]
    lines += [",".join(f"{cols[n][i]:.9g}" for n in names) for i in range(N)]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_tdms(path: Path, cols: dict[str, np.ndarray], units: dict[str, str] | None = None,
               props: dict[str, object] | None = None, group: str = "run", extra_objects: list = ()) -> Path:
    units = units if units is not None else {"t": "s", **BRAKE_UNITS}
    chans = [ChannelObject(group, name, x, properties={**({"unit_string": units[name]} if name in units else {}),
                                                        **(props or {})})
             for name, x in cols.items()]
    with TdmsWriter(str(path)) as w:
        w.write_segment([RootObject(properties={"name": "rig run"}), GroupObject(group), *chans, *extra_objects])
    return path


def listing(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir())


def expect_error(src: Path, rig: str, out: Path, field: str, *fragments: str) -> InputError:
    """import_file fails with one line 'SOURCE: FIELD: message' and leaves no output behind."""
    before = listing(out.parent)
    with pytest.raises(InputError) as info:
        import_file(src, rig, out)
    err = info.value
    assert "\n" not in str(err)
    assert (err.source, err.field) == (str(src), field), str(err)
    assert str(err) == f"{src}: {field}: {err.message}"
    for frag in fragments:
        assert frag in err.message, (frag, str(err))
    assert listing(out.parent) == before  # no output, no .part file
    return err


# ---------------------------------------------------------------- CSV


def test_csv_import_export_round_trip(tmp_path):
    cols = columns()
    src = write_csv_file(tmp_path / "in.csv", cols)
    out = import_file(src, "brake-2dof", tmp_path / "run.h5")
    rec = read_recording(out)
    original = read_csv(src)
    np.testing.assert_array_equal(rec.t, original.t)  # times kept as in the file
    assert list(rec.channels) == COLS
    for name in COLS:
        np.testing.assert_array_equal(rec.channels[name], original.channels[name])
    assert rec.units == {**BRAKE_UNITS, "extra": ""}
    assert rec.rig == "brake-2dof"
    assert rec.meta["format"] == FORMAT_RUN and rec.meta["source_format"] == "csv"
    assert [e["kind"] for e in rec.events] == ["import"] and rec.events[0]["t"] == 10.0
    with h5py.File(out, "r") as f:  # a clean, plain HDF5 file
        assert tomllib.loads(f.attrs["rig_config"])["rig"] == "brake-2dof"
        assert f["streams/import/x1"].attrs["unit"] == "m"
        assert f["streams/import"].attrs["rate_hz"] == pytest.approx(1000.0)

    csv_out = export_csv(out, tmp_path / "back.csv")
    assert csv_out.read_text().splitlines()[0] == "t," + ",".join(COLS)
    back = read_csv(csv_out)
    np.testing.assert_array_equal(back.t, original.t)
    for name in COLS:
        np.testing.assert_array_equal(back.channels[name], original.channels[name])
    assert listing(tmp_path) == ["back.csv", "in.csv", "run.h5"]


def test_csv_header_units_in_brackets_are_checked_and_stripped(tmp_path):
    cols = columns()
    header = ["t", "x1 [m]", "phi (rad)", "vb [m/s]", "vb_set", "temp [°C]", "extra [V]"]
    src = write_csv_file(tmp_path / "units.csv", cols, header)
    rec = read_recording(import_file(src, "brake-2dof", tmp_path / "u.h5"))
    assert list(rec.channels) == COLS
    assert rec.units == {**BRAKE_UNITS, "extra": "V"}


def test_csv_missing_required_column(tmp_path):
    cols = columns()
    del cols["phi"]
    src = write_csv_file(tmp_path / "nophi.csv", cols)
    expect_error(src, "brake-2dof", tmp_path / "o.h5", "phi", "missing column required for brake-2dof",
                 "t, x1, phi, vb")


def test_csv_non_numeric_cell(tmp_path):
    cols = columns()
    src = write_csv_file(tmp_path / "text.csv", cols)
    lines = src.read_text().splitlines()
    lines[3] = lines[3].replace(lines[3].split(",")[3], "fast", 1)
    src.write_text("\n".join(lines) + "\n")
    expect_error(src, "brake-2dof", tmp_path / "o.h5", "vb (line 4)", "not a number", "'fast'")


@pytest.mark.parametrize(("header", "field", "unit"), [("x1 [mm]", "x1", "'mm'"), ("phi [deg]", "phi", "'deg'"),
                                                       ("temp [K]", "temp", "'K'"), ("vb [km/h]", "vb", "'km/h'")])
def test_csv_wrong_unit(tmp_path, header, field, unit):
    cols = columns()
    names = list(cols)
    names[names.index(field)] = header
    src = write_csv_file(tmp_path / "mm.csv", cols, names)
    expect_error(src, "brake-2dof", tmp_path / "o.h5", field, unit, "SI unit")


def test_csv_first_column_must_be_t(tmp_path):
    cols = columns()
    names = list(cols)
    names[0] = "time"
    src = write_csv_file(tmp_path / "time.csv", cols, names)
    expect_error(src, "brake-2dof", tmp_path / "o.h5", "t", "first column")


def test_belt_and_drum_required_columns(tmp_path, belt_cfg, drum_cfg):
    assert required_channels(belt_cfg) == ["x1", "vb"]  # one mass in the shipped config
    assert required_channels(drum_cfg) == ["phi", "force_a", "thrust", "accel", "vel", "drum_speed", "drum_rev", "temp"]
    k = np.arange(N, dtype=float)
    belt = write_csv_file(tmp_path / "belt.csv", {"t": k * 0.01, "x1": k * 1e-4, "vb": k * 1e-3})  # plausible values
    rec = read_recording(import_file(belt, "belt-ndof", tmp_path / "belt.h5"))
    assert rec.rig == "belt-ndof" and rec.units == {"x1": "m", "vb": "m/s"}
    expect_error(belt, "drum-pendulum", tmp_path / "drum.h5", "phi", "missing column required for drum-pendulum")


def test_bad_rig_output_and_input_names(tmp_path):
    src = write_csv_file(tmp_path / "in.csv", columns())
    with pytest.raises(InputError) as info:
        import_file(src, "no-such-rig", tmp_path / "o.h5")
    assert info.value.field == "rig"
    with pytest.raises(InputError) as info:
        import_file(src, "brake-2dof", tmp_path / "o.txt")
    assert (info.value.source, info.value.field) == (str(tmp_path / "o.txt"), "-o")
    other = tmp_path / "in.json"
    other.write_text("{}")
    expect_error(other, "brake-2dof", tmp_path / "o.h5", "(file)", "unsupported format")
    expect_error(tmp_path / "absent.csv", "brake-2dof", tmp_path / "o.h5", "(file)", "No such file")
    assert listing(tmp_path) == ["in.csv", "in.json"]


def test_failed_import_keeps_an_existing_output(tmp_path):
    good = write_csv_file(tmp_path / "good.csv", columns())
    out = import_file(good, "brake-2dof", tmp_path / "run.h5")
    before = out.read_bytes()
    cols = columns()
    del cols["vb"]
    bad = write_csv_file(tmp_path / "bad.csv", cols)
    expect_error(bad, "brake-2dof", out, "vb", "missing column")
    assert out.read_bytes() == before


# ---------------------------------------------------------------- TDMS


def test_tdms_with_t_channel_round_trip(tmp_path):
    cols = columns()
    src = write_tdms(tmp_path / "run.tdms", cols)
    rec = read_recording(import_file(src, "brake-2dof", tmp_path / "run.h5"))
    np.testing.assert_array_equal(rec.t, cols["t"])
    assert list(rec.channels) == COLS
    for name in COLS:
        np.testing.assert_array_equal(rec.channels[name], cols[name])
    assert rec.units == {**BRAKE_UNITS, "extra": ""}
    assert rec.meta["source_format"] == "tdms" and rec.meta["tdms_group"] == "run"
    back = read_csv(export_csv(tmp_path / "run.h5", tmp_path / "run.csv"))
    np.testing.assert_allclose(back.channels["x1"], cols["x1"], rtol=5e-9, atol=0)


def test_tdms_with_waveform_timing(tmp_path):
    cols = columns()
    del cols["t"]
    src = write_tdms(tmp_path / "wf.tdms", cols, props={"wf_start_offset": 0.5, "wf_increment": 0.002,
                                                         "wf_samples": N})
    rec = read_recording(import_file(src, "brake-2dof", tmp_path / "wf.h5"))
    expected = TdmsFile.read(src)["run"]["x1"].time_track()
    np.testing.assert_array_equal(rec.t, expected)
    np.testing.assert_allclose(rec.t, 0.5 + 0.002 * np.arange(N), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(rec.channels["phi"], cols["phi"])


def test_tdms_float32_and_integer_channels_become_float64(tmp_path):
    cols = columns()
    cols["x1"] = cols["x1"].astype(np.float32)
    cols["extra"] = np.arange(N, dtype=np.int32)
    src = write_tdms(tmp_path / "mixed.tdms", cols)
    rec = read_recording(import_file(src, "brake-2dof", tmp_path / "mixed.h5"))
    np.testing.assert_array_equal(rec.channels["x1"], cols["x1"].astype(np.float64))
    np.testing.assert_array_equal(rec.channels["extra"], np.arange(N, dtype=float))


@pytest.mark.parametrize(("edit", "extra", "field", "fragment"), [
    pytest.param({"vb": None}, [], "vb", "missing column required", id="missing_required_channel"),
    pytest.param({}, [("run", "comment", ["ok"] * N)], "run/comment", "not numeric",
                 id="string_channel_is_not_numeric"),
    pytest.param({"t": None}, [], "t", "wf_increment", id="without_timing"),
    pytest.param({"temp": slice(None, -5)}, [], "run/temp", f"{N - 5} samples, t has {N}",
                 id="channels_of_different_lengths"),
])
def test_tdms_bad_channels(tmp_path, edit, extra, field, fragment):
    """A channel removed (None) or cut (a slice), or an extra channel object: one error naming it."""
    cols = columns()
    for name, keep in edit.items():
        if keep is None:
            del cols[name]
        else:
            cols[name] = cols[name][keep]
    src = write_tdms(tmp_path / "bad.tdms", cols, extra_objects=[ChannelObject(*o) for o in extra])
    expect_error(src, "brake-2dof", tmp_path / "o.h5", field, fragment)


@pytest.mark.parametrize(("name", "unit"), [("x1", "mm"), ("phi", "deg"), ("t", "ms"), ("vb", "rpm")])
def test_tdms_wrong_unit(tmp_path, name, unit):
    cols = columns()
    units = {"t": "s", **BRAKE_UNITS, name: unit}
    src = write_tdms(tmp_path / "u.tdms", cols, units)
    expect_error(src, "brake-2dof", tmp_path / "o.h5", name, repr(unit))


def test_tdms_two_groups_are_ambiguous(tmp_path):
    cols = columns()
    src = write_tdms(tmp_path / "two.tdms", cols,
                     extra_objects=[GroupObject("other"), ChannelObject("other", "x1", cols["x1"])])
    expect_error(src, "brake-2dof", tmp_path / "o.h5", "(group)", "one group", "'run'", "'other'")


def test_tdms_not_increasing_time(tmp_path):
    cols = columns()
    cols["t"] = cols["t"].copy()
    cols["t"][50] = cols["t"][49]
    src = write_tdms(tmp_path / "t.tdms", cols)
    expect_error(src, "brake-2dof", tmp_path / "o.h5", "t", "strictly increasing")


def test_garbage_tdms(tmp_path):
    src = tmp_path / "junk.tdms"
    src.write_bytes(b"TDSm" + bytes(range(256)) * 4)
    err = expect_error(src, "brake-2dof", tmp_path / "o.h5", "(file)")
    assert "TDMS" in err.message


# ---------------------------------------------------------------- export of a recorder file, units


def test_export_csv_of_a_multi_stream_run(tmp_path):
    path = tmp_path / "rec.h5"
    fast = StreamMeta(stream="can", channels=("x1", "phi"), units=("m", "rad"))
    slow = StreamMeta(stream="motor", channels=("vb",), units=("m/s",))
    w = RunWriter().open(path, None, start_host_time=5.0)
    t = 5.0 + np.arange(10) * 0.125
    w.append(make_block(fast, 0, t, np.column_stack([t, -t])))
    w.append(make_block(slow, 0, t[2:6], 2 * t[2:6, None]))
    w.close()
    back = read_csv(export_csv(path, tmp_path / "rec.csv"))
    np.testing.assert_array_equal(back.t, np.arange(10) * 0.125)
    assert list(back.channels) == ["x1", "phi", "vb"]
    vb = back.channels["vb"]
    assert np.all(np.isnan(vb[[0, 1, 6, 7, 8, 9]]))
    np.testing.assert_array_equal(vb[2:6], 2 * t[2:6])
    with pytest.raises(InputError) as info:
        export_csv(path, tmp_path / "rec.h5.txt")
    assert info.value.field == "-o"


@pytest.mark.parametrize(("unit", "canonical", "ok"), [
    ("", "m", True), (None, "m", True), ("m", "m", True), (" metre ", "m", True),
    ("mm", "m", False), ("m/s", "m/s", True), ("m s^-1", "m/s", True), ("°C", "degC", True), ("C", "degC", True),
    ("K", "degC", False), ("rad", "rad", True), ("deg", "rad", False), ("m/s2", "m/s^2", True), ("g", "m/s^2", False),
    ("counts", "count", True), ("N", "N", True), ("kN", "N", False), ("rad/s", "rad/s", True), ("rpm", "rad/s", False)])
def test_si_units(unit, canonical, ok):
    assert is_si(unit, canonical) is ok
