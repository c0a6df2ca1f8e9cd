"""Refit a model once per extension (a candidate, or a pair), in parallel processes when the machine has cores.

Why forked processes: each extension's fit is an independent multiple-shooting fit of seconds; the session (the
recording, its windows, the compiled simulators) is inherited by fork, nothing is pickled to the workers, and each
returns its fit as plain parts (session.Portable), so a fit made in a worker and one made here are the same object.
Decision records: docs/decisions/0015-diagnosis-forward-selection.md, docs/decisions/0028-margins-and-honest-ties.md.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from dataclasses import dataclass
from functools import partial

from ..candidates import Candidate
from ..fit import forked
from ..fit.linalg import FAILURES, failure_reason
from ..fit.session import Fitted, Portable, Session, portable
from ..spec import Model

FLOOR = "(noise floor)"  # the pool's one task that is not a fit


def _extend(model: Model, cands: tuple[Candidate, ...]) -> Model:
    for c in cands:
        model = c.apply(model)
    return model


@dataclass
class Extended:
    """What a task of the pool sends back: the extension's fit as plain parts, or (the FLOOR task) the noise floor."""

    task: tuple[Candidate, ...] | str
    fit: Portable | None = None
    floors: dict[str, float] | None = None
    failed: str | None = None  # the fit failed numerically: why (linalg.failure_reason)


@dataclass
class Work:
    """What every task of one pool works on (inherited by the forked workers: forked.py)."""

    session: Session
    current: Fitted
    root: Model
    cold: dict[str, float] | None


def _fit_task(work: Work, task: tuple[Candidate, ...] | str) -> Extended:
    if task == FLOOR:
        return Extended(task=task, floors=work.session.noise_floor(work.current))
    try:
        f = work.session.fit(_extend(work.root, task), warm=work.current, cold=work.cold)  # type: ignore[arg-type]
    except FAILURES as exc:
        return Extended(task=task, failed=failure_reason(exc))
    return Extended(task=task, fit=portable(f))


def fit_extensions(session: Session, current: Fitted, tasks: list[tuple[Candidate, ...]], workers: int | None = None,
                   on_done=None, floors: dict | None = None,
                   cold: dict[str, float] | None = None,
                   root: Model | None = None,
                   cost: dict[Candidate, float] | None = None,
                   failures: dict[tuple[Candidate, ...], str] | None = None) -> dict[tuple[Candidate, ...], Fitted]:
    """Refit the current model once per extension (a candidate, or a pair), each from the current fit with
    the new parameters at neutral, in parallel processes if we can. Given a dict ``floors``, the current
    fit's noise floor is computed too (filled in): in the pool it fills the gap an odd number of fits leaves.
    Given a ``root``, the extensions are of the root model (a model with less than the current one, which
    then gives only the start values: the backward check of prune). ``cost``: a guess at each candidate's cost per
    simulation; the costliest tasks go to the pool first (the order of the results does not depend on it: on the brake
    bench accel-sign (body) took 7.2 s of 20.6 s of fits and, started last, held one core alone for 4 s).
    A task whose fit fails numerically (linalg.FAILURES) is left out of the result, its reason put in ``failures``
    (every caller passes one: a failed fit is reported, not lost) and given to ``on_done`` as a second argument
    (decision 50)."""
    root = root or current.model
    workers = workers or min(len(tasks) + (floors is not None), os.cpu_count() or 1)
    out: dict[tuple[Candidate, ...], Fitted] = {}
    if workers > 1 and "fork" in mp.get_all_start_methods():
        todo: list = list(tasks)
        if cost:
            todo.sort(key=lambda t: -sum(cost.get(c, 0.0) for c in t))  # stable: equal guesses keep their order
        todo = ([FLOOR] if floors is not None else []) + todo
        with forked.pool(workers, partial(_fit_task, Work(session, current, root, cold))) as pool:
            for done in pool.imap_unordered(forked.run, todo):
                if done.floors is not None:
                    floors.update(done.floors)  # type: ignore[union-attr]
                    continue
                _collect(session, done, out, failures, on_done)
        return out
    if floors is not None:
        floors.update(session.noise_floor(current))
    work = Work(session, current, root, cold)
    for task in tasks:
        _collect(session, _fit_task(work, task), out, failures, on_done)
    return out


def _collect(session: Session, done: Extended, out: dict, failures: dict | None, on_done) -> None:
    """A task's answer into the results (its fit) or the failures (its reason); on_done told either way."""
    if done.failed is not None:
        if failures is not None:
            failures[done.task] = done.failed
        if on_done:
            on_done(done.task, done.failed)
        return
    out[done.task] = session.restore(done.fit)
    if on_done:
        on_done(done.task)


def keep_fits(seen: dict, prefix: tuple[Candidate, ...], fits: dict[tuple[Candidate, ...], Fitted]) -> None:
    """Remember each fit by the set of candidates the base model was extended by (the current model's ``prefix``
    and the task's); of two fits of one model the lower fit cost is kept (all share the base fit's window weights)."""
    for task, f in fits.items():
        key = frozenset(prefix + task)
        if key not in seen or f.fit.cost < seen[key].fit.cost:
            seen[key] = f
