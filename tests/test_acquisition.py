"""The acquisition glue against a whole simulated bench: drivers -> threads -> one PUB socket -> a subscriber.

Everything waits by polling with generous deadlines (a loaded 2-core CI machine), never by sleeping.
"""

from __future__ import annotations

import time
from collections import defaultdict

import numpy as np
import pytest
from helpers import brake_on_serial_stream
from pydantic import ValidationError

from daq.config import load_rig
from daq.daemon.acquisition import Acquisition, AcquisitionCfg
from daq.io.stream_format import Block, BusEvent
from daq.streaming.bus import Subscriber
from drivers.factory import build_drivers
from sim_backends.hardware import SimulatedHardware

DEADLINE_S = 8.0


class Listener:
    """Collects blocks per stream and events from a Subscriber, checking host times as they come."""

    def __init__(self, endpoint: str) -> None:
        self.sub = Subscriber(endpoint, rcvhwm=100_000)
        self.blocks: dict[str, list[Block]] = defaultdict(list)
        self.events: list[BusEvent] = []
        self.last_t: dict[str, float] = {}

    def pump(self, timeout: float = 0.05) -> None:
        msg = self.sub.recv(timeout)
        if isinstance(msg, BusEvent):
            self.events.append(msg)
        elif isinstance(msg, Block):
            s = msg.meta.stream
            assert msg.header.n > 0 and np.all(np.diff(msg.t) >= 0), s
            assert msg.t[0] >= self.last_t.get(s, -np.inf), f"{s}: host time went back across blocks"
            self.last_t[s] = float(msg.t[-1])
            self.blocks[s].append(msg)

    def until(self, cond, what: str, timeout: float = DEADLINE_S) -> None:
        t_end = time.monotonic() + timeout
        while not cond():
            assert time.monotonic() < t_end, f"timed out waiting for {what}"
            self.pump()

    def event(self, kind: str, source: str, after: int = 0) -> BusEvent | None:
        return next((e for e in self.events[after:] if e.kind == kind and e.source == source), None)

    def close(self) -> None:
        self.sub.close()


@pytest.fixture
def bench(tmp_path):
    """A running simulated brake bench, its opened drivers, a started Acquisition and a listener."""
    cfg = load_rig("brake-2dof")
    with SimulatedHardware(cfg, tmp_path) as hw:
        drivers = build_drivers(cfg, hw.endpoints())
        drivers.open()
        acq = Acquisition(cfg, drivers, AcquisitionCfg(endpoint="tcp://127.0.0.1:0"))
        acq.start()
        lis = Listener(acq.endpoint)
        try:
            yield cfg, hw, drivers, acq, lis
        finally:
            lis.close()
            acq.stop()
            try:
                drivers.motor.stop()
            except Exception:  # noqa: BLE001 - best effort; the regulator's watchdog stops it anyway
                pass
            drivers.close()


