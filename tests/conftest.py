"""Shared fixtures (rig configs and short simulations, computed once per session), and the order files run in.

`make test` runs the suite on two pytest-xdist workers, a file to a worker at a time (``-n 2 --dist loadfile
--no-loadscope-reorder``: a module's fixtures, such as a daemon, are started once), taking files in collection
order: RUN_FIRST below, then the files with a slow test, then the rest. Tests that take seconds are marked
``slow``: ``pytest -m "not slow"`` is the quick loop (``make test`` runs them all).
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

pytest.register_assert_rewrite("helpers")  # its assertions explain themselves as a test file's do

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")

# The long files, in the order the two workers take them (seconds: the file's tests summed, `make test` on a 2-core
# machine with both workers busy, 2026-11-28: 2663 s in all, 1363 s of wall time). First the long computations, both
# workers busy with fits and simulations; then the files that run in real time (a daemon against a simulated bench, a
# soak, a browser), paired with each other rather than with a fit that keeps both cores busy: their assertions hold
# rates and reaction times to bounds. The short files come last, so the two workers finish together. Re-measure
# (`DAQ_TEST_TIMELINE=FILE`, then `python tests/timeline.py FILE`) when a file grows or shrinks by tens of seconds; a
# new long file belongs in the list. Why not three workers with the real-time files on one:
# docs/decisions/0042-the-suite-on-three-workers.md (tried, rejected); why not the real-time files as one chain beside
# one fit: 0045 (tried, withdrawn: the soak's motor poll failed once in six clean clones); nor that chain at full
# priority beside fits at nice 10 on three workers: 0047 (tried, withdrawn: the closed-loop demo missed its floor once
# in six).
RUN_FIRST = (
    # computations
    "test_rsf.py",  # 190 s: two of the user's paths
    "test_propose_loop.py",  # 273 s: two experiment loops through the CLI on the reference rig
    "test_recovery.py",  # 203 s
    "test_diagnose.py",  # 347 s
    "test_real_slider.py",  # 79 s
    "test_refsim.py",  # 138 s
    "test_robust.py",  # 82 s
    "test_belt_model.py",  # 43 s
    "test_paper000.py",  # 41 s
    "test_archive.py",  # 127 s: Dask clusters
    "test_diagnose_multi.py",  # 66 s
    "test_propose.py",  # 25 s
    "test_api.py",  # 25 s (2026-12-08): the loop from Python, one diagnosis and one proposal
    "test_failures.py",  # 25 s (2026-12-08): fits that fail, contained (a diagnosis, compares, a proposal, a job)
    # in real time
    "test_demo_loop.py",  # 276 s: two runs through the daemon, diagnoses, a proposal
    "test_tutorial.py",  # 84 s (2026-12-08, a loaded machine): the tutorial's recording through the daemon, its loop
    "test_campaign.py",  # 82 s
    "test_daemon_e2e.py",  # 125 s
    "test_soak.py",  # 63 s: a half-minute soak
    "test_web.py",  # 105 s
    "test_reliability_web.py",  # 33 s
    "test_reliability_daemon.py",  # 42 s
    "test_crash_recovery.py",  # 44 s
)


def pytest_collection_modifyitems(config, items):
    """RUN_FIRST's files in its order, then the other files with a slow test, then the rest (a stable sort: inside a
    file, and within each of the last two parts, the order is unchanged)."""
    rank = {name: i for i, name in enumerate(RUN_FIRST)}
    with_slow = {item.path.name for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank) + (item.path.name not in with_slow)))


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


def pytest_configure(config):
    """Every `daq` command the suite runs (in its processes, and in the CLI subprocesses and daemons they start) logs
    an exception it ends in to one file (daq.cli.main.TRACEBACK_LOG), set here by the process that reports, before
    xdist starts its workers (they inherit it)."""
    from daq.cli.main import TRACEBACK_LOG

    if not hasattr(config, "workerinput") and not os.environ.get(TRACEBACK_LOG):
        fd, path = tempfile.mkstemp(prefix="daq-tracebacks-", suffix=".jsonl")
        os.close(fd)
        os.environ[TRACEBACK_LOG] = path


def pytest_sessionfinish(session, exitstatus):
    """No command of the suite ended in a traceback (issue 59): a LinAlgError, a FloatingPointError or a ValueError from
    a diagnosis, a comparison or a proposal is a numerical failure the product must contain and report, and any other
    exception a command ended in is a defect too, even where its test looked only at the exit status. The run fails
    with the tracebacks printed. Said by the process that reports, after every worker has ended."""
    from daq.cli.main import TRACEBACK_LOG
    from helpers import logged_tracebacks

    if hasattr(session.config, "workerinput") or not os.environ.get(TRACEBACK_LOG):
        return
    found = logged_tracebacks(Path(os.environ[TRACEBACK_LOG]))
    if found:
        tr = session.config.pluginmanager.get_plugin("terminalreporter")
        for e in found:
            tr.write_line(f"daq {' '.join(e['argv'])} ended in {e['type']}:\n{e['traceback']}", red=True)
        tr.write_line(f"{len(found)} daq command(s) ended in a traceback (tests/conftest.py: pytest_sessionfinish)",
                      red=True)
        session.exitstatus = 1


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
    """With DAQ_TEST_TIMELINE=FILE, each test's worker, start and end (wall clock), and the CPU it cost are appended
    to FILE: how the two workers filled the suite's time, to re-order RUN_FIRST by, and where the CPU went, to cut
    (tests/timeline.py reads it). Why CPU too: the suite is compute-bound (its wall time is about half its CPU on two
    cores), so a test's wall time beside another says little about what it costs. The CPU is the worker's own and
    its reaped children's (a forked pool's, a CLI subprocess's, a daemon's with what it reaped), counted in the test
    that reaps them."""
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
