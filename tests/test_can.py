"""CAN sensors end to end: SimCanSensors on a python-can virtual bus against CanSensorDriver.

Most tests step the rig from the test (the simulator encodes inside rig.step, so
what is on the bus is known exactly); the clock-drift test runs the rig in real
time, since drift is only defined against the host's clock.
"""

from __future__ import annotations

import time
import uuid
from typing import Callable

import can
import numpy as np
import pytest
from pydantic import ValidationError

from daq.config import ChannelCfg, RigConfig, load_rig
from drivers.base import BackoffCfg, DriverState, Sample
from drivers.can_sensors import (
    SEQ_SIGNAL,
    TIME_SIGNAL,
    CanBusCfg,
    CanSensorCfg,
    CanSensorDriver,
    SensorSelection,
    load_dbc,
    message_rig,
    value_signal,
)
from sim_backends.can_sensors import SimCanSensors
from sim_backends.instrument import DeviceClock, Faults
from sim_backends.realtime import RealtimeRig, Tick

RIG_CHANNELS = {  # what issue 3 puts on CAN, per rig
    "brake-2dof": {"x1", "phi"},
    "drum-pendulum": {"phi", "force_a", "thrust", "accel", "vel", "drum_speed", "drum_rev"},
    "belt-ndof": {"x1", "x2", "x3"},
}


def scale_of(rig: str, channel: str) -> float:
    """The DBC resolution of a rig's channel."""
    m = next(m for m in load_dbc().messages if message_rig(m) == rig and value_signal(m) == channel)
    return m.get_signal_by_name(channel).scale


class Bench:
    """A rig, its simulated CAN sensors and a driver on a fresh virtual channel, plus what the driver reported."""

    def __init__(self, cfg: RigConfig, *, channels: dict[str, ChannelCfg] | None = None,
                 faults: Faults | None = None, clock: DeviceClock | None = None, silence_timeout_s: float = 0.5,
                 attach: bool = True, error_frame_limit: int = 10) -> None:
        """attach=True: the simulator sends inside rig.step(); False: call sim.start() and rig.start()."""
        self.bus = CanBusCfg(interface="virtual", channel=f"test-can-{uuid.uuid4().hex}")
        self.rig = RealtimeRig(cfg)
        self.rig.set_drive(cfg.drive.V0_m_per_s)
        self.ticks: list[Tick] = []
        self.rig.subscribe(self.ticks.append)
        self.drv = CanSensorDriver(CanSensorCfg(
            name="can-test", bus=self.bus, select=SensorSelection(rig=cfg.rig), silence_timeout_s=silence_timeout_s,
            error_frame_limit=error_frame_limit, backoff=BackoffCfg(initial_s=0.02, max_s=0.1)))
        self.drv.open()
        self.sim = SimCanSensors(self.rig, self.bus, channels=channels, faults=faults, clock=clock)
        if attach:
            self.sim.attach()
        self.samples: list[Sample] = []
        self.events = []

    def step(self, ticks: int) -> None:
        for _ in range(ticks):
            self.rig.step(0.01)

    def read_once(self) -> None:
        self.samples += self.drv.read(0.02)
        self.events += self.drv.events()

    def pump(self, until: Callable[[], bool], what: str, timeout: float = 15.0) -> None:
        """Read until the condition holds; generous timeout for a loaded machine."""
        deadline = time.monotonic() + timeout
        while not until():
            assert time.monotonic() < deadline, f"timed out waiting for {what}; events {self.kinds()}"
            self.read_once()

    def pump_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.read_once()

    def pump_all(self) -> None:
        """Read until every frame the simulator sent has become a sample."""
        self.pump(lambda: len(self.samples) >= self.sim.frames_sent, "all frames")
        self.read_once()  # nothing more may come
        assert len(self.samples) == self.sim.frames_sent

    def kinds(self) -> list[str]:
        return [e.kind for e in self.events]

    def values(self, channel: str) -> np.ndarray:
        return np.array([s.value for s in self.samples if s.channel == channel])

    def truth(self, channel: str) -> np.ndarray:
        return np.concatenate([t.channels[channel] for t in self.ticks])

    def close(self) -> None:
        self.rig.stop()
        self.sim.stop()
        self.drv.close()


@pytest.fixture
def bench():
    made: list[Bench] = []

    def make(cfg: RigConfig, **kw) -> Bench:
        """A Bench closed at teardown."""
        b = Bench(cfg, **kw)
        made.append(b)
        return b

    yield make
    for b in made:
        b.close()


