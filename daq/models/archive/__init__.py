"""The archive's jobs: every catalogued recording diagnosed (compared, fitted) with a model, on Dask distributed or
serially, each result kept in the catalog. Decision record: docs/decisions/0033-archive-on-dask.md.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {"jobs": ["run_job", "JobReport", "DiagnoseRow"]})
