"""Speed programmes: exact seed ramp of paper 001 eq. (11), TOML segment files, CSV tables, rig limits."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from helpers import expect_error, write

from daq.config import load_rig
from daq.errors import InputError
from daq.physics.effects import ramp_eval_side
from daq.ramps import EXP_POINTS, Ramp, Segment, check_limits, constant_ramp, load_ramp, ramp_table, seed_ramp


def load_bad(path: Path) -> InputError:
    with pytest.raises(InputError) as info:
        load_ramp(path)
    return info.value


# ---------------------------------------------------------------- seed ramp, paper 001 eq. (11)


def test_seed_ramp_table_is_exactly_two_points():
    rt, rv = ramp_table(seed_ramp(0.17, 45.0))
    assert rt.tolist() == [0.0, 45.0]
    assert rv.tolist() == [0.17, 0.0]


def test_seed_ramp_interpolates_eq_11():
    v0, tmax = 0.17, 45.0
    rt, rv = ramp_table(seed_ramp(v0, tmax))
    t = np.linspace(0.0, tmax, 91)
    np.testing.assert_allclose(np.interp(t, rt, rv), v0 * (1.0 - t / tmax), rtol=0, atol=1e-15)


def test_seed_ramp_cut_short_ends_on_the_line():
    rt, rv = ramp_table(seed_ramp(0.17, 45.0, duration=30.0))
    assert rt.tolist() == [0.0, 30.0]
    assert rv[0] == 0.17
    assert rv[1] == pytest.approx(0.17 * (1 - 30 / 45), abs=1e-15)


def test_seed_ramp_of_the_brake_config_is_within_its_limits():
    cfg = load_rig("brake-2dof")
    rt, rv = ramp_table(seed_ramp(cfg.drive.V0_m_per_s, cfg.drive.Tmax_s))
    assert rt.tolist() == [0.0, 45.0] and rv.tolist() == [0.17, 0.0]
    assert check_limits(rt, rv, cfg.drive.max_speed_m_per_s, cfg.drive.max_accel_m_per_s2, "seed") is None


def test_constant_ramp_holds():
    rt, rv = ramp_table(constant_ramp(0.2, 10.0))
    assert rt.tolist() == [0.0, 10.0]
    assert rv.tolist() == [0.2, 0.2]


# ---------------------------------------------------------------- TOML segment files

PROGRAMME = """\
name = "warm-up and decay"
start_m_per_s = 0.05

[[segment]]
kind = "hold"
duration_s = 3.0

[[segment]]
kind = "linear"
duration_s = 2.0
to_m_per_s = 0.25

[[segment]]
kind = "exponential"
duration_s = 4.0
to_m_per_s = 0.1
tau_s = 0.5

