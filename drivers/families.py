"""The instrument families' registry: which driver serves each ``family`` of a rig config's [instruments].

It works as python-can finds its interfaces (can/interfaces/__init__.py): a dict from
family name to where the driver class lives, imported only when a rig's drivers are built,
so nothing here costs a transport import. Each family's settings are declared once, in
daq/config.py (the layer below the drivers; the module docstring there says why); the driver
class builds itself from them with ``from_settings(name, settings, rig)``.

Adding a family: its settings model in daq/config.py (and in its ``Instrument`` union), its
driver module and one line in ``FAMILIES`` here; its simulator module and one line in
sim_backends/families.py. Drivers never learn about simulators.

Decision record: docs/decisions/0016-instrument-family-registry.md.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Literal

from daq.config import CanSettings, InstrumentSettings, MotorSettings, StreamSettings, ThermocoupleSettings


def load_class(where: str) -> type:
    """The class named by ``"package.module:Class"``, importing its module now."""
    module, _, name = where.partition(":")
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class Family:
    """One instrument family: its settings model, its driver, and the driver's role in a rig."""

    settings: type[InstrumentSettings]
    driver: str  # "module:Class"; the class has from_settings(name, settings, rig)
    role: Literal["motor", "source"]  # the rig's one motor regulator, or a SampleSource

    def driver_class(self) -> type:
        return load_class(self.driver)


#: every instrument family, by the ``family`` value of its [instruments] entry
FAMILIES: dict[str, Family] = {
    "motor-regulator": Family(MotorSettings, "drivers.motor:SerialMotorRegulator", "motor"),
    "can-sensors": Family(CanSettings, "drivers.can_sensors:CanSensorDriver", "source"),
    "serial-stream": Family(StreamSettings, "drivers.serial_stream:BinaryStreamDriver", "source"),
    "thermocouple": Family(ThermocoupleSettings, "drivers.thermocouple:ThermocoupleDriver", "source"),
}
