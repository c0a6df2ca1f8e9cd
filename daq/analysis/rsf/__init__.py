"""Rate-and-state friction's standard reductions: velocity steps and slide-hold-slide (issue 27).

Entry point: :func:`daq.analysis.rsf.analysis.analyse_rsf`; the figures in :mod:`.figures`. The fit of one event
(daq/estimation/rsf_fit.py) and the programme read back from a record (daq/estimation/rsf_programme.py) sit a layer
lower, where the model loop's fits take their rate-and-state starts from them.

Exports (``__all__``) ``analyse_rsf`` and the module ``figures``, each imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {"analysis": ["analyse_rsf"]}, modules=["figures"])
