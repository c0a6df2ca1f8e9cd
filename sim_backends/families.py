"""Which simulated instrument serves each instrument family: the simulator side of drivers/families.py.

Keyed by the same ``family`` names as the drivers' registry, and kept here because drivers
never import simulators (tests/test_layering.py). Each class builds itself from the family's
settings (the rig config's [instruments] entry, endpoint applied) with
``from_settings(rig, name, settings, port=..., clock=..., seed=...)``; ``port`` is the
instrument's pty for serial families and None for CAN (sim_backends/hardware.py makes the
transports). As in drivers/families.py, a module is imported only when a bench needs it.

Decision record: docs/decisions/0016-instrument-family-registry.md.
"""

from __future__ import annotations

from drivers.families import load_class

#: family -> "module:Class" of its simulated instrument
SIMULATORS: dict[str, str] = {
    "motor-regulator": "sim_backends.motor:SimMotorRegulator",
    "can-sensors": "sim_backends.can_sensors:SimCanSensors",
    "serial-stream": "sim_backends.serial_stream:SimSerialStream",
    "thermocouple": "sim_backends.thermocouple:SimThermocouple",
}


def simulator_class(family: str) -> type:
    """The simulated instrument class of ``family``."""
    return load_class(SIMULATORS[family])