def in_order(kinds: list[str], wanted: list[str]) -> bool:
    """Whether wanted occurs as a subsequence of kinds."""
    it = iter(kinds)
    return all(k in it for k in wanted)


# --- the protocol definition


def test_dbc_layout_ids_and_resolution_finer_than_lsb():
    db = load_dbc()
    ids = [m.frame_id for m in db.messages]
    assert len(ids) == len(set(ids)) and all(i < 0x800 for i in ids)
    for rig_id, wanted in RIG_CHANNELS.items():
        cfg = load_rig(rig_id)
        msgs = [m for m in db.messages if message_rig(m) == rig_id]
        assert {value_signal(m) for m in msgs} == wanted
        for m in msgs:
            assert m.length == 8 and not m.is_extended_frame and m.senders
            sig = {s.name: s for s in m.signals}
            t, q, v = sig[TIME_SIGNAL], sig[SEQ_SIGNAL], sig[value_signal(m)]
            layout = (t.start, t.length, t.is_signed, q.start, q.length, v.start, v.length, v.is_signed)
            assert layout == (32, 24, False, 56, 8, 0, 32, True)
            ch = cfg.channels[v.name]
            assert v.unit == ch.unit
            if ch.lsb > 0:  # finer than the channel's lsb, and the lsb a whole number of steps
                assert v.scale <= ch.lsb / 10
                assert abs(ch.lsb / v.scale - round(ch.lsb / v.scale)) < 1e-6


def test_selection_is_validated():
    bus = CanBusCfg(interface="virtual", channel="unused")
    with pytest.raises(ValidationError, match="NO_SUCH"):
        CanSensorCfg(bus=bus, select=SensorSelection(rig="drum-pendulum", sensors=["NO_SUCH"]))
    with pytest.raises(ValidationError, match="no messages"):
        CanSensorCfg(bus=bus, select=SensorSelection(rig="no-rig"))
    cfg = CanSensorCfg(bus=bus, select=SensorSelection(rig="drum-pendulum", sensors=["DRUM_GAUGE_A"]))
    assert CanSensorDriver(cfg).channels == ["phi", "force_a"]


# --- values and times


def test_values_and_times_exact_when_noise_free(brake_cfg, bench):
    exact = {ch: ChannelCfg(unit=c.unit, instrument=c.instrument) for ch, c in brake_cfg.channels.items()}
    clock = DeviceClock(offset_s=16.5)  # time_us wraps (2^24 us = 16.78 s) 0.28 s into the run
    b = bench(brake_cfg, channels=exact, clock=clock)
    b.step(100)
    b.pump_all()
    assert b.sim.frames_sent == 2000 and b.drv.counters.lost_frames == 0
    host_ref = np.concatenate([t.host_time for t in b.ticks])
    for ch in ("x1", "phi"):
        got = [s for s in b.samples if s.channel == ch]
        assert len(got) == 1000
        np.testing.assert_allclose(b.values(ch), b.truth(ch), rtol=0, atol=scale_of("brake-2dof", ch) / 2 + 1e-12)
        dev = np.array([s.device_time for s in got])
        assert np.abs(dev - clock.device_time(host_ref, b.rig.wall0)).max() < 0.6e-6  # 1 us counter, rounded
        assert dev[-1] > 16.78  # unwrapped across the wrap
        host = np.array([s.host_time for s in got])
        assert np.all(np.isfinite(host)) and np.all(np.diff(host) >= 0)
        assert [s.seq for s in got] == [k % 256 for k in range(1000)]


@pytest.mark.parametrize("rig_id", sorted(RIG_CHANNELS))
def test_every_rig_channel_arrives_within_noise_and_lsb(rig_id, bench):
    cfg = load_rig(rig_id)
    b = bench(cfg)
    b.step(50)
    b.pump_all()
    produced = RIG_CHANNELS[rig_id] & set(b.ticks[0].channels)  # belt-ndof with one mass has only x1
    assert {s.channel for s in b.samples} == produced
    for ch in produced:
        c = cfg.channels[ch]
        v, truth = b.values(ch), b.truth(ch)
        assert v.size == truth.size == b.sim.sent[ch]
        hold = np.abs(np.diff(truth)).max() * np.ceil(b.rig.rate / c.rate_Hz) if c.rate_Hz else 0.0
        assert np.abs(v - truth).max() <= 6 * c.noise_std + c.lsb + hold + 1e-9, ch
        step = c.lsb or 1.0  # quantised values arrive as exact multiples of the lsb (counts: integers)
        assert np.abs(v / step - np.round(v / step)).max() < 1e-3, ch


