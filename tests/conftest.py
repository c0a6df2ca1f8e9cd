"""Shared fixtures (rig configs and short simulations, computed once per session), and the order files run in.

`make test` runs the suite on three pytest-xdist workers, a file to a worker at a time (``-n 3 --dist loadfile
--no-loadscope-reorder``: a module's fixtures, such as a daemon, are started once): the files on the clock one after
another on the first worker, the computations (COMPUTATIONS below) on the others at nice 10, the longest first. Tests
that take seconds are marked ``slow``: ``pytest -m "not slow"`` is the quick loop (``make test`` runs them all).
"""

from __future__ import annotations

import getpass
import os
import resource
import tempfile
import time
from pathlib import Path

import daq  # noqa: F401, I001 - before numpy (matplotlib's): daq pins the BLAS kernels numpy loads (decision 46)
import matplotlib
import pytest
from xdist.scheduler import LoadFileScheduling

pytest.register_assert_rewrite("helpers")  # its assertions explain themselves as a test file's do

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")

# Two kinds of file. COMPUTATIONS fit, simulate and diagnose: they need the CPU and no clock. Every other file is on
# the clock: a daemon against a simulated bench, a soak, a browser, a serial or CAN device with its reply timeout, a
# Dask cluster with its heartbeats; its assertions hold rates and reaction times to bounds.
#
# `make test` runs three workers on two cores. The files on the clock are one unit of work (_OnTheClock): the first
# worker runs them one after another, at the priority they were started with, while the two others compute at nice 10
# (_yield_to_the_clock), so a computation takes mostly the CPU the clock's processes leave. When the chain ends, its
# worker computes too. Why: paired with each other, the files on the clock waited on the wall clock at the end while
# a core idled (the machine 85-90 % busy, 607-684 s on clean clones); beside fits at the same priority, the demo's
# record and the soak's motor poll depended on the load beside them (decisions 42 and 45, withdrawn). At nice 10 a fit
# gets a tenth of a core against a process at nice 0 that wants it, and a process that wakes at nice 0 runs at once
# (not nice 19: a computation's CLI subprocess, with its 60 s timeout, must not starve beside a chain's forked fit).
# Decision record: docs/decisions/0047-computations-yield-to-the-clock.md.
#
# The computations, the longest first (CPU seconds of the file's tests, clean clone of 675c3dd on a 2-core machine,
# 2026-11-28); the short ones after, in any order. A new file is on the clock unless it is listed here: a computation
# left off the list runs at full priority in the chain (slower, never wrong); a file on the clock put on it runs at
# nice 10 beside fits (wrong). Re-measure (`DAQ_TEST_TIMELINE=FILE`, then `python tests/timeline.py FILE`) when a file
# grows or shrinks by tens of seconds.
COMPUTATIONS = (
    "test_diagnose.py",  # 183 s
    "test_propose_loop.py",  # 143 s: two experiment loops through the CLI on the reference rig
    "test_rsf.py",  # 105 s: two of the user's paths
    "test_recovery.py",  # 89 s
    "test_refsim.py",  # 52 s
    "test_real_slider.py",  # 36 s
    "test_diagnose_multi.py",  # 30 s
    "test_robust.py",  # 30 s
    "test_paper000.py",  # 19 s
    "test_belt_model.py",  # 17 s
    "test_propose.py",  # 13 s
    "test_cli_basic.py",  # 13 s
    "test_models.py",  # 10 s
    "test_archive_results.py",  # 9 s
    "test_layering.py",  # 7 s
    "test_bad_values.py",  # 6 s
    "test_paper001.py",
    "test_paper002.py",
    "test_ringing.py",
    "test_blas_kernel.py",
    "test_effect_forms.py",
    "test_effect_chain.py",
    "test_effects_sim.py",
    "test_old_readers.py",
    "test_convergence.py",
    "test_physics.py",
    "test_ramps.py",
    "test_model_rate.py",
    "test_import_mapped.py",
    "test_import.py",
    "test_config.py",
    "test_frames.py",
    "test_programmes.py",
    "test_interchange.py",
    "test_windows.py",
    "test_shooting_solver.py",
    "test_seed_case.py",
    "test_user_rig.py",
    "test_where.py",
    "test_margins.py",
    "test_timeline.py",
)
# The files on the clock, the longest first (wall seconds, paired after the computations, 2026-11-28); the others on
# the clock follow in any order.
ON_THE_CLOCK_FIRST = (
    "test_demo_loop.py",  # 93 s: two runs through the daemon, diagnoses, a proposal
    "test_campaign.py",  # 66 s
    "test_archive.py",  # 65 s: Dask clusters, a worker killed
    "test_daemon_e2e.py",  # 64 s
    "test_web.py",  # 48 s
    "test_soak.py",  # 47 s: a half-minute soak
    "test_reliability_web.py",  # 25 s
    "test_soak_memory.py",  # 18 s
    "test_reliability_daemon.py",  # 18 s
    "test_crash_recovery.py",  # 12 s
)
CHAIN = "on-the-clock"
COMPUTING_NICENESS = 10


def _is_computation(path: Path) -> bool:
    return path.name in COMPUTATIONS


class _OnTheClock(LoadFileScheduling):
    """xdist's loadfile, a file to a worker at a time, except that the files on the clock are one unit of work."""

    def _split_scope(self, nodeid: str) -> str:
        file = super()._split_scope(nodeid)
        return file if file.rsplit("/", 1)[-1] in COMPUTATIONS else CHAIN