[[segment]]
kind = "hold"
duration_s = 1.5
"""


@pytest.fixture
def programme(tmp_path):
    ramp, rt, rv = load_ramp(write(tmp_path, "prog.toml", PROGRAMME))
    return ramp, rt, rv


def test_toml_ramp_is_parsed_into_segments(programme):
    ramp, _, _ = programme
    assert isinstance(ramp, Ramp)
    assert ramp.name == "warm-up and decay"
    assert ramp.start_m_per_s == 0.05
    assert [s.kind for s in ramp.segment] == ["hold", "linear", "exponential", "hold"]
    assert ramp.segment[2].tau_s == 0.5


def test_durations_add_up(programme):
    _, rt, rv = programme
    assert rt[0] == 0.0
    assert rt[-1] == pytest.approx(3.0 + 2.0 + 4.0 + 1.5, abs=1e-12)
    assert len(rt) == len(rv) == 1 + 1 + 1 + EXP_POINTS + 1
    assert np.all(np.diff(rt) > 0)


def test_hold_then_linear_are_exact(programme):
    _, rt, rv = programme
    assert rt[:3].tolist() == [0.0, 3.0, 5.0]
    assert rv[:3].tolist() == [0.05, 0.05, 0.25]
    # the table is piecewise linear: halfway through the linear segment is the mean speed
    assert np.interp(4.0, rt, rv) == pytest.approx(0.15, abs=1e-15)
    assert np.interp(1.7, rt, rv) == 0.05  # a hold keeps the speed


def test_exponential_segment_has_the_given_time_constant(programme):
    _, rt, rv = programme
    t0, v0, target, tau = 5.0, 0.25, 0.1, 0.5
    seg = slice(3, 3 + EXP_POINTS)
    te, ve = rt[seg], rv[seg]
    assert te[0] == pytest.approx(t0 + 4.0 / EXP_POINTS, abs=1e-12)
    assert te[-1] == pytest.approx(t0 + 4.0, abs=1e-12)
    np.testing.assert_allclose(ve - target, (v0 - target) * np.exp(-(te - t0) / tau), rtol=0, atol=1e-9)
    # the sample one time constant in: 4 s / 200 points * 25 = 0.5 s
    k = int(np.argmin(np.abs(te - (t0 + tau))))
    assert te[k] == pytest.approx(t0 + tau, abs=1e-12)
    assert ve[k] - target == pytest.approx((v0 - target) * math.exp(-1.0), abs=1e-9)
    assert np.all(np.diff(ve) < 0) and np.all(ve > target)


def test_hold_after_exponential_keeps_its_end_speed(programme):
    _, rt, rv = programme
    v_end = 0.1 + 0.15 * math.exp(-4.0 / 0.5)
    assert rv[-2] == pytest.approx(v_end, abs=1e-12)
    assert rv[-1] == rv[-2]
    assert rt[-1] - rt[-2] == pytest.approx(1.5, abs=1e-12)


def test_exponential_rising_to_target(tmp_path):
    text = """start_m_per_s = 0.0
[[segment]]
kind = "exponential"
duration_s = 2.0
to_m_per_s = 0.3
tau_s = 0.25
"""
    _, rt, rv = load_ramp(write(tmp_path, "rise.toml", text))
    assert rt[0] == 0.0 and rv[0] == 0.0
    np.testing.assert_allclose(rv[1:] - 0.3, (0.0 - 0.3) * np.exp(-rt[1:] / 0.25), rtol=0, atol=1e-9)
    i = int(np.argmin(np.abs(rt - 0.25)))
    assert rv[i] - 0.3 == pytest.approx(-0.3 * math.exp(-1.0), abs=1e-9)


def test_seed_segment_first_needs_no_start_speed(tmp_path):
    text = """[[segment]]
kind = "seed"
V0_m_per_s = 0.17
Tmax_s = 45.0
"""
    ramp, rt, rv = load_ramp(write(tmp_path, "seed.toml", text))
    assert ramp.start_m_per_s is None
    assert rt.tolist() == [0.0, 45.0] and rv.tolist() == [0.17, 0.0]


def test_seed_segment_after_a_hold_steps_to_v0(tmp_path):
    text = """start_m_per_s = 0.05
