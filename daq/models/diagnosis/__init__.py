"""The diagnosis: how far a fitted model is from a record, and which physical effect it lacks.

``compare`` scores a model (its error against the noise floor, where in the cycle and the mechanics it fails);
``diagnose`` runs the forward selection over the catalog: each step screens the candidates (``screening``), fits the
promising ones (``extensions``, by ``selection``'s rules), scores them on held-out windows (``scoring``), and the
margins judge what it names (``margins``, ``verdict``); ``summary`` and ``report`` say what it found. ``recovery``
is the table of our own simulator's effects recovered through it. Decision records:
docs/decisions/0015-diagnosis-forward-selection.md, docs/decisions/0028-margins-and-honest-ties.md.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__, {"diagnose": ["Diagnosis", "Scored"]}
)