@pytest.hookimpl(optionalhook=True)  # a run without xdist (``-p no:xdist``) does not know the hook
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadfile`` (``make test``) with the files on the clock together: see _OnTheClock. (Not xdist's own
    ``loadgroup`` with marks: under pytest 9.2 it groups nothing, as it renames a node id pytest no longer reads.)"""
    if config.getvalue("dist") == "loadfile":
        return _OnTheClock(config, log)
    return None


def pytest_collection_modifyitems(config, items):
    """The files on the clock first (ON_THE_CLOCK_FIRST's in its order: the chain's unit is then the first, and the
    first worker's), then COMPUTATIONS in its order (a stable sort: inside a file the order is unchanged)."""
    clock = {name: i for i, name in enumerate(ON_THE_CLOCK_FIRST)}
    computing = {name: i for i, name in enumerate(COMPUTATIONS)}

    def rank(item) -> tuple[int, int]:
        name = item.path.name
        if name in computing:
            return 2, computing[name]
        return (0, clock[name]) if name in clock else (1, 0)

    items.sort(key=rank)


def _yield_to_the_clock(item) -> None:
    """A worker of a parallel run that starts a computation lowers its priority to nice 10 for good (a process cannot
    raise it again): the files on the clock run in the chain on another worker (_OnTheClock), or have all run. A
    serial run keeps its priority. (A worker cannot tell ``--dist load`` from ``loadfile``: both read "no" there; in
    ``load`` a file on the clock may follow a computation on a worker at nice 10, so `make test` uses loadfile.)"""
    if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) > 1 and _is_computation(item.path):
        now = os.nice(0)
        if now < COMPUTING_NICENESS:
            os.nice(COMPUTING_NICENESS - now)


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """The machine's speed beside the suite's time, at the end of the run: the compiled brake seed run (`daq bench
    sim`'s kernel, 45 s at 1 kHz), best of three. Why: the suite is compute-bound, so its wall time is the machine's as
    much as the code's: 632 s on 2026-11-27 before the machine changed (`daq bench diagnose`'s same-run baseline, one
    forward simulation, took 0.40 s there the day before), 1330 s after (that baseline 0.85 s, this kernel 36-49 ms).
    A suite time read without it compares machines, not changes; and across 2026-11-28's kernel change (the right-hand
    side compiled into RK4's stage loop, decision 11's note) the kernel itself got 1.6x faster: 36 -> 22 ms. Said by
    the process that reports (xdist's controller), not by the workers."""
    if hasattr(config, "workerinput"):
        return
    try:
        from daq.bench.sim import SEED_DURATION, run_kernel

        run_kernel(1.0)  # compile or load the cache
        best = min(run_kernel()[0] for _ in range(3))
    except Exception as exc:  # noqa: BLE001 - a broken kernel is the tests' to report; the summary must still print
        terminalreporter.write_line(f"machine speed: not measured ({type(exc).__name__}: {exc})")
        return
    terminalreporter.write_line(f"machine speed: the brake seed run ({SEED_DURATION:g} s at 1 kHz, compiled) in "
                                f"{best * 1e3:.1f} ms, best of 3 (`daq bench sim`)")


def pytest_sessionstart(session):
    """Refuse to run, in one line, when an archive catalog would claim the tests' temporary files. A recording finds
    its catalog in its folder or any parent (daq.io.archive.find_catalog, or $DAQ_ARCHIVE), so a catalog left in
    /tmp by a recording written there took every file the tests wrote under /tmp/pytest-of-USER, and the archive
    tests failed on rows that had gone elsewhere (seen on a fresh machine, 2026-11-27)."""
    from daq.io.archive import ENV, find_catalog

    base = session.config.option.basetemp or Path(tempfile.gettempdir()) / f"pytest-of-{getpass.getuser()}"
    stray = find_catalog(Path(base))
    if stray is not None:
        why = f"${ENV} is set" if os.environ.get(ENV) else "it is in a parent folder of the tests' temporary files"
        pytest.exit(f"an archive catalog at {stray} would take the files the tests write ({why}): remove it, "
                    f"unset ${ENV}, or run with --basetemp in a folder without one above it", returncode=4)


def _cpu_s() -> tuple[float, float]:
    """CPU seconds (user + system) of this process, and of its children reaped so far."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime, kids.ru_utime + kids.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """A computation's worker first yields to the clock (_yield_to_the_clock: before the test's fixtures start).
    With DAQ_TEST_TIMELINE=FILE, each test's worker, start and end (wall clock), and the CPU it cost are appended
    to FILE: how the workers filled the suite's time, to re-order COMPUTATIONS by, and where the CPU went, to cut
    (tests/timeline.py reads it). Why CPU too: the suite is compute-bound (its wall time is about half its CPU on two
    cores), so a test's wall time beside another says little about what it costs. The CPU is the worker's own and
    its reaped children's (a forked pool's, a CLI subprocess's, a daemon's with what it reaped), counted in the test
    that reaps them."""
    _yield_to_the_clock(item)
    t0, (self0, kids0) = time.time(), _cpu_s()
    yield
    path = os.environ.get("DAQ_TEST_TIMELINE")
    if path:
        self1, kids1 = _cpu_s()
        with open(path, "a", encoding="utf-8") as f:
            f.write(f"{os.environ.get('PYTEST_XDIST_WORKER', 'main')}\t{t0:.3f}\t{time.time():.3f}\t{item.nodeid}"
                    f"\t{self1 - self0:.2f}\t{kids1 - kids0:.2f}\n")


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
