"""Rate-and-state friction's standard reductions: velocity steps and slide-hold-slide (issue 27).

Entry point: :func:`daq.analysis.rsf.analysis.analyse_rsf`; the fit of one event in :mod:`.reduction`, the
programme read back from a record in :mod:`.programme`, the figures in :mod:`.figures`.
"""
