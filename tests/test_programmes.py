"""The next experiment's candidates (daq/models/design/programmes.py): every programme a ramp file the daemon's runner takes
as it is, within the rig's limits and the run's length, and the family varying what separates the rival
explanations (accelerations for a brake's ramps, stick times for a slider at one speed)."""

from __future__ import annotations

import numpy as np
import pytest

from daq.config import load_rig
from daq.daemon.ramp_runner import RampRunner
from daq.errors import InputError
from daq.models.design.programmes import MIN_SLIDE_S, family, write_programme
from daq.ramps import load_ramp

CASES = (  # rig, the record's drive speed [m/s], the longest run [s]
    ("brake-2dof", 0.17, 40.0),  # the seed ramp's V0
    ("belt-ndof", 0.004, 60.0),  # a spring-slider at 4 mm/s (docs/examples/spring-slider.md)
    ("belt-ndof", 42e-6, 300.0),  # the lab's slowest real record (docs/examples/real-slider.md)
    ("drum-pendulum", 0.012, 30.0),
)


@pytest.mark.parametrize("rig,v0,max_s", CASES)
def test_every_programme_is_a_ramp_file_the_daemon_runs_within_the_rigs_limits(tmp_path, rig, v0, max_s):
    cfg = load_rig(rig)
    fam = family(cfg, v0, max_s)
    assert len(fam) >= 36, [p.name for p in fam]
    assert len({p.name for p in fam}) == len(fam)
    for i, p in enumerate(fam):
        path = write_programme(p, tmp_path / f"p{i}.toml")
        ramp, rt, rv = load_ramp(path)  # the file round-trips to the same programme
        assert ramp == p.ramp, p.name
        t0, v0_table = p.table()
        np.testing.assert_allclose(rt, t0)
        np.testing.assert_allclose(rv, v0_table)
        assert rt[-1] == pytest.approx(p.duration_s) and p.duration_s <= max_s * (1 + 1e-9), p.name
        # the daemon's own check before any motion (service.run_sim_ramp's dry run): limits, table, the runner's cfg
        runner = RampRunner.from_file(None, path, cfg.drive.max_speed_m_per_s, cfg.drive.max_accel_m_per_s2)
        assert runner.duration == pytest.approx(p.duration_s)
        sliding = np.diff(rt) > 0
        assert np.all(rv <= cfg.drive.max_speed_m_per_s * (1 + 1e-9)) and np.all(rv >= 0.0)
        if np.any(sliding & (rv[1:] == rv[:-1]) & (rv[1:] > 0)):  # every plateau at speed lasts a slide at least
            plateau_s = np.diff(rt)[sliding & (rv[1:] == rv[:-1]) & (rv[1:] > 0)]
            assert plateau_s.min() >= MIN_SLIDE_S * 0.999 or "decelerate" in p.name, (p.name, plateau_s.min())


def test_a_brakes_family_changes_the_speed_and_reverses_the_acceleration():
    """What separates accel-sign from a belt lag, or a drive effect from a spring change: other start speeds, other
    deceleration rates, accelerations (dv/dt > 0) and plateaus; at least the 50 candidates `daq bench propose`
    scores."""
    fam = family(load_rig("brake-2dof"), 0.17, 40.0)
    assert len(fam) >= 50
    starts, rates, accelerating = set(), set(), 0
    for p in fam:
        rt, rv = p.table()
        starts.add(round(rv[0], 4))
        slopes = np.diff(rv) / np.where(np.diff(rt) > 0, np.diff(rt), np.inf)
        rates.add(round(float(slopes.min()), 4))
        accelerating += bool(np.any(slopes > 0))
    assert len(starts) >= 5 and len(rates) >= 8 and accelerating >= 10, (starts, rates, accelerating)
    assert max(starts) == pytest.approx(0.5)  # capped at the rig's top speed, not beyond


@pytest.mark.parametrize("rig,v0", [("belt-ndof", 0.004), ("drum-pendulum", 0.012)])
def test_a_slider_at_one_speed_gets_programmes_that_vary_its_stick_times(rig, v0):
    """At one constant drive speed every stick lasts as long as the last, so aging cannot be told from a higher
    static level (docs/examples/spring-slider.md). Every programme of the family changes that: it slides at another
    speed (x1.5 at least), steps between two speeds, or holds the slider still."""
    fam = family(load_rig(rig), v0, 60.0)
    kinds = {"other speed": 0, "steps": 0, "holds": 0}
    for p in fam:
        rt, rv = p.table()
        speeds = sorted({round(float(v), 12) for v in rv if v > 0})
        holds = np.any(rv == 0.0)
        ratio = max(max(speeds) / v0, v0 / min(speeds))
        assert holds or ratio >= 1.5 - 1e-9 or len(speeds) >= 2 and max(speeds) / min(speeds) >= 1.5, p.name
        assert "stick time" in p.varies
        kinds["holds" if holds else "steps" if len(speeds) >= 2 else "other speed"] += 1
    assert min(kinds.values()) >= 6, kinds


def test_a_run_the_rig_cannot_make_is_one_clear_error():
    cfg = load_rig("brake-2dof")
    with pytest.raises(InputError) as e:
        family(cfg, 0.8, 40.0)  # above the belt's 0.5 m/s
    assert e.value.field == "V0" and "0.5" in str(e.value)
    with pytest.raises(InputError) as e:
        family(cfg, 0.17, 2.0)
    assert e.value.field == "max_s"
