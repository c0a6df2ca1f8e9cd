"""The researcher's loop from Python, as notebook users expect: ``daq.compare``, ``daq.diagnose``, ``daq.propose``.

Exports (``__all__``) the three steps (loop.py) and their results (results.py), each imported when first used;
``import daq`` exposes the steps themselves (``daq.compare(...)``) the same way, so that ``import daq`` stays light.
The tutorial (docs/tutorial.md) walks the loop both from the shell and from here.
"""

from daq import lazy_exports

# a proposal's longest programme by default: twice the first record, within these (a short record's run may need
# longer to show a slow effect: aging on the brake at one speed was decided by no 10 s run of its family, by 20 s ones).
# Here, not in loop.py: `daq propose --help` says them without loading the models
MIN_RUN_S, MAX_RUN_S = 20.0, 60.0

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "loop": ["compare", "diagnose", "propose"],
        "results": ["Comparison", "Diagnosis", "Proposal", "Figure"],
    },
)
