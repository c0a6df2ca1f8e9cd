"""The operator daemon: acquisition, control socket, ramp runner, the estimator and recorder processes.

Exports (``__all__``) the daemon, its control socket's client and server, and ``RampRunner``, each imported when
first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "service": ["Daemon", "DaemonCfg", "run_sim_ramp"],
        "control": ["ControlClient", "ControlServer", "Reply"],
        "ramp_runner": ["RampRunner"],
    },
)
