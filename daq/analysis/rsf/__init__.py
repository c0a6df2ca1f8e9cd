"""Rate-and-state friction's standard reductions: velocity steps and slide-hold-slide (issue 27).

Entry point: :func:`daq.analysis.rsf.analysis.analyse_rsf`; the figures in :mod:`.figures`. The fit of one event
(daq/estimation/rsf_fit.py) and the programme read back from a record (daq/estimation/rsf_programme.py) sit a layer
lower, where the model loop's fits take their rate-and-state starts from them.
"""
