"""Motor regulator: protocol, and the driver against the simulated regulator over a real pty."""

from __future__ import annotations

import contextlib
import time

import pytest
import serial

from daq.config import load_rig
from drivers.base import DriverState
from drivers.motor import MotorCfg, MotorError, MotorUnavailable, SerialMotorRegulator
from drivers.motor_protocol import ERR_LATCHED, ERR_LIMIT, ERR_STATE, LineBuffer, ProtocolError, decode, encode
from sim_backends.motor import SimMotorRegulator
from sim_backends.pty_port import PtyPort
from sim_backends.realtime import RealtimeRig


def wait_for(cond, timeout=5.0, period=0.01):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if cond():
            return True
        time.sleep(period)
    return cond()


# --------------------------------------------------------------------------- protocol


def test_line_checksum_round_trip_and_rejection():
    raw = encode("SPD 0.12000")
    assert raw.endswith(b"\r\n") and raw[-5:-2].startswith(b"*")
    assert decode(raw) == "SPD 0.12000"
    for i in range(len(raw) - 2):  # any single flipped bit in the body or checksum is refused
        bad = bytearray(raw)
        bad[i] ^= 0x04
        with pytest.raises(ProtocolError):
            decode(bytes(bad))
    with pytest.raises(ProtocolError):
        decode(b"SPD 0.1\r\n")


def test_line_buffer_splits_and_bounds_garbage():
    lb = LineBuffer(max_line=16)
    assert lb.feed(b"A*41\r\nB*4") == [b"A*41\r\n"]
    assert lb.feed(b"2\r\n") == [b"B*42\r\n"]
    assert lb.feed(b"x" * 40) == [] and lb.discarded == 40


# --------------------------------------------------------------------------- end to end


@contextlib.contextmanager
def running_bench(tmp_path, port_type: type[PtyPort] = PtyPort):
    """A brake rig running in real time, its regulator on a pty (of ``port_type``), and the driver on the pty's path,
    opened: (rig, port, regulator, driver)."""
    rig = RealtimeRig(load_rig("brake-2dof"))
    rig.start()
    port = port_type(tmp_path / "rn12")
    sim = SimMotorRegulator(rig, port).start()
    drv = SerialMotorRegulator(MotorCfg(url=str(tmp_path / "rn12"), watchdog_ms=300, heartbeat_s=0.05))
    try:
        drv.open()
        yield rig, port, sim, drv
    finally:
        drv.close()
        sim.stop()
        port.close()
        rig.stop()


@pytest.fixture()
def bench(tmp_path):
    with running_bench(tmp_path) as parts:
        yield parts


def test_commands_drive_the_simulated_belt(bench):
    rig, port, sim, drv = bench
    assert drv.identify().startswith("ID ")
    with pytest.raises(MotorError) as exc:
        drv.set_speed(0.1)  # not enabled
    assert exc.value.code == ERR_STATE
    drv.enable()
    drv.set_speed(0.1)
    assert wait_for(lambda: abs(rig.belt_speed - 0.1) < 1e-6, timeout=3.0)
    measured, setpoint = drv.read_speed()
    assert setpoint == 0.1 and abs(measured - 0.1) < 0.005  # tachometer noise 1 mm/s
    with pytest.raises(MotorError) as exc:
        drv.set_speed(0.6)  # above the rig's 0.5 m/s: refused by the regulator itself
    assert exc.value.code == ERR_LIMIT
    assert drv.read_speed()[1] == 0.1
    drv.stop()
    assert wait_for(lambda: rig.belt_speed < 1e-9, timeout=3.0)
    assert wait_for(lambda: drv.status().state == "DISABLED", timeout=2.0)


def test_acceleration_limit_shapes_the_ramp(bench):
    rig, port, sim, drv = bench
    drv.enable()
    drv.set_accel(0.2)
    t0 = time.monotonic()
    drv.set_speed(0.2)
    assert wait_for(lambda: rig.belt_speed > 0.2 - 1e-6, timeout=4.0)
    took = time.monotonic() - t0
    assert took > 0.8  # 0.2 m/s at 0.2 m/s^2 takes 1 s of (real) time
    with pytest.raises(MotorError):
        drv.set_accel(5.0)