[[segment]]
kind = "hold"
duration_s = 2.0
[[segment]]
kind = "seed"
V0_m_per_s = 0.17
Tmax_s = 45.0
duration_s = 9.0
"""
    _, rt, rv = load_ramp(write(tmp_path, "step.toml", text))
    assert rt.tolist() == [0.0, 2.0, 2.0, 11.0]
    assert rv[:3].tolist() == [0.05, 0.05, 0.17]
    assert rv[3] == pytest.approx(0.17 * (1 - 9 / 45), abs=1e-15)


def test_ramp_table_of_an_in_memory_ramp():
    ramp = Ramp(start_m_per_s=0.1, segment=[Segment(kind="linear", duration_s=1.0, to_m_per_s=0.3),
                                            Segment(kind="hold", duration_s=0.5)])
    rt, rv = ramp_table(ramp)
    assert rt.tolist() == [0.0, 1.0, 1.5]
    assert rv.tolist() == [0.1, 0.3, 0.3]


# ---------------------------------------------------------------- bad TOML ramps

_BAD_TOML_RAMPS = [
    pytest.param('start_m_per_s = 0.1\n[[segment]]\nkind = "linear"\nduration_s = 2.0\n',
                 "segment[0].to_m_per_s", ("required", "linear"), id="linear_without_end_speed"),
    pytest.param('start_m_per_s = 0.1\n[[segment]]\nkind = "hold"\nduration_s = 1.0\n'
                 '[[segment]]\nkind = "exponential"\nduration_s = 2.0\nto_m_per_s = 0.2\n',
                 "segment[1].tau_s", ("required", "exponential"), id="exponential_without_tau_in_the_second_segment"),
    pytest.param('start_m_per_s = 0.1\n[[segment]]\nkind = "sine"\nduration_s = 1.0\n',
                 "segment[0].kind", ("'hold'", "'exponential'"), id="unknown_segment_kind"),
    pytest.param('start_m_per_s = 0.1\n[[segment]]\nkind = "hold"\nduration_s = 1.0\n'
                 '[[segment]]\nkind = "hold"\nduraton_s = 1.0\n',
                 "segment[1].duraton_s", ("Extra inputs",), id="unknown_key_in_a_segment"),
    pytest.param('start_speed = 0.1\n[[segment]]\nkind = "hold"\nduration_s = 1.0\n',
                 "start_speed", ("Extra inputs",), id="unknown_top_level_key"),
    pytest.param('[[segment]]\nkind = "hold"\nduration_s = 1.0\n',
                 "start_m_per_s", ("seed",), id="no_start_speed_and_first_segment_not_seed"),
    pytest.param("start_m_per_s = 0.1\n", "segment", ("Field required",), id="no_segments"),
    pytest.param("start_m_per_s = 0.1\nsegment = []\n", "segment", ("at least 1",), id="empty_segment_list"),
    pytest.param('[[segment]]\nkind = "seed"\nV0_m_per_s = 0.17\nTmax_s = 45.0\nduration_s = 50.0\n',
                 "segment[0].duration_s", ("exceeds Tmax_s=45.0",), id="seed_segment_longer_than_tmax"),
    pytest.param('start_m_per_s = 0.1\n[[segment]\nkind = "hold"\n',
                 "(syntax)", ("line 2",), id="toml_syntax_error"),
]


@pytest.mark.parametrize(("text", "field", "fragments"), _BAD_TOML_RAMPS)
def test_bad_toml_ramp_is_one_error_naming_its_field(tmp_path, text, field, fragments):
    path = write(tmp_path, "r.toml", text)
    expect_error(load_bad(path), str(path), field, *fragments)


@pytest.mark.parametrize(
    ("start", "segment", "field", "fragments"),
    [
        # a key the segment's kind needs is missing
        ("0.1", 'kind = "hold"', "segment[0].duration_s", ("required",)),
        ("0.1", 'kind = "linear"\nto_m_per_s = 0.2', "segment[0].duration_s", ("required",)),
        ("0.1", 'kind = "exponential"\nduration_s = 1.0\ntau_s = 0.2', "segment[0].to_m_per_s", ("required",)),
        ("0.1", 'kind = "seed"\nV0_m_per_s = 0.1', "segment[0].Tmax_s", ("required",)),
        ("0.1", 'kind = "seed"\nTmax_s = 10.0', "segment[0].V0_m_per_s", ("required",)),
        # a rate-and-state protocol (velocity steps, slide-hold-slide) missing a key or with a bad value
        ("1e-5", 'kind = "velocity-steps"\nslip_m = 1e-4', "segment[0].speeds_m_per_s", ()),
        ("1e-5", 'kind = "velocity-steps"\nspeeds_m_per_s = [1e-5, 0.0]\nslip_m = 1e-4',
         "segment[0].speeds_m_per_s[1]", ()),
        ("1e-5", 'kind = "slide-hold-slide"\nto_m_per_s = 1e-5\nslip_m = 1e-4\nholds_s = [3, -1]',
         "segment[0].holds_s[1]", ()),
        ("1e-5", 'kind = "slide-hold-slide"\nto_m_per_s = 1e-5\nholds_s = [3]', "segment[0].slip_m", ()),
    ],
)
def test_a_bad_segment_is_one_error_naming_its_field(tmp_path, start, segment, field, fragments):
    path = write(tmp_path, "r.toml", f"start_m_per_s = {start}\n[[segment]]\n{segment}\n")
    expect_error(load_bad(path), str(path), field, *fragments)


@pytest.mark.parametrize(
    ("value", "fragment"), [("-1.0", "greater than 0"), ("0.0", "greater than 0"), ("inf", "finite"),
                            ("nan", "finite"), ('"2 s"', "valid number")])
def test_bad_duration(tmp_path, value, fragment):
    path = write(tmp_path, "r.toml", f'start_m_per_s = 0.1\n[[segment]]\nkind = "hold"\nduration_s = {value}\n')
    expect_error(load_bad(path), str(path), "segment[0].duration_s", fragment)


def test_negative_or_nan_target_speed(tmp_path):
    for value, fragment in (("-0.1", "greater than or equal to 0"), ("nan", "finite")):
        path = write(tmp_path, "r.toml",
                     f'start_m_per_s = 0.1\n[[segment]]\nkind = "linear"\nduration_s = 1.0\nto_m_per_s = {value}\n')
        expect_error(load_bad(path), str(path), "segment[0].to_m_per_s", fragment)


def test_missing_ramp_file(tmp_path):
    path = tmp_path / "nowhere.toml"
    expect_error(load_bad(path), str(path), "(file)", "No such file")


# ---------------------------------------------------------------- CSV ramp tables


def test_csv_table_with_extra_and_reordered_columns(tmp_path):
    path = write(tmp_path, "r.csv", "note,vb,t\na,0.1,0\nb,0.2,1.5\nc,0.0,4\n")
    ramp, rt, rv = load_ramp(path)
    assert ramp is None
    assert rt.tolist() == [0.0, 1.5, 4.0]
    assert rv.tolist() == [0.1, 0.2, 0.0]


def test_csv_table_is_rebased_to_start_at_zero(tmp_path):
    path = write(tmp_path, "r.CSV", " t , vb \n10,0.1\n12.5,0.2\n\n13,0.2\n")
    _, rt, rv = load_ramp(path)
    assert rt.tolist() == [0.0, 2.5, 3.0]
    assert rv.tolist() == [0.1, 0.2, 0.2]


def test_csv_non_numeric_value(tmp_path):
    path = write(tmp_path, "r.csv", "t,vb\n0,0.1\n1,fast\n")
    expect_error(load_bad(path), str(path), "line 3", "numbers")


def test_csv_row_missing_the_speed(tmp_path):
    path = write(tmp_path, "r.csv", "t,vb\n0,0.1\n1,0.2\n2\n")
    expect_error(load_bad(path), str(path), "line 4", "numbers")


@pytest.mark.parametrize("row", ["1,nan", "nan,0.2", "1,inf"])
def test_csv_non_finite_value(tmp_path, row):
    path = write(tmp_path, "r.csv", f"t,vb\n0,0.1\n{row}\n2,0.3\n")
    expect_error(load_bad(path), str(path), "line 3", "finite")


@pytest.mark.parametrize("rows", ["0,0.1\n1,0.2\n1,0.3\n", "0,0.1\n2,0.2\n1,0.3\n", "0,0.1\n"])
def test_csv_t_not_strictly_increasing_or_too_short(tmp_path, rows):
    path = write(tmp_path, "r.csv", "t,vb\n" + rows)
    expect_error(load_bad(path), str(path), "t", "strictly increasing")


@pytest.mark.parametrize(("header", "missing"), [("time,vb", "t"), ("t,v", "vb")])
def test_csv_missing_column(tmp_path, header, missing):
    path = write(tmp_path, "r.csv", f"{header}\n0,0.1\n1,0.2\n")
    expect_error(load_bad(path), str(path), missing, "missing column")


def test_csv_empty_file(tmp_path):
    path = write(tmp_path, "r.csv", "")
    expect_error(load_bad(path), str(path), "(header)", "empty")


# ---------------------------------------------------------------- rig limits


def arr(*xs: float) -> np.ndarray:
    return np.asarray(xs, dtype=float)


def test_within_limits_passes():
    assert check_limits(arr(0, 1, 2), arr(0.1, 0.5, 0.0), 0.5, 0.5, "src") is None


def test_exactly_at_the_acceleration_limit_passes():
    assert check_limits(arr(0, 2), arr(0.0, 1.0), 1.0, 0.5, "src") is None


@pytest.mark.parametrize(("rt", "rv", "max_speed", "max_accel", "src", "field", "fragments"), [
    pytest.param((0, 1, 3), (0.1, 0.2, 0.6), 0.5, 10.0, "prog.toml", "speed", ("0.6 m/s", "t=3 s", "0.5 m/s"),
                 id="over_speed"),
    pytest.param((0, 1), (0.1, -0.01), 0.5, 10.0, "prog.toml", "speed", ("negative",), id="negative_speed"),
    pytest.param((0, 1, 1.5), (0.1, 0.2, 0.5), 1.0, 0.5, "prog.toml", "acceleration",
                 ("0.6 m/s^2", "t=1 s", "0.5 m/s^2"), id="over_acceleration_names_where"),
    pytest.param((0, 0.1), (0.3, 0.0), 1.0, 0.5, "src", "acceleration", ("3 m/s^2",),
                 id="deceleration_counts_as_acceleration"),
])
def test_programme_over_the_limits_is_refused(rt, rv, max_speed, max_accel, src, field, fragments):
    with pytest.raises(InputError) as info:
        check_limits(arr(*rt), arr(*rv), max_speed, max_accel, src)
    expect_error(info.value, src, field, *fragments)


def test_step_is_infinite_acceleration(tmp_path):
    text = ('start_m_per_s = 0.05\n[[segment]]\nkind = "hold"\nduration_s = 2.0\n'
            '[[segment]]\nkind = "seed"\nV0_m_per_s = 0.17\nTmax_s = 45.0\n')
    path = write(tmp_path, "step.toml", text)
    _, rt, rv = load_ramp(path)
    with pytest.raises(InputError) as info:
        check_limits(rt, rv, 0.5, 0.5, str(path))
    expect_error(info.value, str(path), "acceleration", "inf")


@pytest.mark.parametrize(("rt", "rv", "field"), [((0, 1), (0.1, math.nan), "speed"), ((0, math.nan), (0.1, 0.2), "t"),
                                                  ((0, math.inf), (0.1, 0.2), "t")])
def test_non_finite_programme_is_refused(rt, rv, field):
    with pytest.raises(InputError) as info:
        check_limits(arr(*rt), arr(*rv), 0.5, 0.5, "src")
    expect_error(info.value, "src", field, "non-finite")


def test_fast_exponential_exceeds_the_brake_acceleration_limit(tmp_path):
    cfg = load_rig("brake-2dof")
    lim = cfg.drive
    fast = "start_m_per_s = 0.3\n[[segment]]\nkind = \"exponential\"\nduration_s = 1.0\nto_m_per_s = 0.0\ntau_s = 0.1\n"
    slow = fast.replace("tau_s = 0.1", "tau_s = 2.0")
    path = write(tmp_path, "fast.toml", fast)
    _, rt, rv = load_ramp(path)
    with pytest.raises(InputError) as info:
        check_limits(rt, rv, lim.max_speed_m_per_s, lim.max_accel_m_per_s2, str(path))
    expect_error(info.value, str(path), "acceleration", "t=0 s")
    _, rt, rv = load_ramp(write(tmp_path, "slow.toml", slow))
    assert check_limits(rt, rv, lim.max_speed_m_per_s, lim.max_accel_m_per_s2, "slow") is None


def test_csv_ramp_over_the_brake_speed_limit(tmp_path):
    lim = load_rig("brake-2dof").drive
    path = write(tmp_path, "r.csv", "t,vb\n0,0.1\n10,0.6\n")
    _, rt, rv = load_ramp(path)
    with pytest.raises(InputError) as info:
        check_limits(rt, rv, lim.max_speed_m_per_s, lim.max_accel_m_per_s2, str(path))
    expect_error(info.value, str(path), "speed", "exceeds the rig limit 0.5")


# ---------------------------------------------------------------- rate-and-state protocols (issue 27)

DOCS_RAMPS = Path(__file__).resolve().parent.parent / "docs" / "ramps"


def test_velocity_steps_hold_each_speed_for_its_slip():
    _, rt, rv = load_ramp(DOCS_RAMPS / "velocity-steps.toml")
    travel = np.concatenate([[0.0], np.cumsum(0.5 * (rv[1:] + rv[:-1]) * np.diff(rt))])
    flat = np.flatnonzero(np.diff(rt) > 0.05)  # the plateaus (changes take 10 ms)
    assert [rv[i] for i in flat] == [1e-5, 1e-4, 1e-5, 3e-5, 3e-6]
    np.testing.assert_allclose([travel[i + 1] - travel[i] for i in flat], 3e-4, rtol=1e-9)
    np.testing.assert_allclose(np.diff(rt)[np.diff(rt) < 0.05], 0.01, rtol=1e-9)


def test_slide_hold_slide_stops_for_each_hold_and_slides_between():
    _, rt, rv = load_ramp(DOCS_RAMPS / "slide-hold-slide.toml")
    holds = [rt[i + 1] - rt[i] for i in range(rt.size - 1) if rv[i] == 0.0 and rv[i + 1] == 0.0]
    np.testing.assert_allclose(holds, [3, 10, 30, 100], rtol=1e-12)
    slides = [rt[i + 1] - rt[i] for i in range(rt.size - 1) if rv[i] == 1e-5 and rv[i + 1] == 1e-5]
    np.testing.assert_allclose(slides, 20.0, rtol=1e-12)  # 200 um at 10 um/s, five times
    assert len(slides) == 5
    check_limits(rt, rv, 1.0, 1.0, "shs")  # 1e-5 m/s in 10 ms: 1e-3 m/s^2


# ---------------------------------------------------------------- the table as the integrator reads it


def _bisected(rt: np.ndarray, rv: np.ndarray, t: float, left: bool) -> tuple[float, float]:
    """ramp_eval_side's value and slope by the bisection it used before its guess-and-walk (the reference)."""
    n = rt.size
    if t <= rt[0]:
        return rv[0], 0.0
    if t > rt[-1] or (t == rt[-1] and not left):
        return rv[-1], 0.0
    lo, hi = 0, n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if rt[mid] < t or (rt[mid] == t and not left):
            lo = mid
        else:
            hi = mid
    slope = (rv[hi] - rv[lo]) / (rt[hi] - rt[lo])
    return rv[lo] + slope * (t - rt[lo]), slope


