"""A whole simulated bench for one rig: the physics in real time and every instrument on its transport.

Serial instruments get a real pty each (behind a stable link in ``workdir``), CAN
sensors a python-can bus (the ``virtual`` interface unless told otherwise).
``endpoints()`` tells the driver factory where to connect; nothing else changes.
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path
from typing import Any

from daq.config import CanInstrument, MotorInstrument, RigConfig, StreamInstrument, ThermocoupleInstrument
from daq.sim.effectset import EffectRequest
from drivers.can_sensors import CanBusCfg, SensorSelection

from .can_sensors import SimCanSensors
from .instrument import DeviceClock, SimInstrument
from .motor import SimMotorRegulator
from .pty_port import PtyPort
from .realtime import RealtimeRig
from .serial_stream import SimSerialStream
from .thermocouple import SimThermocouple

_bus_ids = itertools.count()


class SimulatedHardware:
    def __init__(self, cfg: RigConfig, workdir: str | Path, effects: list[EffectRequest] = (),
                 time_scale: float = 1.0, seed: int = 0, can_interface: str = "virtual",
                 can_channel: str | None = None, clock_drift_ppm: float = 0.0) -> None:
        self.cfg = cfg
        self.workdir = Path(workdir)
        self.rig = RealtimeRig(cfg, effects, time_scale=time_scale)
        self.ports: dict[str, PtyPort] = {}
        self.instruments: dict[str, SimInstrument] = {}
        self.motor: SimMotorRegulator | None = None
        self._endpoints: dict[str, dict[str, Any]] = {}
        channel = can_channel or f"sim-{cfg.rig}-{os.getpid()}-{next(_bus_ids)}"
        for k, (name, inst) in enumerate(cfg.instruments.items()):
            clock = DeviceClock(offset_s=100.0 * (k + 1), drift_ppm=clock_drift_ppm)
            if isinstance(inst, CanInstrument):
                bus = CanBusCfg(interface=can_interface, channel=channel, bitrate=inst.bitrate)
                self.instruments[name] = SimCanSensors(
                    self.rig, bus, SensorSelection(rig=cfg.rig, channels=list(inst.channels)), name=name,
                    clock=clock, seed=seed + k)
                self._endpoints[name] = {"interface": can_interface, "channel": channel}
                continue
            port = self.ports[name] = PtyPort(self.workdir / name)
            self._endpoints[name] = {"url": str(port.link)}
            if isinstance(inst, MotorInstrument):
                self.motor = SimMotorRegulator(self.rig, port, seed=seed + k)
            elif isinstance(inst, StreamInstrument):
                self.instruments[name] = SimSerialStream(self.rig, port, names=tuple(inst.channels),
                                                         baudrate=inst.baudrate, name=name, clock=clock,
                                                         seed=seed + k)
            elif isinstance(inst, ThermocoupleInstrument):
                self.instruments[name] = SimThermocouple(self.rig, port, name=name, clock=clock, seed=seed + k,
                                                         baudrate=inst.baudrate)

    def endpoints(self) -> dict[str, dict[str, Any]]:
        """Per-instrument overrides for drivers.factory.build_drivers."""
        return {k: dict(v) for k, v in self._endpoints.items()}

    def start(self) -> "SimulatedHardware":
        for inst in self.instruments.values():
            inst.start()
        if self.motor is not None:
            self.motor.start()
        self.rig.start()
        return self

    def stop(self) -> None:
        self.rig.stop()
        if self.motor is not None:
            self.motor.stop()
        for inst in self.instruments.values():
            inst.stop()
        for port in self.ports.values():
            port.close()

    def __enter__(self) -> "SimulatedHardware":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
