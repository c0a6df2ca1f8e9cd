"""Models against measurements, in four parts above the model files.

- ``spec`` (model files), ``candidates`` (what a diagnosis can add to a model), ``user_effects``: what a model is.
- ``fit``: a model against one or several recordings, by multiple shooting (the solver and the sessions).
- ``diagnosis``: compare a fitted model with the record, and find which physical effect it lacks.
- ``design``: the next run, under which the rival explanations a diagnosis leaves differ most.
- ``archive``: every catalogued recording diagnosed, on Dask or serially.
- ``figures``: what a researcher looks at before reading numbers.

Each part imports only the ones listed above it (tests/test_layering.py). Exports (``__all__``) the model files'
functions, the fits (``Session``, ``MultiSession``), ``candidates_for`` and ``rig_data``, each imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "spec": ["Model", "seed_model", "load_model", "save_model", "add_effect", "remove_effect"],
        "fit.session": ["Session"],
        "fit.multi_session": ["MultiSession"],
        "candidates": ["candidates_for"],
        "fit.data": ["rig_data"],
    },
)