@pytest.mark.parametrize("table", ["even", "uneven", "steps"])
def test_the_drive_table_is_read_at_the_same_row_as_by_bisection(table):
    """The integrator's table lookup guesses the row in proportion and walks to it: on an evenly spaced record, on
    an uneven table and on one with repeated times (a step in a programme), at its rows, between them and outside,
    from either side: bit for bit what a bisection reads."""
    rng = np.random.default_rng(3)
    rt = {"even": np.arange(2001) * 1e-3,
          "uneven": np.cumsum(rng.exponential(1.0, 300) ** 3),
          "steps": np.repeat(np.arange(40, dtype=float), 2)}[table]
    rv = rng.normal(0.0, 1.0, rt.size) if table != "steps" else rng.normal(0.0, 1.0, rt.size).cumsum()
    ts = np.concatenate([rt, rng.uniform(rt[0] - 1.0, rt[-1] + 1.0, 3000), [rt[0], rt[-1]]])
    for t in ts:
        for left in (False, True):
            assert ramp_eval_side(rt, rv, float(t), left) == _bisected(rt, rv, float(t), left), (t, left)


def test_paper_001s_deceleration_is_named_so_and_the_old_name_still_reads(tmp_path):
    """"Seed" means a random seed only: a ramp file's segment and a rig file's drive say "deceleration" for paper
    001's eq. (11), and files that say "seed" read the same."""
    from daq.config import load_rig, rig_path

    text = "[[segment]]\nkind = \"{}\"\nV0_m_per_s = 0.17\nTmax_s = 45.0\n"
    (tmp_path / "new.toml").write_text(text.format("deceleration"))
    (tmp_path / "old.toml").write_text(text.format("seed"))
    _, rt_new, rv_new = load_ramp(tmp_path / "new.toml")
    _, rt_old, rv_old = load_ramp(tmp_path / "old.toml")
    assert np.array_equal(rt_new, rt_old) and np.array_equal(rv_new, rv_old)
    rig = rig_path("brake-2dof").read_text()
    assert 'ramp = "seed"' in rig
    (tmp_path / "rig.toml").write_text(rig.replace('ramp = "seed"', 'ramp = "deceleration"'))
    assert load_rig(str(tmp_path / "rig.toml")).drive == load_rig("brake-2dof").drive
