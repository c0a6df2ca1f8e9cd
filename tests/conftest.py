"""Shared fixtures (rig configs and short simulations, computed once per session), and the order files run in.

`make test` runs the suite on three pytest-xdist workers on two cores, a file to a worker at a time (``-n 3 --dist
loadfile --no-loadscope-reorder``: a module's fixtures, such as a daemon, start once), except that the files that run
in real time are one unit of work, on one worker, while the other two compute. Files are taken in collection order:
RUN_FIRST below, then the files with a slow test, then the rest (docs/decisions/0042-the-suite-on-three-workers.md).
Tests that take seconds are marked ``slow``: ``pytest -m "not slow"`` is the quick loop (``make test`` runs them all).
"""

from __future__ import annotations

import os
import time

import matplotlib
import pytest
from xdist.scheduler import LoadFileScheduling

pytest.register_assert_rewrite("helpers")  # its assertions explain themselves as a test file's do

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")

# The files that run in real time (a daemon against a simulated bench, a soak, a browser): one xdist group, so one
# worker runs them one after another, never two at once (their assertions hold rates and reaction times to bounds,
# and two daemons with their benches, recorders and browsers would share two cores), starting first: the chain is
# the suite's longest (~360 s), and mostly waits on the wall clock.
REAL_TIME = (
    "test_demo_loop.py",  # 106 s: two runs through the daemon, diagnoses, a proposal
    "test_campaign.py",  # 53 s
    "test_soak.py",  # 49 s: a half-minute soak
    "test_daemon_e2e.py",  # 43 s
    "test_web.py",  # 38 s
    "test_reliability_web.py",  # 24 s
    "test_soak_memory.py",  # 19 s
    "test_reliability_daemon.py",  # 13 s
    "test_crash_recovery.py",  # 11 s
)
# The long computations, in the order the other two workers take them (seconds in a suite run on a 2-core machine:
# `DAQ_TEST_TIMELINE=FILE`, then `python tests/timeline.py FILE`). The short files come last, so the workers finish
# together. Re-measure when a file grows or shrinks by tens of seconds; a new long file belongs in a list.
RUN_FIRST = (
    *REAL_TIME,
    "test_propose_loop.py",  # 141 s: two experiment loops through the CLI on the reference rig
    "test_rsf.py",  # 112 s: two of the user's paths
    "test_diagnose.py",  # 97 s
    "test_recovery.py",  # 88 s
    "test_refsim.py",  # 62 s
    "test_real_slider.py",  # 57 s
    "test_archive.py",  # 54 s: Dask clusters
    "test_robust.py",  # 42 s
    "test_diagnose_multi.py",  # 27 s
    "test_paper000.py",  # 25 s
    "test_belt_model.py",  # 25 s
    "test_propose.py",  # 10 s
)


class _RealTimeTogether(LoadFileScheduling):
    """xdist's loadfile, a file to a worker at a time, except that REAL_TIME's files are one unit of work."""

    def _split_scope(self, nodeid: str) -> str:
        file = super()._split_scope(nodeid)
        return "real-time" if file.rsplit("/", 1)[-1] in REAL_TIME else file


@pytest.hookimpl(optionalhook=True)  # a run without xdist (``-p no:xdist``) does not know the hook
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadfile`` (``make test``) with the real-time files together: see _RealTimeTogether. (Not xdist's own
    ``loadgroup`` with marks: under pytest 9.2 it groups nothing, as it renames a node id pytest no longer reads.)"""
    if config.getvalue("dist") == "loadfile":
        return _RealTimeTogether(config, log)
    return None


def pytest_collection_modifyitems(config, items):
    """RUN_FIRST's files in its order, then the other files with a slow test, then the rest (a stable sort: inside a
    file, and within each of the last two parts, the order is unchanged)."""
    rank = {name: i for i, name in enumerate(RUN_FIRST)}
    with_slow = {item.path.name for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank) + (item.path.name not in with_slow)))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """With DAQ_TEST_TIMELINE=FILE, each test's worker, start and end (wall clock) are appended to FILE: how the two
    workers filled the suite's time, to re-order RUN_FIRST by (tests/timeline.py reads it)."""
    t0 = time.time()
    yield
    path = os.environ.get("DAQ_TEST_TIMELINE")
    if path:
        with open(path, "a", encoding="utf-8") as f:
            f.write(f"{os.environ.get('PYTEST_XDIST_WORKER', 'main')}\t{t0:.3f}\t{time.time():.3f}\t{item.nodeid}\n")


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
