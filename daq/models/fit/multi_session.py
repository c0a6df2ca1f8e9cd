"""Several recordings of one rig against one model: shared parameters, each record its own windows and noise.

A MultiSession holds one Session per record (its Measured, windows and noise level) and fits the model on the
windows of all of them through a StackedProblem (stacked.py): the same fits, scores and diagnosis as a Session,
each window judged against its own record. Of one record it is that record's Session, number for number.
Decision record: docs/decisions/0035-several-records-one-model.md.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from daq.config import RigConfig
from daq.errors import InputError
from daq.io.interchange import Recording

from ..spec import Model, drive_source
from . import robust
from .build import Builder
from .session import Fitted, Session
from .shooting import Problem, ShootingFit
from .stacked import StackedProblem, StackedWindows
from .windows import WINDOW_CYCLES, cycle_period, make_windows

MAX_WINDOWS = 90  # in all: each of n records cuts max(MIN_RECORD_WINDOWS, MAX_WINDOWS // n)
MIN_RECORD_WINDOWS = 30
WINDOW_SPREAD = 3.0  # the common window is the slowest record's cycle, at most this many times the fastest's
# records whose (averaged) rates differ by more than this share are refused. Within it every record's windows hold the
# same number of samples (stacked windows are cut in samples) and each record is simulated at its own rate (each
# part's Problem steps by its own 1/rate), so their windows differ in length by at most this share. A recording's
# rate is read from its host timestamps: two daemon runs of one rig gave 1000 and 1000.01 Hz on a quiet machine,
# and 999.994 and 997.464 Hz on CI's loaded one (the second's device clock mapped 0.25 % long onto the host's)
RATE_TOLERANCE = 0.02
RECORD_KEY = "#"  # per-record floors ride in the floor dict as "output#r" (it crosses a process boundary)


class MultiSession(Session):
    def __init__(self, recs: list[Recording], sources: list[str], cfg: RigConfig, max_windows: int | None = None,
                 loss: str = robust.HUBER, window_s: float | None = None) -> None:
        n = len(recs)
        if n == 0:
            raise InputError("data", "data", "no recording given")
        per = max_windows or (MAX_WINDOWS if n == 1 else max(MIN_RECORD_WINDOWS, MAX_WINDOWS // n))
        self.parts = [Session(rec, src, cfg, max_windows=per, loss=loss, window_s=window_s)
                      for rec, src in zip(recs, sources)]
        first = self.parts[0]
        for p in self.parts[1:]:
            if abs(p.m.rate / first.m.rate - 1.0) > RATE_TOLERANCE:
                raise InputError(p.source, "rate", f"sampled at {p.m.rate:g} Hz where {first.source} is at "
                                 f"{first.m.rate:g} Hz (after averaging to the model's step): resample one")
            if set(p.m.outputs) != set(first.m.outputs):
                raise InputError(p.source, "channels", f"outputs {', '.join(sorted(p.m.outputs))} where "
                                 f"{first.source} has {', '.join(sorted(first.m.outputs))}")
        if n > 1:  # one window length for all, in samples: the slowest record's cycle, within a spread
            own = [WINDOW_CYCLES * cycle_period(p.m) for p in self.parts]
            common = window_s if window_s is not None else min(max(own), WINDOW_SPREAD * min(own))
            intervals = round(common * first.m.rate)  # a window's sample intervals, the same in every record
            for p in self.parts:
                p.win = make_windows(p.m, p.m.stick_threshold(cfg), intervals / p.m.rate, max_windows=per)
        self.sources = [p.source for p in self.parts]
        self.source = ", ".join(self.sources)
        self.cfg, self.loss = cfg, loss
        self.rd, self.m, self.rec = first.rd, first.m, first.rec  # units, primary output, display
        self.win = StackedWindows.stack([p.win for p in self.parts], self.sources)
        guesses = [p.law_guess for p in self.parts]
        self.law_guess = first.law_guess if n == 1 else {k: float(np.median([g[k] for g in guesses if k in g]))
                                                         for k in dict.fromkeys(k for g in guesses for k in g)}
        self._own_fits = {}
        self._effect_guesses = {}

    @classmethod
    def open(cls, data, model: Model, rig: str | None = None, **kw) -> MultiSession:  # type: ignore[override]
        """Every path loaded as Session.open loads one (the same model, rig check and config)."""
        paths = [data] if isinstance(data, (str, Path)) else list(data)
        loaded = [Session.load(p, model, rig) for p in paths]
        recs, cfg = [rec for rec, _ in loaded], loaded[0][1]
        return cls(recs, [str(p) for p in paths], cfg, **kw)

    def problem(self, model: Model) -> StackedProblem:
        b = Builder(model)
        return StackedProblem([Problem(b, p.rd, p.m, p.win, drive_source(model), loss=self.loss) for p in self.parts],
                              self.win)

    def effect_starts(self, model: Model, values: dict[str, float], bounds: dict) -> dict[str, float]:
        """The first record's starts read from its data that has any (the record with steps gives rate-and-state's)."""
        for p in self.parts:
            out = p.effect_starts(model, values, bounds)
            if out:
                return out
        return {}

    def weighted(self, ms: dict[str, np.ndarray], windows: np.ndarray) -> np.ndarray:
        """Per window: the mean-square error of all outputs, each in units of its own record's noise."""
        rec = self.win.record[windows]
        return sum(v / np.array([p.m.sigma[k] for p in self.parts])[rec] ** 2 for k, v in ms.items())

    def record_of(self, windows: np.ndarray) -> np.ndarray:
        return self.win.record[windows]

    def window_t(self, windows: np.ndarray) -> np.ndarray:
        """Each window's start time in its own record [s]."""
        return np.array([self.parts[r].m.t[self.parts[r].win.starts[j]]
                         for r, j in zip(self.win.record[windows], self.win.local[windows])], dtype=float)

    # ------------------------------------------------------------------ one record's view of a fit

    def part_fit(self, fitted: Fitted, r: int) -> tuple[Session, Fitted]:
        """Record r's Session and the fit as if made on it alone (its windows, start values, errors, weights)."""
        part = self.parts[r]
        pr: StackedProblem = fitted.problem  # type: ignore[assignment]
        sub = pr.parts[r]
        view = Problem(sub.builder, sub.rd, sub.m, sub.win, sub.drive, loss=sub.loss)
        mine = np.flatnonzero(self.win.record == r)
        if pr.weights is not None:
            view.weights = pr.weights[mine]
        if pr.sample_weights is not None:
            view.sample_weights = pr.sample_weights[mine]

        def cut(f: ShootingFit, ms: dict[str, np.ndarray]) -> tuple[ShootingFit, dict[str, np.ndarray]]:
            keep = self.win.record[f.windows] == r
            sf = ShootingFit(f.values, f.free, f.std, f.start_values[keep], self.win.local[f.windows[keep]], f.cost,
                             f.nfev, f.success, f.message)
            return sf, {k: v[keep] for k, v in ms.items()}

        fit, ms_fit = cut(fitted.fit, fitted.ms_fit)
        held, ms_held = (fit, {}) if fitted.held is fitted.fit else cut(fitted.held, fitted.ms_held)
        return part, Fitted(fitted.model, fitted.values, fit, held, view, ms_held, ms_fit)

    def where_view(self, fitted: Fitted) -> tuple[Session, Fitted]:
        """The record that carries the most of the fit's held-out squared error (in its noise units), as one."""
        if not fitted.ms_held:
            return self.part_fit(fitted, 0)
        w = self.weighted(fitted.ms_held, fitted.held.windows)
        rec = self.win.record[fitted.held.windows]
        return self.part_fit(fitted, int(np.argmax([w[rec == r].sum() for r in range(len(self.parts))])))

    # ------------------------------------------------------------------ forward simulation and noise floor

    def free_run(self, fitted: Fitted):
        return self.parts[0].free_run(self.part_fit(fitted, 0)[1])

    def timing_noise(self, fitted: Fitted) -> float:
        """The largest clock jitter any record's residual shows (Session.timing_noise per record)."""
        if fitted._jitter_s is None:
            fitted._jitter_s = max(p.timing_noise(self.part_fit(fitted, r)[1]) for r, p in enumerate(self.parts))
        return fitted._jitter_s

    def noise_floor(self, fitted: Fitted, seed: int = 12345) -> dict[str, float]:
        """Each record's floor (Session.noise_floor on its view of the fit), pooled as the errors are: the root of the
        mean square over held-out windows, each record's floor counted once per held-out window it has. The records'
        own floors ride along as "output#r"."""
        own = [p.noise_floor(self.part_fit(fitted, r)[1], seed) for r, p in enumerate(self.parts)]
        if len(own) == 1:
            return own[0]
        n = np.array([max(int(p.win.select(True).size), 1) for p in self.parts], dtype=float)
        out = {k: float(math.sqrt(np.sum(n * np.array([f[k] for f in own]) ** 2) / n.sum())) for k in own[0]}
        out.update({f"{k}{RECORD_KEY}{r}": v for r, f in enumerate(own) for k, v in f.items()})
        return out

    def records_json(self, fitted: Fitted, floors: dict[str, float]) -> list[dict]:
        """Per record: its file, samples, windows, noise floor and the fit's held-out error of the primary output."""
        k = self.primary
        out = []
        for r, p in enumerate(self.parts):
            _, view = self.part_fit(fitted, r)
            flagged = p.win.transient if p.win.transient is not None else np.zeros(p.win.starts.size, bool)
            out.append({"data": p.source, "samples": int(p.m.n), "rate": p.m.rate,
                        "windows": {"fit": int(p.win.select(False).size), "held_out": int(p.win.select(True).size),
                                    "flagged_transient": [float(p.m.t[p.win.starts[i]]) for i in np.flatnonzero(flagged)]},
                        "noise": {"sigma": p.m.sigma, "source": p.m.sigma_source},
                        "noise_floor": floors.get(f"{k}{RECORD_KEY}{r}", floors.get(k)),
                        "error": view.rms(k)})
        return out
