"""A whole simulated bench for one rig: the physics in real time and every instrument on its transport.

Serial instruments get a real pty each (behind a stable link in ``workdir``), CAN
sensors a python-can bus (the ``virtual`` interface unless told otherwise).
Each instrument is built by the simulator its family registers (sim_backends/families.py)
from the rig config's entry pointed at that endpoint. ``endpoints()`` tells the driver
factory where to connect; nothing else changes.
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path
from typing import Any

from daq.config import RigConfig
from daq.sim.effectset import EffectRequest
from drivers.families import FAMILIES

from .families import simulator_class
from .instrument import DeviceClock, SimInstrument
from .motor import SimMotorRegulator
from .pty_port import PtyPort
from .realtime import RealtimeRig

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
            port: PtyPort | None = None
            if inst.transport == "can":
                endpoint: dict[str, Any] = {"interface": can_interface, "channel": channel}
            else:
                port = self.ports[name] = PtyPort(self.workdir / name)
                endpoint = {"url": str(port.link)}
            self._endpoints[name] = endpoint
            sim = simulator_class(inst.family).from_settings(self.rig, name, inst.with_endpoint(endpoint), port=port,
                                                             clock=clock, seed=seed + k)
            if FAMILIES[inst.family].role == "motor":
                self.motor = sim
            else:
                self.instruments[name] = sim

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