@pytest.mark.slow
def test_streams_units_motor_and_clean_stop(bench):
    cfg, hw, drivers, acq, lis = bench
    want = {"can.x1": ("x1", "m"), "can.phi": ("phi", "rad"), "thermocouple": ("temp", "degC")}
    lis.until(lambda: all(len(lis.blocks[s]) >= 3 for s in [*want, "motor"]), "every stream")
    for s, (ch, unit) in want.items():
        b = lis.blocks[s][-1]
        assert b.meta.channels == (ch,) and b.meta.units == (unit,)
        assert b.meta.rig == cfg.rig and b.meta.source == s.split(".")[0] and b.meta.rate_hz
        assert b.device_t is not None and np.all(np.isfinite(b.device_t)) and np.all(np.diff(b.device_t) > 0)
    assert lis.blocks["can.x1"][-1].meta.rate_hz == cfg.sensors.rate_Hz
    motor = lis.blocks["motor"][-1]
    assert motor.meta.channels == ("vb", "vb_set") and motor.meta.units == ("m/s", "m/s")
    assert motor.meta.rate_hz == 100.0 and motor.device_t is None

    drivers.motor.enable()
    drivers.motor.set_speed(0.1)
    lis.until(lambda: lis.blocks["motor"][-1].column("vb_set")[-1] == pytest.approx(0.1), "set point 0.1")
    lis.until(lambda: abs(lis.blocks["motor"][-1].column("vb")[-1] - 0.1) < 0.01, "belt speed near 0.1")
    # The regulator's replies carry no tag: on a starved machine a late SPD? reply from before the
    # set point can still be taken for a later poll's (seen once in CI). Until the protocol tags its
    # replies (next session), wait for the status to show the set point instead of reading it once.
    lis.until(lambda: acq.status()["motor"]["setpoint"] == pytest.approx(0.1), "status shows set point 0.1")
    st = acq.status()
    assert st["motor"]["setpoint"] == pytest.approx(0.1)
    assert st["sources"]["can"]["state"] == "connected" and st["sources"]["can"]["samples"] > 0
    assert {"lost_frames", "checksum_errors", "reconnects"} <= set(st["sources"]["thermocouple"])

    # the motor is polled near its nominal rate (loosely: a loaded machine may lag, never burst)
    t = np.concatenate([b.t for b in lis.blocks["motor"]])
    span = t[-1] - t[0]
    assert 25 <= (t.size - 1) / span <= 110

    counters = acq.counters()
    acq.stop()
    assert acq.threads_alive() == [] and not acq.running
    assert counters["can.x1"].blocks >= len(lis.blocks["can.x1"]) and counters["can.x1"].samples > 0
    acq.stop()  # idempotent


def test_driver_events_and_unplugged_thermocouple(bench):
    cfg, hw, drivers, acq, lis = bench
    lis.until(lambda: lis.blocks["thermocouple"] and lis.blocks["can.x1"], "first blocks")
    n0 = len(lis.events)
    hw.ports["thermocouple"].unplug()
    lis.until(lambda: lis.event("disconnected", "thermocouple", n0), "disconnected event")
    # the other streams keep flowing while the thermocouple is away
    counts = {s: len(lis.blocks[s]) for s in ("can.x1", "can.phi", "motor")}
    lis.until(lambda: all(len(lis.blocks[s]) >= counts[s] + 5 for s in counts), "other streams during the outage")
    assert acq.status()["sources"]["thermocouple"]["state"] == "reconnecting"

    hw.ports["thermocouple"].plug()
    lis.until(lambda: lis.event("gap", "thermocouple", n0), "gap event after replug")
    assert lis.event("connected", "thermocouple", n0).detail == "reconnected"
    gap = lis.event("gap", "thermocouple", n0)
    assert gap.gap_s is not None and gap.gap_s > 0
    n_temp = len(lis.blocks["thermocouple"])
    lis.until(lambda: len(lis.blocks["thermocouple"]) > n_temp, "temperature again")
    assert acq.status()["sources"]["thermocouple"]["reconnects"] >= 1


def test_framed_serial_stream_is_one_stream(tmp_path):
    """The binary serial stream carries x1 and phi in one frame: one stream, rows of one frame each."""
    cfg = brake_on_serial_stream()
    with SimulatedHardware(cfg, tmp_path) as hw:
        drivers = build_drivers(cfg, hw.endpoints())
        drivers.open()
        try:
            with Acquisition(cfg, drivers, AcquisitionCfg(endpoint="tcp://127.0.0.1:0", motor_hz=50)) as acq:
                lis = Listener(acq.endpoint)
                try:
                    lis.until(lambda: sum(b.header.n for b in lis.blocks["laser_serial"]) > 200, "laser rows")
                finally:
                    lis.close()
                assert acq.status()["misaligned_reads"] == 0
            b = lis.blocks["laser_serial"][-1]
            assert b.meta.channels == ("x1", "phi") and b.meta.units == ("m", "rad")
            assert b.data.shape == (b.header.n, 2) and b.device_t is not None
            assert acq.threads_alive() == []
        finally:
            drivers.close()


def test_motor_rate_must_be_at_least_50_hz():
    with pytest.raises(ValidationError):
        AcquisitionCfg(motor_hz=20)
