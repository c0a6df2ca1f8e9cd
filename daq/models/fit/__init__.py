"""The fit: a model file against one or several recordings, by multiple shooting.

From the bottom up: what the model sees of a record (``data``, ``cycle_features``) and its windows (``windows``); the
simulator a model file builds (``build``); the solver, Levenberg-Marquardt on the windows' block structure with its
linear algebra and loss (``lm``, ``linalg``, ``robust``) driven by the shooting problem (``shooting``, ``stacked`` for
several records); the sessions that fit models on one record's windows (``session``, its starts in ``starts``) or
several records' (``multi_session``); forked pools (``forked``) and the kernels compiled ahead (``warm``).
Decision records: docs/decisions/0002-output-error-by-multiple-shooting.md, docs/decisions/0041-models-core-as-a-solver.md.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__, {"session": ["Session", "Fitted"], "multi_session": ["MultiSession"], "data": ["rig_data"]}
)
