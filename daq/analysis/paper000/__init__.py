"""Paper 000 (Bogacz & Ryczek, belt-ndof): the friction law and the periodicity, identified from trajectories.

The paper identifies its dry-friction model from measured trajectories of 1-3 masses
on springs riding a belt (its Figs. 8-11, 19); docs/analyses-000.md has the method and
the measured recovery. Commands: ``daq analyse belt-law`` and ``daq analyse poincare``
(daq/cli/paper000.py does the I/O). The modules, in the order the analysis runs:

- preparation.py: a recording checked and put in the rig's units (BeltRun, prepare), stick episodes (find_sticks)
- equation_error.py: stage 1, the paper's least squares on f(w) points (friction_points, fit_kinetic_points),
  the law's parameter names (LAW) and the least-squares result (LsqFit)
- windows.py: slip windows cut from a recording (slip_windows) and simulated with the rig's physics (WindowSimulator)
- output_error.py: stage 2, the law fitted over slip windows (scan_break_levels, fit_output_error)
- static_law.py: f_s(t_s, Delta) fitted to the windows' break-away levels (fit_static)
- belt_law.py: the whole identification (belt_law) and its JSON (BeltLawResult)
- poincare.py: Poincaré section, period-k / irregular (poincare, PoincareResult)
- figures.py: the paper's figures from the results

Exports (``__all__``) ``prepare``, the results and the modules ``belt_law`` and ``poincare`` (their functions share
the modules' names), each imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {"preparation": ["prepare"], "belt_law": ["BeltLawResult"], "poincare": ["PoincareResult"]},
    modules=["belt_law", "poincare"],
)
