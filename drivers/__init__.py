"""Instrument drivers: one abstract interface per instrument family, transports behind it (issue 3).

- ``families.py``: the registry, family name -> driver class (as python-can finds its interfaces);
  each family's settings are declared in daq/config.py;
- ``factory.py``: ``build_drivers`` turns a rig config's [instruments] into a ``RigDrivers``;
- ``base.py``: what every streaming driver shares (samples, events, reconnection, clock sync);
- ``motor.py`` / ``motor_protocol.py``: the motor regulator and its tagged line protocol;
- ``can_sensors.py`` (+ ``rig_sensors.dbc``): CAN sensors decoded with cantools;
- ``serial_stream.py`` / ``framing.py``: the high-rate binary serial stream and its frames;
- ``thermocouple.py``: the slowly polled thermocouple meter.

Drivers never import the simulators (sim_backends/, daq.sim): tests/test_layering.py.

Exports (``__all__``) ``build_drivers``, its ``RigDrivers``, what every driver shares and the family registry, each
imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__, {"factory": ["build_drivers", "RigDrivers"], "base": ["Sample", "DriverState"], "families": ["FAMILIES"]}
)
