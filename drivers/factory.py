"""Build a rig's drivers from its config's ``[instruments]`` table.

Each entry's ``family`` finds its driver class through the one registry,
drivers/families.py; the class builds itself from the entry's settings
(``from_settings``). The config names real endpoints (serial device paths, CAN
interface/channel); ``endpoints`` overrides them per instrument, which is how ``--sim``
points the very same drivers at simulated instruments: the drivers never know the difference.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from daq.config import ENDPOINT_KEYS, RigConfig
from daq.errors import InputError

from .base import SampleSource
from .families import FAMILIES
from .motor import SerialMotorRegulator

#: every key an endpoint override may have (a family takes those of its transport)
_ENDPOINT_KEYS = {k for keys in ENDPOINT_KEYS.values() for k in keys}


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
        unknown = set(over) - _ENDPOINT_KEYS
        if unknown:
            raise InputError("endpoints", f"{name}.{sorted(unknown)[0]}", "unknown endpoint key")
        family = FAMILIES[inst.family]
        driver = family.driver_class().from_settings(name, inst.with_endpoint(over), cfg)
        if family.role == "motor":
            out.motor = driver
        else:
            out.sources[name] = driver
    return out
