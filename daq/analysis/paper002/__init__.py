"""Paper 002 (Furmanik, drum-pendulum): the friction coefficient mu(t) by eq. (2) and law (3) fitted to it.

The paper identifies its friction model in two steps, and so do we; one module per job:

- ``programme.py``: one cell's drum-speed programme (``cell_ramp``: lead-in, hold at v0, slow sweep),
  the run ``daq campaign drum`` records per (thrust, drum speed).
- ``kinematics.py``: step 1, mu(t) by eq. (2) from the measured gauges (``mu_series``), the drum's
  zero-order hold undone, the sample selection (v_min, guard band) and ``differentiation_check``.
- ``law.py``: step 2, law (3) A-E by variable projection with standard errors (``fit_law`` -> ``DrumLawFit``).
- ``analysis.py``: the whole ``daq analyse drum-mu`` (``analyse_drum_mu`` -> ``DrumMuResult``).
- ``figures.py``: mu_t.png, mu_v.png, residuals.png (``figures``).

Method, measured selection and recovery: docs/campaign.md.

Exports (``__all__``) ``analyse_drum_mu``, the cell's programme and law (3)'s fit, with their results, each imported
when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {"analysis": ["analyse_drum_mu", "DrumMuResult"], "programme": ["cell_ramp"], "law": ["fit_law", "DrumLawFit"]},
)
