"""Friction estimation: online, by inverse dynamics of each rig with causal differentiation; and rate-and-state's
reduction of velocity steps and holds (rsf_programme, rsf_fit).

Exports (``__all__``) the online estimator, ``estimate_arrays``, ``CycleDetector`` and ``classify``, each imported when
first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "online": ["OnlineEstimator", "OnlineCfg"],
        "core": ["estimate_arrays"],
        "cycles": ["CycleDetector"],
        "regime": ["classify"],
    },
)