# --- loss


def test_dropped_frames_counted_exactly(drum_cfg, bench):
    b = bench(drum_cfg)
    b.step(2)
    b.sim.faults.drop_prob = 0.2
    b.step(60)
    b.sim.faults.drop_prob = 0.0
    b.step(2)  # so that trailing drops are followed by a frame that shows them
    b.pump_all()
    assert b.sim.frames_dropped > 500
    assert b.drv.counters.lost_frames == b.sim.frames_dropped
    assert len(b.samples) == b.sim.frames_sent == 64 * 10 * 7 - b.sim.frames_dropped
    per_msg: dict[str, int] = {}
    for e in b.events:
        if e.kind == "lost_frames":
            per_msg[e.detail] = per_msg.get(e.detail, 0) + e.count
    names = {value_signal(m): m.name for m in SensorSelection(rig="drum-pendulum").messages()}
    assert per_msg == {names[ch]: n for ch, n in b.sim.dropped.items() if n}
    assert b.drv.counters.bus_errors == 0 and b.drv.state == DriverState.CONNECTED


def test_loss_longer_than_the_sequence_counter_is_counted_from_device_time(brake_cfg, bench):
    b = bench(brake_cfg)
    b.step(5)
    b.sim.faults.drop_prob = 1.0
    b.step(30)  # 300 frames per message: the 8-bit counter alone would say 44
    b.sim.faults.drop_prob = 0.0
    b.step(5)
    b.pump_all()
    assert b.sim.frames_dropped == 600
    assert b.drv.counters.lost_frames == 600


def test_undecodable_and_foreign_frames(brake_cfg, bench):
    b = bench(brake_cfg)
    peer = b.bus.open()
    try:
        peer.send(can.Message(arbitration_id=0x101, data=b"\x01\x02\x03", is_extended_id=False))  # too short
        peer.send(can.Message(arbitration_id=0x7F0, data=bytes(8), is_extended_id=False))  # someone else's
        peer.send(can.Message(arbitration_id=0x101, data=bytes(8), is_extended_id=True))  # 29-bit id: not ours
    finally:
        peer.shutdown()
    b.step(5)
    b.pump_all()
    c = b.drv.counters
    assert c.frame_errors == 1 and "frame_error" in b.kinds()
    assert c.extra["foreign_frames"] == 2
    assert c.bus_errors == 0 and b.drv.state == DriverState.CONNECTED


# --- faults that cut the stream


def test_isolated_error_frames_are_counted_and_the_stream_goes_on(brake_cfg, bench):
    """A real bus sees an occasional error frame and goes on; reopening it for each would cut the stream."""
    b = bench(brake_cfg)
    b.step(10)
    for _ in range(3):
        b.sim.bus_error()
        b.step(5)
    b.pump(lambda: len(b.samples) >= 500, "samples around the error frames")
    c = b.drv.counters
    assert c.bus_errors == 3 and b.kinds().count("bus_error") == 3
    assert b.drv.state == DriverState.CONNECTED and c.reconnects == 0 and "disconnected" not in b.kinds()
    assert len(b.samples) == 500 and c.lost_frames == 0  # 25 ticks x 20 samples: nothing lost around them


def test_error_frame_burst_reconnects_and_reports_the_gap(brake_cfg, bench):
    b = bench(brake_cfg, error_frame_limit=1)  # the threshold (10 in 1 s by default) reached at once
    b.step(10)
    b.sim.bus_error()
    b.step(10)  # behind the error frame: dropped with the bus
    b.pump(lambda: b.drv.state == DriverState.RECONNECTING, "disconnect")
    assert len(b.samples) == 200  # everything before the error frame was handed out
    last_dev = b.samples[-1].device_time
    b.pump(lambda: b.drv.state == DriverState.CONNECTED, "reconnect")
    b.step(10)
    b.pump(lambda: "gap" in b.kinds() and len(b.samples) >= 400, "samples after the reconnect")
    assert in_order(b.kinds(), ["connected", "bus_error", "disconnected", "connected", "gap"])
    gap = next(e for e in b.events if e.kind == "gap")
    assert gap.gap_s > 0
    c = b.drv.counters
    assert c.bus_errors == 1 and c.reconnects == 1
    assert c.lost_frames == 0  # frames missed while disconnected are the gap, not sequence loss
    assert len(b.samples) == 400 and b.samples[200].device_time > last_dev + 0.1


