"""Simulated instruments served over real pseudo-terminals and python-can buses (issue 3).

- ``families.py``: the registry, family name -> simulated instrument class (keyed as drivers/families.py);
- ``hardware.py``: ``SimulatedHardware``, a whole bench for one rig and the endpoints its drivers use;
- ``process.py``: that bench in a process of its own (``daq daemon --sim``);
- ``bench_client.py``: starting, asking and ending that process from another (imports no simulator);
- ``realtime.py``: the rig's physics stepped in real time, feeding every instrument;
- ``instrument.py``: what the simulated instruments share (device clock, sensor model, faults);
- ``pty_port.py``: a pseudo-terminal behind a stable link, unpluggable like a USB cable;
- ``motor.py``, ``can_sensors.py``, ``serial_stream.py``, ``thermocouple.py``: one per family.

Exports (``__all__``) the simulated bench (in-process and in a process of its own), the real-time rig and the
family registry, each imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "hardware": ["SimulatedHardware"],
        "bench_client": ["SimBenchProcess"],
        "realtime": ["RealtimeRig"],
        "families": ["SIMULATORS", "simulator_class"],
    },
)
