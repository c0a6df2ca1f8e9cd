"""Rig config loading: the shipped configs load, and every bad config is one InputError naming file and field."""

from __future__ import annotations

import copy
import os
import tomllib
from pathlib import Path

import pytest
import tomli_w
from helpers import expect_error, expect_read_error
from pydantic import ValidationError

from daq.config import CONFIG_DIR, BeltRig, BrakeRig, DrumRig, config_text, load_rig, parse_rig, rig_ids
from daq.errors import InputError

RIGS = {"belt-ndof": BeltRig, "brake-2dof": BrakeRig, "drum-pendulum": DrumRig}


def rig_data(rig: str) -> dict:
    return tomllib.loads((CONFIG_DIR / f"{rig}.toml").read_text())


def write_cfg(tmp_path: Path, data: dict, name: str = "rig.toml") -> Path:
    path = tmp_path / name
    path.write_text(tomli_w.dumps(data))
    return path



def load_bad(tmp_path: Path, data: dict) -> InputError:
    path = write_cfg(tmp_path, data)
    with pytest.raises(InputError) as info:
        load_rig(path)
    assert info.value.source == str(path)
    return info.value


# ---------------------------------------------------------------- good configs


def test_rig_ids_lists_the_shipped_configs_sorted():
    assert rig_ids() == ["belt-ndof", "brake-2dof", "drum-pendulum"]
    assert rig_ids() == sorted(p.stem for p in CONFIG_DIR.glob("*.toml"))


@pytest.mark.parametrize("rig", sorted(RIGS))
def test_every_rig_loads_by_id_as_its_model(rig):
    cfg = load_rig(rig)
    assert type(cfg) is RIGS[rig]
    assert cfg.rig == rig
    assert cfg.channels, "a rig without channels measures nothing"


@pytest.mark.parametrize("rig", sorted(RIGS))
def test_load_by_path_equals_load_by_id(rig):
    path = CONFIG_DIR / f"{rig}.toml"
    assert load_rig(path) == load_rig(rig)
    assert load_rig(str(path)) == load_rig(rig)


@pytest.mark.parametrize("rig", sorted(RIGS))
def test_copy_written_with_tomli_w_loads_identically(tmp_path, rig):
    path = write_cfg(tmp_path, rig_data(rig), f"copy-{rig}.toml")
    assert load_rig(path) == load_rig(rig)


@pytest.mark.parametrize("rig", sorted(RIGS))
def test_config_text_reparses_to_the_same_config(rig):
    cfg = load_rig(rig)
    assert parse_rig(tomllib.loads(config_text(cfg)), "stored") == cfg


def test_brake_values_are_paper_001():
    cfg = load_rig("brake-2dof")
    assert cfg.paper == "001"
    assert cfg.drive.ramp == "seed"
    assert cfg.drive.V0_m_per_s == 0.17
    assert cfg.drive.Tmax_s == 45.0
    m = cfg.mechanics
    assert (m.M_kg, m.m_kg, m.J_kg_m2, m.r_m) == (0.14027, 0.1052, 2.4423e-4, 0.078)
    assert (m.k1_N_per_m, m.k2_N_per_m, m.k3_N_per_m) == (367.0, 76.0, 69.0)
    f = cfg.friction
    assert (f.law, f.mu0, f.gamma_s_per_m, f.alpha_s_per_m, f.beta) == ("brake-eq7", 0.5, 3.0, 200.0, 0.7)
    assert set(cfg.channels) == {"x1", "phi", "vb", "vb_set", "temp"}
    assert cfg.channels["phi"].unit == "rad"
    assert cfg.seed_effects["viscous-damping"] == {"c1": 0.0156, "c2": 0.0}


def test_drum_and_belt_key_values():
    drum = load_rig("drum-pendulum")
    assert drum.mechanics.thrust_N == 28.539
    assert drum.friction.law == "drum-eq3" and drum.friction.A == 0.3185
    assert drum.drive.kind == "drum" and drum.drive.Tmax_s is None
    belt = load_rig("belt-ndof")
    assert belt.mechanics.n_masses == 1
    assert belt.friction.f_s0 == 1.33


def test_omitted_optional_fields_take_their_defaults():
    cfg = load_rig("brake-2dof")
    vb_set = cfg.channels["vb_set"]  # the TOML gives only unit, instrument, description
    assert (vb_set.noise_std, vb_set.lsb, vb_set.offset, vb_set.rate_Hz) == (0.0, 0.0, 0.0, None)
    data = rig_data("brake-2dof")
    del data["effects"], data["seed_effects"], data["chosen"]
    cfg2 = parse_rig(data, "mem")
    assert cfg2.effects == {} and cfg2.seed_effects == {} and cfg2.chosen == []


def test_config_is_frozen():
    cfg = load_rig("brake-2dof")
    with pytest.raises(ValidationError):
        cfg.mechanics.k1_N_per_m = 1.0  # type: ignore[misc]


