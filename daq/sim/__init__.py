"""Simulated rigs: the integrator, the rigs' adapters over daq/physics, effect selection, instruments, the run driver.

Exports (``__all__``) ``simulate``, ``make_sim`` and the effect selection, each imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "run": ["simulate"],
        "rigs": ["make_sim", "SimRig"],
        "effectset": ["parse_effect", "effect_vector", "EffectRequest"],
    },
)
