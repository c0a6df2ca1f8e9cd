"""RampRunner against the simulated brake rig: its regulator on a real pty, the real serial driver."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from daq.config import load_rig
from daq.daemon.ramp_runner import RampEvent, RampProgress, RampRunner, RampRunnerCfg, segment_bounds
from daq.errors import InputError
from daq.ramps import load_ramp, seed_ramp
from drivers.factory import build_drivers
from sim_backends.hardware import SimulatedHardware

RAMP_TOML = """
name = "test ramp"
start_m_per_s = 0.05
[[segment]]
kind = "hold"
duration_s = 0.5
[[segment]]
kind = "linear"
duration_s = 1.0
to_m_per_s = 0.15
[[segment]]
kind = "exponential"
duration_s = 1.0
to_m_per_s = 0.02
tau_s = 0.4
"""


def wait_for(cond, timeout: float = 5.0, period: float = 0.01) -> bool:
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if cond():
            return True
        time.sleep(period)
    return bool(cond())


@pytest.fixture()
def bench(tmp_path):
    """The brake rig simulated in real time and its drivers opened on the simulated endpoints."""
    cfg = load_rig("brake-2dof")
    hw = SimulatedHardware(cfg, tmp_path).start()
    drivers = build_drivers(cfg, hw.endpoints())
    drivers.motor.open()  # only the motor is needed here
    yield cfg, hw, drivers.motor
    drivers.motor.close()
    hw.stop()


def _limits(cfg) -> dict[str, float]:
    return {"max_speed": cfg.drive.max_speed_m_per_s, "max_accel": cfg.drive.max_accel_m_per_s2}


def _write(tmp_path: Path, text: str, name: str = "ramp.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.slow
def test_toml_ramp_runs_at_rate_and_belt_follows(bench, tmp_path):
    cfg, hw, motor = bench
    rig = hw.rig
    events: list[RampEvent] = []
    progress: list[RampProgress] = []
    follow: list[tuple[float, float]] = []  # (command, belt) sampled while running

    def on_progress(p: RampProgress) -> None:
        progress.append(p)
        if p.state == "running":
            follow.append((p.commanded, rig.belt_speed))

    runner = RampRunner.from_file(motor, _write(tmp_path, RAMP_TOML), **_limits(cfg),
                                  on_event=events.append, on_progress=on_progress)
    assert runner.segment_kinds == ["hold", "linear", "exponential"]
    assert np.allclose(runner.segment_starts, [0.0, 0.5, 1.5])
    runner.start()
    assert runner.join(timeout=15.0), "ramp did not finish"
    assert runner.state == "finished", runner.reason

    h = runner.history
    prog = h["t"] >= 0.0
    assert np.any(~prog) and np.all(np.diff(h["t"]) > 0)  # lead-in from rest to 0.05 m/s, at t < 0
    assert np.all(h["vb_set"][~prog] == 0.05)
    dt = np.diff(h["t"][prog])
    assert np.median(dt) <= 0.020  # >= 50 Hz set points (100 Hz nominal)
    assert h["t"][prog][-1] == pytest.approx(runner.duration)
    assert len(h["t"]) == len(h["vb_set"]) == len(h["vb"])
    # the commands follow the table
    assert np.allclose(h["vb_set"][prog], np.interp(h["t"][prog], runner.rt, runner.rv), atol=1e-9)

    # the belt follows the command: one or two set-point periods of lag at most at the ramp's 0.1 m/s^2,
    # plus scheduling jitter on a loaded machine and the 1 mm/s tachometer noise; generous tolerance
    err = np.array([abs(c - b) for c, b in follow])
    assert np.median(err) < 0.005
    assert np.percentile(err, 95) < 0.02
    meas = h["vb"][prog]
    ok = np.isfinite(meas)
    assert np.median(np.abs(meas[ok] - h["vb_set"][prog][ok])) < 0.006

    # events: start/end per segment in order, then finished
    kinds = [(e.kind, e.index, e.segment) for e in events]
    assert kinds == [("segment_start", 0, "hold"), ("segment_end", 0, "hold"),
                     ("segment_start", 1, "linear"), ("segment_end", 1, "linear"),
                     ("segment_start", 2, "exponential"), ("segment_end", 2, "exponential"),
                     ("finished", None, None)]
    ts = [e.t for e in events]
    assert ts == sorted(ts)
    assert events[2].t == pytest.approx(0.5, abs=0.1) and events[4].t == pytest.approx(1.5, abs=0.1)

    # progress: fraction rises to 1, segment index never goes back
    run = [p for p in progress if p.state == "running"]
    assert [p.segment for p in run] == sorted(p.segment for p in run)
    assert runner.progress().fraction == 1.0 and runner.progress().state == "finished"
    # at_end = "stop": the belt comes to rest
    assert wait_for(lambda: rig.belt_speed < 1e-3, timeout=3.0)


def test_hold_at_end_keeps_the_last_speed(bench, tmp_path):
    cfg, hw, motor = bench
    text = 'start_m_per_s = 0.08\n[[segment]]\nkind = "hold"\nduration_s = 0.3\n'
    runner = RampRunner.from_file(motor, _write(tmp_path, text), **_limits(cfg),
                                  cfg=RampRunnerCfg(at_end="hold", rate_hz=50))
    runner.start()
    assert runner.join(timeout=10.0) and runner.state == "finished"
    time.sleep(0.3)
    assert motor.status().state == "RUNNING"
    assert abs(hw.rig.belt_speed - 0.08) < 0.005
    assert np.median(np.diff(runner.history["t"][runner.history["t"] >= 0])) <= 0.025


@pytest.mark.parametrize("text, field", [
    ('start_m_per_s = 0.1\n[[segment]]\nkind = "linear"\nduration_s = 1.0\nto_m_per_s = 0.7\n', "speed"),
    ('start_m_per_s = 0.0\n[[segment]]\nkind = "linear"\nduration_s = 0.1\nto_m_per_s = 0.2\n', "acceleration"),
])
def test_ramp_beyond_limits_is_refused_before_motion(bench, tmp_path, text, field):
    cfg, hw, motor = bench
    n0 = hw.motor.commands
    with pytest.raises(InputError) as exc:
        RampRunner.from_file(motor, _write(tmp_path, text), **_limits(cfg))
    assert exc.value.field == field
    time.sleep(0.05)
    # only heartbeats reached the regulator (they are no motion): no ENA/SPD/ACC, belt at rest
    assert hw.motor.state == "DISABLED" and hw.motor.setpoint == 0.0
    assert hw.rig.belt_speed == 0.0
    assert hw.motor.commands - n0 < 10  # heartbeats at 10 Hz only


def test_refused_ramp_sends_no_command_at_all():
    """With a recording stub, a refused ramp makes no call on the motor at all."""
    calls: list[str] = []

    class Stub:
        def __getattr__(self, name):
            return lambda *a: calls.append(name)

    with pytest.raises(InputError):
        RampRunner(Stub(), np.array([0.0, 1.0]), np.array([0.0, 0.6]), max_speed=0.5, max_accel=0.5)
    with pytest.raises(InputError):  # time compression beyond the acceleration limit
        RampRunner(Stub(), np.array([0.0, 1.0]), np.array([0.0, 0.4]), max_speed=0.5, max_accel=0.5,
                   cfg=RampRunnerCfg(time_scale=0.5))
    with pytest.raises(ValueError):  # pydantic: below 50 Hz
        RampRunnerCfg(rate_hz=20)
    assert calls == []


def test_stop_mid_ramp_brings_belt_to_rest(bench, tmp_path):
    cfg, hw, motor = bench
    text = 'start_m_per_s = 0.1\n[[segment]]\nkind = "hold"\nduration_s = 10.0\n'
    runner = RampRunner.from_file(motor, _write(tmp_path, text), **_limits(cfg)).start()
    assert wait_for(lambda: runner.state == "running" and runner.progress().t > 0.3, timeout=5.0)
    assert hw.rig.belt_speed > 0.08
    runner.stop()
    assert runner.join(timeout=3.0)
    assert runner.state == "stopped" and runner.events[-1].kind == "stopped"
    assert wait_for(lambda: hw.rig.belt_speed < 1e-3, timeout=3.0)
    assert wait_for(lambda: motor.status().state == "DISABLED", timeout=2.0)


def test_estop_latches(bench, tmp_path):
    cfg, hw, motor = bench
    text = 'start_m_per_s = 0.1\n[[segment]]\nkind = "hold"\nduration_s = 10.0\n'
    runner = RampRunner.from_file(motor, _write(tmp_path, text), **_limits(cfg)).start()
    assert wait_for(lambda: runner.state == "running" and runner.progress().t > 0.2, timeout=5.0)
    runner.estop()
    assert runner.join(timeout=3.0)
    assert runner.state == "estopped"
    assert motor.status().state == "ESTOP"
    assert wait_for(lambda: hw.rig.belt_speed < 1e-3, timeout=2.0)
    assert motor.status().state == "ESTOP"  # still latched at rest


def test_regulator_error_mid_ramp_aborts_with_reason(bench, tmp_path):
    cfg, hw, motor = bench
    text = 'start_m_per_s = 0.1\n[[segment]]\nkind = "hold"\nduration_s = 10.0\n'
    runner = RampRunner.from_file(motor, _write(tmp_path, text), **_limits(cfg)).start()
    assert wait_for(lambda: runner.state == "running" and runner.progress().t > 0.2, timeout=5.0)
    hw.motor.handle("ESTOP")  # the operator's panel e-stop: the next set point is refused (latched)
    assert runner.join(timeout=3.0)
    assert runner.state == "aborted"
    assert "regulator error" in runner.reason and "ERR 5" in runner.reason
    assert runner.events[-1].kind == "aborted"
    assert runner.error is not None


@pytest.mark.slow
def test_seed_ramp_time_scaled(bench):
    """Paper 001 eq. (11) with V0 = 0.17 m/s, run in 3 s instead of Tmax = 45 s (time_scale = 3/45)."""
    cfg, hw, motor = bench
    ramp = seed_ramp(0.17, 45.0)
    kinds, starts = segment_bounds(ramp, np.array([0.0, 45.0]))
    assert kinds == ["seed"] and list(starts) == [0.0]
    runner = RampRunner.from_ramp(motor, ramp, **_limits(cfg), cfg=RampRunnerCfg(time_scale=3.0 / 45.0))
    assert runner.duration == pytest.approx(3.0)
    runner.start()
    assert runner.join(timeout=12.0) and runner.state == "finished", runner.reason
    h = runner.history
    prog = h["t"] >= 0
    t, vset, vb = h["t"][prog], h["vb_set"][prog], h["vb"][prog]
    # commanded speed is v = V0 (1 - t/3): eq. (11) with t scaled by 45/3
    assert np.allclose(vset, 0.17 * (1.0 - t / 3.0), atol=1e-6)
    ok = np.isfinite(vb)
    assert np.median(np.abs(vb[ok] - vset[ok])) < 0.006
    assert [e.kind for e in runner.events] == ["segment_start", "segment_end", "finished"]


def test_load_ramp_and_time_scaled_table_agree(tmp_path):
    text = 'start_m_per_s = 0.0\n[[segment]]\nkind = "linear"\nduration_s = 2.0\nto_m_per_s = 0.2\n'
    ramp, rt, rv = load_ramp(_write(tmp_path, text))
    r = RampRunner(object(), rt, rv, max_speed=0.5, max_accel=0.5, ramp=ramp,  # type: ignore[arg-type]
                   cfg=RampRunnerCfg(time_scale=0.5))
    assert r.duration == pytest.approx(1.0)
    assert r.command_at(0.5) == pytest.approx(0.1)
    assert r.segment_at(0.99) == 0
