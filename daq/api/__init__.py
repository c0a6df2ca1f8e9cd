"""The researcher's loop from Python, as notebook users expect: ``daq.compare``, ``daq.diagnose``, ``daq.propose``.

Exports (``__all__``) the three steps (loop.py) and their results (results.py), each imported when first used;
``import daq`` exposes the steps themselves (``daq.compare(...)``) the same way, so that ``import daq`` stays light.
The tutorial (docs/tutorial.md) walks the loop both from the shell and from here.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "loop": ["compare", "diagnose", "propose"],
        "results": ["Comparison", "Diagnosis", "Proposal", "Figure"],
    },
)