@pytest.mark.slow
def test_watchdog_brings_belt_to_rest_when_heartbeats_stop(bench):
    rig, port, sim, drv = bench
    drv.enable()
    drv.set_speed(0.15)
    assert wait_for(lambda: rig.belt_speed > 0.149, timeout=3.0)
    time.sleep(0.5)  # heartbeats keep it running well past the 300 ms watchdog
    assert sim.state == "RUNNING" and rig.belt_speed > 0.149
    drv.stop_heartbeat()  # the daemon dies: nothing talks to the regulator any more
    assert wait_for(lambda: sim.state == "WATCHDOG", timeout=1.0)
    assert wait_for(lambda: rig.belt_speed < 1e-9, timeout=2.0)
    assert sim.watchdog_trips == 1
    with pytest.raises(MotorError) as exc:
        drv.set_speed(0.1)
    assert exc.value.code == ERR_LATCHED
    drv.reset()
    drv.enable()
    drv.set_speed(0.05)
    assert wait_for(lambda: rig.belt_speed > 0.049, timeout=2.0)


class _StallingPort(PtyPort):
    """A real pty whose reader is descheduled once, right after a read that found nothing (a loaded CI machine)."""

    stall_s = 0.0

    def read(self, timeout: float = 0.05, n: int = 4096) -> bytes:
        data = super().read(timeout, n)
        if not data and self.stall_s:
            stall, self.stall_s = self.stall_s, 0.0
            time.sleep(stall)  # the heartbeats the host writes meanwhile wait in the pty
        return data


def test_a_regulator_descheduled_after_an_empty_read_does_not_count_its_own_stall_as_silence(tmp_path):
    with running_bench(tmp_path, _StallingPort) as (rig, port, sim, drv):
        drv.enable()
        drv.set_speed(0.1)
        commands = sim.commands
        port.stall_s = 0.6  # twice the watchdog, while the host keeps beating every 50 ms
        assert wait_for(lambda: port.stall_s == 0.0, timeout=2.0)
        assert wait_for(lambda: sim.commands > commands + 5, timeout=2.0)  # the waiting beats were read
        assert sim.state == "RUNNING" and sim.watchdog_trips == 0
        drv.set_speed(0.05)  # and motion is still allowed


def test_estop_is_faster_than_stop_and_latched(bench):
    rig, port, sim, drv = bench
    drv.enable()
    drv.set_speed(0.2)
    assert wait_for(lambda: rig.belt_speed > 0.199, timeout=3.0)
    t0 = time.monotonic()
    drv.estop()
    assert wait_for(lambda: rig.belt_speed < 1e-9, timeout=2.0)
    assert time.monotonic() - t0 < 0.3  # 0.2 m/s at 2 m/s^2: 0.1 s (a controlled stop takes 0.4 s)
    with pytest.raises(MotorError) as exc:
        drv.enable()
    assert exc.value.code == ERR_LATCHED
    drv.reset()
    drv.enable()


def test_corrupted_command_is_refused_not_executed(bench):
    rig, port, sim, drv = bench
    drv.enable()
    with drv._lock:  # a command damaged on the wire: the regulator must not act on it
        drv._port.write(b"SPD 0.40000*00\r\n")
        time.sleep(0.1)
        drv._port.reset_input_buffer()
    time.sleep(0.2)
    assert sim.checksum_errors == 1
    assert rig.belt_speed == 0.0 and sim.setpoint == 0.0


def test_corrupted_replies_are_retried_and_counted(bench):
    rig, port, sim, drv = bench
    sim.corrupt_replies = 1
    drv.stop_heartbeat()
    drv.enable()  # first reply corrupted, the re-sent command's reply is good
    assert drv.frame_errors == 1
    assert sim.state == "RUNNING"


