"""Shared fixtures: rig configs and short simulations, computed once per session."""

from __future__ import annotations

import os

import matplotlib
import pytest

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def brake_cfg():
    from daq.config import load_rig

    return load_rig("brake-2dof")


@pytest.fixture(scope="session")
def drum_cfg():
    from daq.config import load_rig

    return load_rig("drum-pendulum")


@pytest.fixture(scope="session")
def belt_cfg():
    from daq.config import load_rig

    return load_rig("belt-ndof")


@pytest.fixture(scope="session")
def brake_seed_run(brake_cfg):
    """The 45 s seed run of paper 001 at 1 kHz, noise-free."""
    from daq.sim.run import simulate

    return simulate(brake_cfg, noise=False)
