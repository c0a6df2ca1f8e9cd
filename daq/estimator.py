"""The online friction estimator (issue 4): public entry points; the parts live in daq/estimation/.

* :func:`estimate_arrays` runs the algorithm over whole arrays (offline, tests);
* :class:`FrictionEstimator` is the same algorithm fed block by block;
* :class:`OnlineEstimator` puts it on the bus (subscribe, align, estimate, publish, fit).

See daq/estimation/differentiate.py for the causal differentiator and its delay, and
tests/test_estimator.py for the tolerances against the simulator's truth.
"""

from __future__ import annotations

from .estimation.core import ArrayEstimate, EstimateBlock, EstimatorCfg, FrictionEstimator, estimate_arrays
from .estimation.fit import FitResult
from .estimation.online import OnlineCfg, OnlineEstimator, OnlineStats
from .estimation.rigmodels import RigModel, rig_model

__all__ = ["ArrayEstimate", "EstimateBlock", "EstimatorCfg", "FitResult", "FrictionEstimator", "OnlineCfg",
           "OnlineEstimator", "OnlineStats", "RigModel", "estimate_arrays", "rig_model"]