# ---------------------------------------------------------------- bad configs: fields


def test_typo_in_mechanics_names_the_unknown_field(tmp_path):
    data = rig_data("brake-2dof")
    data["mechanics"]["k1_N_per_mm"] = 0.367
    err = load_bad(tmp_path, data)
    expect_error(err, err.source, "mechanics.k1_N_per_mm", "Extra inputs are not permitted")


def test_renamed_key_is_reported_not_silently_defaulted(tmp_path):
    data = rig_data("brake-2dof")
    data["mechanics"]["k1_N_per_mm"] = data["mechanics"].pop("k1_N_per_m")
    err = load_bad(tmp_path, data)
    assert err.field in ("mechanics.k1_N_per_m", "mechanics.k1_N_per_mm")
    assert "\n" not in str(err)


def test_unknown_top_level_table(tmp_path):
    data = rig_data("drum-pendulum")
    data["mechanic"] = {"m_kg": 1.0}
    err = load_bad(tmp_path, data)
    expect_error(err, err.source, "mechanic", "Extra inputs are not permitted")


def test_negative_stiffness(tmp_path):
    data = rig_data("brake-2dof")
    data["mechanics"]["k1_N_per_m"] = -367.0
    err = load_bad(tmp_path, data)
    expect_error(err, err.source, "mechanics.k1_N_per_m", "greater than or equal to 0")


@pytest.mark.parametrize(
    ("rig", "section", "key", "value", "field", "fragment"),
    [
        ("drum-pendulum", "mechanics", "k_N_per_m", -3000.0, "mechanics.k_N_per_m", "greater than 0"),
        ("belt-ndof", "mechanics", "stiffness_N_per_m", 0.0, "mechanics.stiffness_N_per_m", "greater than 0"),
        ("belt-ndof", "mechanics", "n_masses", 4, "mechanics.n_masses", "less than or equal to 3"),
        ("brake-2dof", "mechanics", "M_kg", 0.0, "mechanics.M_kg", "greater than 0"),
        ("brake-2dof", "mechanics", "M_kg", "heavy", "mechanics.M_kg", "valid number"),
        ("brake-2dof", "friction", "beta", 1.0, "friction.beta", "less than 1"),
        ("brake-2dof", "friction", "law", "drum-eq3", "friction.law", "brake-eq7"),
        ("brake-2dof", "integrator", "dt_s", 0.1, "integrator.dt_s", "less than or equal to 0.01"),
        ("brake-2dof", "drive", "kind", "chain", "drive.kind", "belt"),
        ("brake-2dof", "drive", "V0_m_per_s", -0.17, "drive.V0_m_per_s", "greater than 0"),
        ("brake-2dof", "sensors", "rate_Hz", 0.0, "sensors.rate_Hz", "greater than 0"),
        ("drum-pendulum", "mechanics", "runout", 0.5, "mechanics.runout", "less than 0.5"),
    ],
)
def test_out_of_range_or_wrong_type_values(tmp_path, rig, section, key, value, field, fragment):
    data = rig_data(rig)
    data[section][key] = value
    err = load_bad(tmp_path, data)
    expect_error(err, err.source, field, fragment)


def test_bad_channel_field_names_the_channel(tmp_path):
    data = rig_data("brake-2dof")
    data["channels"]["phi"]["noise_std"] = -2e-4
    err = load_bad(tmp_path, data)
    expect_error(err, err.source, "channels.phi.noise_std", "greater than or equal to 0")


def test_channel_without_unit(tmp_path):
    data = rig_data("belt-ndof")
    del data["channels"]["x1"]["unit"]
    err = load_bad(tmp_path, data)
    expect_error(err, err.source, "channels.x1.unit", "Field required")


@pytest.mark.parametrize("value", [float("inf"), float("-inf"), float("nan")])
def test_non_finite_numbers_are_refused(tmp_path, value):
    data = rig_data("brake-2dof")
    data["contact"]["t_ambient_C"] = value  # no range constraint: only finiteness protects it
    err = load_bad(tmp_path, data)
    expect_error(err, err.source, "contact.t_ambient_C", "finite")


def test_non_finite_effect_value_is_refused(tmp_path):
    data = rig_data("brake-2dof")
    data["effects"]["accel-sign"]["amp"] = float("nan")
    err = load_bad(tmp_path, data)
    expect_error(err, err.source, "effects.accel-sign.amp", "finite")


def test_missing_section(tmp_path):
    data = rig_data("brake-2dof")
    del data["friction"]
    err = load_bad(tmp_path, data)
    expect_error(err, err.source, "friction", "Field required")


def test_sections_of_another_rig(tmp_path):
    data = rig_data("brake-2dof")
    data["rig"] = "drum-pendulum"  # brake mechanics under a drum rig id
    err = load_bad(tmp_path, data)
    assert err.field.startswith(("mechanics.", "friction."))
    assert "\n" not in str(err)


