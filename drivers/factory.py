"""Build a rig's drivers from its config's ``[instruments]`` table.

The config names real endpoints (serial device paths, CAN interface/channel);
``endpoints`` overrides them per instrument, which is how ``--sim`` points the
very same drivers at simulated instruments: the drivers never know the difference.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from daq.config import CanInstrument, MotorInstrument, RigConfig, StreamInstrument, ThermocoupleInstrument
from daq.errors import InputError

from .base import SampleSource
from .can_sensors import CanBusCfg, CanSensorCfg, CanSensorDriver, SensorSelection
from .motor import MotorCfg, SerialMotorRegulator
from .serial_stream import BinaryStreamCfg, BinaryStreamDriver, stream_channels
from .thermocouple import ThermocoupleCfg, ThermocoupleDriver


@dataclass
class RigDrivers:
    """The motor regulator (if any) and every streaming source of one rig."""

    motor: SerialMotorRegulator | None = None
    sources: dict[str, SampleSource] = field(default_factory=dict)

    def open(self) -> None:
        """Open every source (absent devices go to reconnecting, they do not fail) and the motor."""
        for src in self.sources.values():
            src.open()
        if self.motor is not None:
            self.motor.open()

    def close(self) -> None:
        for src in self.sources.values():
            src.close()
        if self.motor is not None:
            self.motor.close()


def build_drivers(cfg: RigConfig, endpoints: dict[str, dict[str, Any]] | None = None,
                  include_disabled: bool = False) -> RigDrivers:
    """Drivers for the enabled instruments of ``cfg``; ``endpoints[name]`` overrides url/interface/channel."""
    endpoints = endpoints or {}
    out = RigDrivers()
    for name, inst in cfg.instruments.items():
        if not (inst.enabled or include_disabled):
            continue
        over = endpoints.get(name, {})
        unknown = set(over) - {"url", "interface", "channel", "bitrate"}
        if unknown:
            raise InputError("endpoints", f"{name}.{sorted(unknown)[0]}", "unknown endpoint key")
        if isinstance(inst, MotorInstrument):
            out.motor = SerialMotorRegulator(MotorCfg(url=over.get("url", inst.url), baudrate=inst.baudrate,
                                                      watchdog_ms=inst.watchdog_ms, heartbeat_s=inst.heartbeat_s),
                                             name=name)
        elif isinstance(inst, CanInstrument):
            bus = CanBusCfg(interface=over.get("interface", inst.interface), channel=over.get("channel", inst.channel),
                            bitrate=over.get("bitrate", inst.bitrate))
            out.sources[name] = CanSensorDriver(CanSensorCfg(
                name=name, bus=bus, select=SensorSelection(rig=cfg.rig, channels=list(inst.channels))))
        elif isinstance(inst, StreamInstrument):
            out.sources[name] = BinaryStreamDriver(BinaryStreamCfg(
                url=over.get("url", inst.url), baudrate=inst.baudrate,
                channels=stream_channels(cfg, inst.channels)), name=name)
        elif isinstance(inst, ThermocoupleInstrument):
            out.sources[name] = ThermocoupleDriver(ThermocoupleCfg(
                url=over.get("url", inst.url), baudrate=inst.baudrate, poll_hz=inst.poll_hz), name=name)
    return out
