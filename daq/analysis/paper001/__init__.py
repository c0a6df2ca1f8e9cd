"""Paper 001 (brake-2dof) analyses of a deceleration run: what the paper shows, measured on a recording
(``daq analyse brake-run``, docs/analyses-001.md).

Why one package: the spectrograms (Figs. 4, 5, 10), the phase and configuration planes (Figs. 6, 7, 11),
the effective friction coefficient of eq. (10) with a fit of law (7), and the segmentation of the run
into the regimes of section 5 all start from the same kinematics, estimated once from x1, phi and vb.
The numerical core is pure functions over numpy arrays; each choice the paper leaves open is documented
where it is made and tested.

- ``analysis.py``: :func:`analyse_run`, the whole run (arrays in, :class:`BrakeRunResult` and the figure
  data out), plane windows, the belt ramp of eq. (11).
- ``kinematics.py``: input checks and resampling (``prepare``), the centred differentiators
  (Savitzky-Golay or quintic spline).
- ``friction.py``: inverse dynamics through the rig's own equations (F, N, mu, mu_eff of eq. 10), the
  measured transition bias and the fit of law (7) (:class:`BrakeLawFit`).
- ``spectra.py``: the paper's spectrogram settings and per-column features (dominant line, f/2 line,
  entropy bandwidth).
- ``transitions.py``: the regime detectors (per cycle) and widening strips (per column),
  thresholds in :class:`TransitionCfg`.
- ``reference.py``: what the paper reports for its 160 s run and its Fig. 11 windows (``--paper-marks``).
- ``figures.py``: the four PNGs of ``--report`` (:data:`FIGURES`).

Exports (``__all__``) ``analyse_run``, its result and ``TransitionCfg``, each imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__, {"analysis": ["analyse_run", "BrakeRunResult"], "transitions": ["TransitionCfg"]}
)