@pytest.mark.parametrize("rig_value", ["brake", 3, None])
def test_bad_or_missing_rig_field(tmp_path, rig_value):
    data = rig_data("brake-2dof")
    if rig_value is None:
        del data["rig"]
    else:
        data["rig"] = rig_value
    err = load_bad(tmp_path, data)
    expect_error(err, err.source, "rig", "brake-2dof", "drum-pendulum", "belt-ndof")


# ---------------------------------------------------------------- bad configs: effects


@pytest.mark.parametrize(("rig", "table", "effect", "params", "field", "fragments"), [
    pytest.param("brake-2dof", "effects", "stick-slip", {"gain": 1.0}, "effects.stick-slip",
                 ("unknown effect", "stick-time"), id="unknown_effect_names_the_effect_field"),
    pytest.param("drum-pendulum", "seed_effects", "friction-heating", {}, "seed_effects.friction-heating",
                 ("unknown effect",), id="unknown_seed_effect_names_the_table"),
    pytest.param("brake-2dof", "effects", "accel-sign", {"ampl": 0.15}, "effects.accel-sign.ampl",
                 ("unknown parameter", "amp"), id="unknown_effect_parameter"),
    # mu1 is the drum's key; brake has torque
    pytest.param("brake-2dof", "effects", "bearing-friction", {"mu1": 0.05}, "effects.bearing-friction.mu1",
                 ("unknown parameter", "torque"), id="parameter_of_the_same_effect_on_another_rig"),
    pytest.param("belt-ndof", "effects", "bearing-friction", {"torque": 0.003}, "effects.bearing-friction",
                 ("does not apply to belt-ndof",), id="effect_that_does_not_apply_to_the_rig"),
    pytest.param("brake-2dof", "seed_effects", "geometric", {"weigth": 1.0}, "seed_effects.geometric.weigth",
                 ("unknown parameter",), id="effect_errors_never_fall_back_to_root"),
])
def test_bad_effect_names_its_field(tmp_path, rig, table, effect, params, field, fragments):
    data = rig_data(rig)
    data[table][effect] = params
    err = load_bad(tmp_path, data)
    assert "(root)" not in str(err)
    expect_error(err, err.source, field, *fragments)


# ---------------------------------------------------------------- bad files


def test_toml_syntax_error(tmp_path):
    path = tmp_path / "broken.toml"
    text = (CONFIG_DIR / "brake-2dof.toml").read_text().replace("M_kg = 0.14027", "M_kg = 0.14027 kg")
    path.write_text(text)
    expect_read_error(load_rig, path, "(syntax)", "line")


def test_missing_file(tmp_path):
    path = tmp_path / "absent.toml"
    expect_read_error(load_rig, path, "(file)", "No such file")


def test_directory_instead_of_file(tmp_path):
    path = tmp_path / "dir.toml"
    path.mkdir()
    expect_read_error(load_rig, path, "(file)")


def test_unknown_rig_id_lists_the_known_ones():
    with pytest.raises(InputError) as info:
        load_rig("brake-3dof")
    expect_error(info.value, "brake-3dof", "rig", "unknown rig", "belt-ndof", "brake-2dof", "drum-pendulum")


def test_parse_rig_uses_the_given_source():
    data = rig_data("belt-ndof")
    data["friction"]["w_min"] = -1.0
    with pytest.raises(InputError) as info:
        parse_rig(data, "somewhere/else.toml")
    expect_error(info.value, "somewhere/else.toml", "friction.w_min", "greater than 0")


def test_parse_rig_does_not_modify_its_input():
    data = rig_data("brake-2dof")
    before = copy.deepcopy(data)
    parse_rig(data, "mem")
    assert data == before


def test_a_rig_file_edited_between_two_loads_is_read_again(tmp_path):
    """load_rig keeps a parsed file per text: an edit is seen at once, even one that keeps the file's size and its
    modification time, and a file made invalid is refused again."""
    data = rig_data("brake-2dof")
    path = write_cfg(tmp_path, data, "mine.toml")
    first = load_rig(path)
    stat = path.stat()
    text = path.read_text()
    old = f"k1_N_per_m = {first.mechanics.k1_N_per_m!r}"
    assert old in text and old[-1] != "7", old
    path.write_text(text.replace(old, old[:-1] + "7"))  # the same size
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))  # and the same modification time
    edited = load_rig(path)
    assert edited.mechanics.k1_N_per_m != first.mechanics.k1_N_per_m and path.stat().st_size == stat.st_size
    assert load_rig(path) == edited
    data["mechanics"]["k1_N_per_m"] = -1.0
    write_cfg(tmp_path, data, "mine.toml")
    expect_read_error(load_rig, path, "mechanics.k1_N_per_m")