def test_a_late_reply_is_recognised_by_its_tag_and_never_answers_a_later_command(bench):
    """A starved regulator answers after the driver's timeout: the late reply must not be taken
    for the answer to the re-sent or a later command (the untagged protocol stayed one reply behind)."""
    rig, port, sim, drv = bench
    drv.stop_heartbeat()
    drv.enable()
    sim.late_by_s = drv.cfg.timeout_s + 0.15
    sim.late_replies = 1
    drv.set_speed(0.02)  # times out and is re-sent; the late OK arrives while the driver waits for the re-sent one
    sim.late_replies = 1
    assert drv.request("STAT?").startswith("STAT ")
    assert drv.frame_errors >= 2 and drv.stale_replies >= 2
    # normally caught by its tag; on a starved host it may already be discarded before the re-send
    assert any("waiting for tag" in e.detail or "late repl" in e.detail for e in drv.log.events())
    drv.set_speed(0.05)
    measured, setpoint = drv.read_speed()
    assert setpoint == pytest.approx(0.05)
    assert drv.state == DriverState.CONNECTED and drv.reconnects == 0


def test_a_write_timeout_is_a_retry_not_a_lost_port(bench, monkeypatch):
    """pyserial raises a write timeout after a complete write when the thread was descheduled past
    write_timeout; that is a starved host, not a pulled cable, and must not drop the link."""
    rig, port, sim, drv = bench
    drv.stop_heartbeat()
    real_write = drv._port.write
    calls = []

    def starved_write(data):
        calls.append(data)
        n = real_write(data)
        if len(calls) == 1:
            raise serial.SerialTimeoutException("Write timeout")
        return n

    monkeypatch.setattr(drv._port, "write", starved_write)
    drv.enable()
    assert len(calls) == 2 and drv.frame_errors == 1
    assert drv.state == DriverState.CONNECTED and drv.reconnects == 0 and sim.state == "RUNNING"


def test_a_reply_that_came_while_the_host_was_descheduled_is_read_not_timed_out(bench, monkeypatch):
    """The host's thread reads nothing yet (the regulator answers 30 ms later), then is descheduled past its reply
    timeout (a starved host): the reply waiting in the port is read, one write, no frame error, nothing discarded.
    Before 2026-11-28 the deadline was judged first: a timeout, a re-send and the good reply thrown away as late."""
    rig, port, sim, drv = bench
    drv.stop_heartbeat()
    drv.enable()
    writes, stalls = [], []
    real_write, real_read = drv._port.write, drv._port.read

    def counted_write(data):
        writes.append(data)
        return real_write(data)

    def starved_read(n=1):
        data = real_read(n)
        if not data and not stalls:
            stalls.append(n)
            time.sleep(drv.cfg.timeout_s + 0.1)  # descheduled right after an empty read
        return data

    monkeypatch.setattr(drv._port, "write", counted_write)
    monkeypatch.setattr(drv._port, "read", starved_read)
    sim.late_by_s, sim.late_replies = 0.03, 1
    errors, stale = drv.frame_errors, drv.stale_replies
    measured, setpoint = drv.read_speed()
    assert stalls and len(writes) == 1, writes
    assert drv.frame_errors == errors and drv.stale_replies == stale
    assert setpoint == 0.0 and drv.state == DriverState.CONNECTED


def test_unplug_and_replug_recover_without_restart(bench):
    rig, port, sim, drv = bench
    drv.enable()
    drv.set_speed(0.1)
    assert wait_for(lambda: rig.belt_speed > 0.099, timeout=3.0)
    drv.log.events()
    port.unplug()  # cable pulled: the regulator hears nothing, its watchdog stops the belt
    assert wait_for(lambda: drv.state == DriverState.RECONNECTING, timeout=2.0)
    with pytest.raises(MotorUnavailable):
        drv.read_speed()
    assert wait_for(lambda: rig.belt_speed < 1e-9, timeout=2.0) and sim.state == "WATCHDOG"
    port.replug()
    assert wait_for(lambda: drv.state == DriverState.CONNECTED, timeout=5.0)  # the heartbeat reconnects
    kinds = [e.kind for e in drv.log.events()]
    assert kinds.index("disconnected") < kinds.index("connected") and "gap" in kinds
    drv.reset()
    drv.enable()
    drv.set_speed(0.05)
    assert wait_for(lambda: rig.belt_speed > 0.049, timeout=2.0)
    assert drv.reconnects == 1
