"""Pools of forked processes that inherit what their tasks work on (a session, its fits) instead of receiving it.

Why fork: a task is a fit of seconds on a session that holds the recording, its windows and compiled simulators;
pickling that to every worker would cost more than the fit. A forked worker has it already (copy-on-write). The
work is handed to the pool as one callable (typically ``functools.partial(task_function, state)``): the pool's
initializer gets it as an argument, and under fork a worker's arguments are inherited, never pickled. Only the
tasks (small: a candidate, an index) and the results travel through pipes.

The one module global: :data:`_WORK`, written once in each forked worker by :func:`_inherit` (the pool's
initializer), read by :func:`run`; the parent process never writes it. Decision record:
docs/decisions/0041-models-core-as-a-solver.md.
"""

from __future__ import annotations

import multiprocessing as mp
import multiprocessing.pool
import os
from collections.abc import Callable

_WORK: Callable | None = None  # in a forked worker only: what its tasks run (see the module's docstring)


def _inherit(work: Callable) -> None:
    global _WORK
    _WORK = work


def run(task):
    """A task in a worker: the pool's work applied to it (the function given to imap_unordered / apply_async)."""
    return _WORK(task)  # type: ignore[misc]


def can_fork() -> bool:
    """Fork is there, there is more than one core, and this is no pool's worker (it may not have children)."""
    return ((os.cpu_count() or 1) > 1 and "fork" in mp.get_all_start_methods()
            and not mp.current_process().daemon)


def pool(workers: int, work: Callable) -> multiprocessing.pool.Pool:
    """A pool of ``workers`` forked processes, each running ``work`` on the tasks given with :func:`run`."""
    return mp.get_context("fork").Pool(workers, initializer=_inherit, initargs=(work,))
