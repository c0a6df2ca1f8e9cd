"""Several recordings of one rig as one shooting problem: shared parameters, each window its own record's.

Why stacked and not concatenated: a window is started, shot and scaled by its own record (its start state, the
contact history before it, its drive table, its noise level); a concatenated record would carry one record's
contact state into the next, let a window cross the seam and keep one noise level for both. Problem.fit,
fit_starts and window_errors reach the data only through scaled, shoot and default_starts, so overriding those
three is enough. Decision record: docs/decisions/0035-several-records-one-model.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from daq.errors import InputError

from .shooting import Problem, Shot
from .windows import Windows


@dataclass
class StackedWindows(Windows):
    """The windows of several records, record after record (select() and scored() as for one)."""

    record: np.ndarray | None = None  # record of each window
    local: np.ndarray | None = None  # its index among that record's windows

    @classmethod
    def stack(cls, wins: list[Windows], sources: list[str]) -> StackedWindows:
        """One list of the records' windows; they must be equally long (the same rate and window time)."""
        for w, src in zip(wins[1:], sources[1:]):
            if w.length != wins[0].length:
                raise InputError(src, "windows", f"{w.length} samples long where {sources[0]}'s are "
                                 f"{wins[0].length}: a record too short for windows as long as the others'")
        transient = [w.transient if w.transient is not None else np.zeros(w.starts.size, bool) for w in wins]
        return cls(np.concatenate([w.starts for w in wins]), wins[0].length,
                   np.concatenate([w.held_out for w in wins]), np.concatenate(transient),
                   np.concatenate([np.full(w.starts.size, r) for r, w in enumerate(wins)]),
                   np.concatenate([np.arange(w.starts.size) for w in wins]))


class StackedProblem(Problem):
    """Windows of several records as one Problem: shared parameters; each window started, shot and scaled by its own
    record's data and noise (Problem.fit, fit_starts and window_errors unchanged)."""

    def __init__(self, parts: list[Problem], win: StackedWindows) -> None:  # (no __post_init__: it reads one record)
        first = parts[0]
        self.parts, self.win = parts, win
        self.builder, self.rd, self.m, self.drive, self.loss = first.builder, first.rd, first.m, first.drive, first.loss
        self.weights = self.sample_weights = None
        self._cache = {}
        self.outputs, self.slots, self.n_start, self.r0 = first.outputs, first.slots, first.n_start, first.r0

    def sim(self, values: dict[str, float]):
        """One simulator for every record (built once per values; the parts are handed it)."""
        sim = Problem.sim(self, values)
        for p in self.parts:
            p._cache = self._cache
        return sim

    def split(self, windows: np.ndarray):
        """(record, its part, positions in ``windows``, the part's own window indices), for each record present."""
        rec = self.win.record[windows]
        for r, p in enumerate(self.parts):
            pos = np.flatnonzero(rec == r)
            if pos.size:
                yield r, p, pos, self.win.local[windows[pos]]

    def default_starts(self, windows: np.ndarray) -> np.ndarray:
        self.sim(self.builder.base_values)
        out = np.empty((windows.size, self.n_start))
        for _, p, pos, loc in self.split(windows):
            out[pos] = p.default_starts(loc)
        return out

    def scaled(self, values: dict[str, float], windows: np.ndarray, start_values: np.ndarray | None,
               length: int | None = None) -> np.ndarray:
        self.sim(values)
        z = np.empty((windows.size, len(self.outputs), (length or self.win.length) - self.r0))
        for _, p, pos, loc in self.split(windows):
            z[pos] = p.scaled(values, loc, None if start_values is None else start_values[pos], length)
        return z

    def shoot(self, values: dict[str, float], windows: np.ndarray, start_values: np.ndarray | None = None,
              length: int | None = None) -> Shot:
        self.sim(values)
        shots = [(pos, p.shoot(values, loc, None if start_values is None else start_values[pos], length))
                 for _, p, pos, loc in self.split(windows)]
        n, L = windows.size, length or self.win.length
        s0 = shots[0][1] if shots else None
        pred = {k: np.empty((n, L)) for k in self.outputs}
        meas = {k: np.empty((n, L)) for k in self.outputs}
        states = np.empty((n, L, s0.states.shape[2] if s0 is not None else 0))
        aux = np.empty((n, L, s0.aux.shape[2] if s0 is not None else 0))
        index = np.empty((n, L), int)
        for pos, s in shots:
            for k in self.outputs:
                pred[k][pos], meas[k][pos] = s.pred[k], s.meas[k]
            states[pos], aux[pos], index[pos] = s.states, s.aux, s.index
        return Shot(windows, pred, meas, states, aux, index)
