"""Thermocouple meter over a real pty: polling, frame errors (garbled, silent, ERR), unplug and reconnect."""

from __future__ import annotations

import time

import pytest
from pydantic import ValidationError

from drivers.base import BackoffCfg, DriverState, Sample
from drivers.thermocouple import ThermocoupleCfg, ThermocoupleDriver
from sim_backends.pty_port import PtyPort
from sim_backends.realtime import RealtimeRig
from sim_backends.thermocouple import SimThermocouple, format_temp

POLL_HZ = 20.0


@pytest.fixture
def meter(brake_cfg, tmp_path):
    """A running brake rig (belt moving, so the contact heats), the simulated meter and the driver on one pty."""
    rig = RealtimeRig(brake_cfg)
    rig.step(0.01)
    rig.set_drive(0.17)
    port = PtyPort(tmp_path / "tc")
    sim = SimThermocouple(rig, port, seed=4)
    drv = ThermocoupleDriver(ThermocoupleCfg(url=str(tmp_path / "tc"), poll_hz=POLL_HZ, timeout_s=0.2,
                                             reconnect_after_timeouts=3),
                             backoff=BackoffCfg(initial_s=0.02, max_s=0.1))
    rig.start()
    sim.start()
    deadline = time.monotonic() + 5.0
    while sim.value is None and time.monotonic() < deadline:  # the meter has a first reading
        time.sleep(0.01)
    drv.open()
    yield rig, port, sim, drv
    drv.close()
    sim.stop()
    rig.stop()
    port.close()


def collect(drv: ThermocoupleDriver, until, timeout: float = 10.0) -> list[Sample]:
    """Read until until(samples) holds (generous timeout for a loaded CI machine)."""
    out: list[Sample] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        out += drv.read(0.05)
        if until(out):
            return out
    raise AssertionError(f"condition not reached; got {len(out)} samples, counters {drv.counters}")


def answered(sim: SimThermocouple) -> list:
    """The meter's well-formed temperature replies so far."""
    return [a for a in sim.answers if a.command == "TEMP?" and a.value is not None
            and a.reply == format_temp(a.value)]


def test_reports_rig_temperature_at_poll_rate(meter):
    """Each sample is the meter's reply exactly, within lsb/2 + 5 sigma of the rig's true temperature."""
    rig, port, sim, drv = meter
    t0 = time.monotonic()
    samples = collect(drv, lambda s: len(s) >= 12)
    elapsed = time.monotonic() - t0
    good = answered(sim)
    assert [s.value for s in samples] == [a.value for a in good[:len(samples)]]
    ch = rig.cfg.channels["temp"]
    for s, a in zip(samples, good):
        assert s.channel == "temp" and s.value == round(s.value / ch.lsb) * ch.lsb
        assert abs(s.value - a.truth) <= ch.lsb / 2 + 5 * ch.noise_std
        assert s.device_time <= s.host_time
    assert abs(samples[-1].value - rig.last_tick.channels["temp"][-1]) < 2.0
    host = [s.host_time for s in samples]
    mean_period = (host[-1] - host[0]) / (len(host) - 1)
    assert 0.7 / POLL_HZ < mean_period < 1.5 / POLL_HZ  # polled at the configured rate, not flooded
    assert len(samples) <= elapsed * POLL_HZ + 2
    assert drv.counters.frame_errors == 0 and drv.counters.frames == len(samples)


def test_garbled_answer_is_a_frame_error_and_next_poll_succeeds(meter):
    """One corrupted reply: counted and reported, the sample skipped, the very next poll is good again."""
    rig, port, sim, drv = meter
    collect(drv, lambda s: len(s) >= 2)
    n_answers = len(sim.answers)
    sim.garble_next = 1
    after = collect(drv, lambda s: len(s) >= 2)
    assert drv.counters.frame_errors == 1
    errs = [e for e in drv.events() if e.kind == "frame_error"]
    assert len(errs) == 1 and "garbled" in errs[0].detail and "#" in errs[0].detail
    garbled = [a for a in list(sim.answers)[n_answers:] if a.reply and "#" in a.reply]
    assert len(garbled) == 1
    nxt = list(sim.answers)[list(sim.answers).index(garbled[0]) + 1]
    assert after[0].value == nxt.value and nxt.reply == format_temp(nxt.value)  # the next poll was good


def test_silent_meter_times_out_as_frame_error_and_recovers(meter):
    """No reply within timeout_s: one frame error, no reconnect (below the threshold), then samples again."""
    rig, port, sim, drv = meter
    collect(drv, lambda s: len(s) >= 1)
    sim.silent_next = 1
    collect(drv, lambda s: len(s) >= 2)
    assert drv.counters.frame_errors == 1 and drv.counters.reconnects == 0
    errs = [e.detail for e in drv.events() if e.kind == "frame_error"]
    assert len(errs) == 1 and "no complete reply" in errs[0]
    assert drv.state == DriverState.CONNECTED


def test_err_reply_is_counted_as_device_error(meter):
    """An ERR line is a well-formed refusal: a frame error with the device's text, counted apart too."""
    rig, port, sim, drv = meter
    collect(drv, lambda s: len(s) >= 1)
    sim.error_next = 1
    collect(drv, lambda s: len(s) >= 2)
    assert drv.counters.frame_errors == 1 and drv.counters.extra["device_errors"] == 1
    assert [e.detail for e in drv.events() if e.kind == "frame_error"] == ["device: ERR OPEN CIRCUIT"]


def test_persistently_silent_meter_makes_the_driver_reopen_the_port(meter):
    """reconnect_after_timeouts silent polls in a row count as a lost device: disconnected, reopened."""
    rig, port, sim, drv = meter
    collect(drv, lambda s: len(s) >= 1)
    sim.silent_next = 3
    collect(drv, lambda s: len(s) >= 2)
    kinds = [e.kind for e in drv.events()]
    assert kinds.count("frame_error") == 3 and drv.counters.reconnects == 1
    assert kinds[kinds.index("disconnected"):][:2] == ["disconnected", "connected"]


def test_unplug_replug_reconnects_same_driver(meter):
    """The meter's cable pulled and replugged: disconnected, connected, a gap; polling resumes."""
    rig, port, sim, drv = meter
    collect(drv, lambda s: len(s) >= 2)
    port.unplug()
    t0 = time.monotonic()
    deadline = t0 + 5.0
    while drv.state != DriverState.RECONNECTING and time.monotonic() < deadline:
        assert drv.read(0.05) == []
    assert drv.state == DriverState.RECONNECTING
    for _ in range(4):
        assert drv.read(0.05) == []  # retries with back-off while the link is absent
    out_s = time.monotonic() - t0
    port.replug()
    after = collect(drv, lambda s: len(s) >= 2)
    assert drv.state == DriverState.CONNECTED and drv.counters.reconnects == 1
    events = [e for e in drv.events() if e.kind in ("connected", "disconnected", "gap")]
    assert [e.kind for e in events] == ["connected", "disconnected", "connected", "gap"]
    assert events[3].gap_s >= out_s
    assert abs(after[-1].value - sim.truth) <= 1.0


def test_config_is_validated():
    """Poll rate and timeout are checked when the config is built, not when the port misbehaves."""
    with pytest.raises(ValidationError):
        ThermocoupleCfg(url="/dev/null", poll_hz=0)
    with pytest.raises(ValidationError):
        ThermocoupleCfg(url="/dev/null", timeout_s=-1)
    with pytest.raises(ValidationError):
        ThermocoupleCfg(url="/dev/null", pol_hz=10)