def test_unplug_is_silence_then_reconnect_and_gap(brake_cfg, bench):
    b = bench(brake_cfg, silence_timeout_s=0.2)
    b.step(10)
    b.pump_all()
    b.sim.unplug()
    b.step(10)  # sampled by the sensor, never sent
    b.pump(lambda: b.kinds().count("connected") >= 2, "silence detected and bus reopened")
    b.pump_for(0.6)  # still silent: the reopened bus waits for frames instead of flapping
    assert b.kinds().count("disconnected") == 1
    b.sim.replug()
    b.step(10)
    b.pump(lambda: "gap" in b.kinds() and len(b.samples) >= 400, "samples after replug")
    kinds = b.kinds()
    assert in_order(kinds, ["connected", "disconnected", "connected", "gap"])
    assert "bus_error" not in kinds and b.drv.counters.bus_errors == 0
    assert "TimeoutError" in next(e.detail for e in b.events if e.kind == "disconnected")
    assert next(e.gap_s for e in b.events if e.kind == "gap") >= 0.2 + 0.6
    assert sum(b.sim.unplugged_frames.values()) == 200
    assert b.drv.counters.lost_frames == 0 and len(b.samples) == 400 == b.sim.frames_sent


def test_device_time_after_a_long_outage_keeps_its_wraps():
    """A gap longer than half the 16.78 s counter period cannot be unwrapped from time_us alone."""
    bus = CanBusCfg(interface="virtual", channel=f"test-can-{uuid.uuid4().hex}")
    drv = CanSensorDriver(CanSensorCfg(bus=bus, select=SensorSelection(rig="brake-2dof")))
    drv.open()
    try:
        node = drv.nodes["BRAKE_LASER"]
        t0 = drv._device_time(node, 1000, host_t=50.0)
        drv._disconnect()
        drv._connect()  # a reconnection: the next time_us is anchored with the host clock
        t1 = drv._device_time(node, (1000 + 40_000_000) % (1 << 24), host_t=90.0)
        assert t1 - t0 == pytest.approx(40.0, abs=1e-6)
    finally:
        drv.close()


# --- sensor faults


def test_stuck_sensor_is_constant(brake_cfg, bench):
    b = bench(brake_cfg, faults=Faults(stuck=True))
    b.step(30)
    b.pump_all()
    x1, truth = b.values("x1"), b.truth("x1")
    assert np.ptp(truth) > 100 * brake_cfg.channels["x1"].lsb
    assert np.unique(x1).size == 1
    b.sim.faults.stuck = False
    n = len(b.samples)
    b.step(10)
    b.pump_all()
    assert np.unique(b.values("x1")[n // 2:]).size > 10


def test_saturated_sensor_is_clipped(brake_cfg, bench):
    fs = 2e-3
    b = bench(brake_cfg, faults=Faults(saturate_at=fs))
    b.step(100)
    b.pump_all()
    x1, phi, phi_true = b.values("x1"), b.values("phi"), b.truth("phi")
    assert b.truth("x1").max() > fs + 1e-3 and np.mean(phi_true < -fs - 1e-3) > 0.5
    assert np.abs(x1).max() == pytest.approx(fs, abs=1e-9) and np.sum(np.isclose(x1, fs, rtol=0, atol=1e-9)) > 10
    assert np.abs(phi).max() == pytest.approx(fs, abs=1e-9)
    assert np.allclose(phi[phi_true < -fs - 1e-3], -fs, rtol=0, atol=1e-9)


# --- clocks, in real time


@pytest.mark.slow
def test_device_clock_drift_is_estimated(brake_cfg, bench):
    b = bench(brake_cfg, clock=DeviceClock(offset_s=100.0, drift_ppm=300.0), attach=False)
    b.sim.start()
    b.rig.start()
    b.pump(lambda: len(b.samples) > 2 and b.samples[-1].device_time - b.samples[0].device_time > 3.0,
           "3 s of device time", timeout=30.0)
    expected = 300e-6  # ClockSync reports the device clock's rate error: +300 ppm = runs fast
    for name, node in b.drv.nodes.items():
        offset, drift = node.sync.estimate()
        assert abs(drift - expected) < 50e-6, (name, drift * 1e6)
    s = b.samples[-1]
    assert abs(b.drv.clock.to_host(s.device_time) - s.host_time) < 0.05
    assert b.drv.counters.lost_frames == 0 and b.sim.ticks_dropped == 0
