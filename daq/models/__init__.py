"""Models against measurements: model files, fit by multiple shooting, compare, diagnose (screening, candidates).

Exports (``__all__``) the model files' functions, the fits (``Session``, ``MultiSession``), ``candidates_for`` and
``rig_data``, each imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "spec": ["Model", "seed_model", "load_model", "save_model", "add_effect", "remove_effect"],
        "session": ["Session"],
        "multi_session": ["MultiSession"],
        "candidates": ["candidates_for"],
        "data": ["rig_data"],
    },
)
