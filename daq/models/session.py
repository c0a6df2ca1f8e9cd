"""One recording against models: load it, cut it into windows once, fit models on the same windows.

Why a session: compare, fit and diagnose all judge models on *the same* windows
of *the same* data (fit windows and held-out windows), so errors of different
model revisions can be compared at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from daq.config import RigConfig
from daq.errors import InputError
from daq.io.interchange import Recording
from daq.io.loading import load_data
from daq.physics.effects import CATALOG

from .build import Builder
from .data import Measured, RigData, rig_data
from .shooting import FitResult, Problem, Windows, make_windows
from .spec import Model, drive_source, rig_config_for

MIN_CONTINUATION = 8  # samples
PROBE_ITER = 5  # iterations each start gets before the best one goes on


@dataclass
class Fitted:
    """A model fitted on a session's fit windows and scored on its held-out windows."""

    model: Model  # with fitted values (and their std)
    values: dict[str, float]
    fit: FitResult  # fit windows
    held: FitResult  # held-out windows (start values only)
    problem: Problem
    ms_held: dict[str, np.ndarray]  # per held-out window, mean-square error per output
    ms_fit: dict[str, np.ndarray]

    def rms(self, output: str, which: str = "held") -> float:
        ms = self.ms_held[output] if which == "held" else (
            self.ms_fit[output] if which == "fit" else np.concatenate([self.ms_fit[output], self.ms_held[output]]))
        return float(math.sqrt(np.mean(ms))) if ms.size else float("nan")

    def start_values(self) -> np.ndarray:
        """Start values (the free start-state entries) of every window of the session (fit windows' from the fit, held-out from theirs)."""
        vel = np.zeros((self.fit.windows.size + (self.held.windows.size if self.held is not self.fit else 0),
                        self.fit.start_values.shape[1]))
        vel[self.fit.windows] = self.fit.start_values
        if self.held is not self.fit:
            vel[self.held.windows] = self.held.start_values
        return vel


class Session:
    def __init__(self, rec: Recording, source: str, cfg: RigConfig, max_windows: int = 90) -> None:
        self.rec = rec
        self.source = source
        self.cfg = cfg
        self.rd: RigData = rig_data(cfg, source)
        self.m: Measured = self.rd.prepare(rec, source)
        self.win: Windows = make_windows(self.m, cfg.contact.v_stick_m_per_s, max_windows=max_windows)

    @classmethod
    def open(cls, data: str | Path, model: Model, rig: str | None = None, **kw) -> "Session":
        if rig is not None and rig != model.rig:
            raise InputError(str(data), "--rig", f"the model is for {model.rig}, not {rig}")
        rec = load_data(data, model.rig)
        return cls(rec, str(data), rig_config_for(model), **kw)

    @property
    def primary(self) -> str:
        return self.m.primary

    def problem(self, model: Model) -> Problem:
        return Problem(Builder(model), self.rd, self.m, self.win, drive_source(model))

    def fit(self, model: Model, warm: Fitted | None = None, max_iter: int = 40) -> Fitted:
        """Fit the model's free parameters on the fit windows, then score it on the held-out ones."""
        pr = self.problem(model)
        params = model.params()
        free = model.free_names()
        bounds = {n: (params[n].lo if params[n].lo is not None else -np.inf,
                      params[n].hi if params[n].hi is not None else np.inf) for n in free}
        # Starts: the model file's values (what `model add` + refit does), and, when refining a fitted
        # model, its fitted values with the new effect at its start values and switched off. No one
        # start is safe: the warm ones can sit in the smaller model's compromise (a local minimum, e.g.
        # bearing friction hidden behind extra damping), the cold one can be far away (force-rate needs
        # the fitted level and a non-zero gain). All run on half windows; the best goes on.
        starts: list[tuple[dict[str, float], np.ndarray | None]] = [(dict(pr.builder.base_values), None)]
        if warm is not None:
            new = self._new_keys(warm.model, model)
            values = dict(pr.builder.base_values)
            values.update({k: v for k, v in warm.values.items() if k in values and k not in new})
            starts.append((dict(values), warm.fit.start_values))  # the new effect at its start values
            off = switched_off(model, new)
            if any(values[k] != v for k, v in off.items()):
                values.update(off)
                starts.append((values, warm.fit.start_values))  # ... and switched off
        fw, hw = self.win.select(False), self.win.select(True)
        half = max(MIN_CONTINUATION, self.win.length // 2)
        # first on the windows' first halves: less nonlinear (a shifted break-away costs less), cheaper;
        # with several starts each gets PROBE_ITER iterations and only the best goes on (the others
        # used to run their whole half-window budget: half of a candidate's simulations)
        probe = PROBE_ITER if len(starts) > 1 else max_iter // 2
        best = min((pr.fit(values, free, bounds, fw, start_values=vel, max_iter=probe, length=half)
                    for values, vel in starts), key=lambda f: f.cost)
        if probe < max_iter // 2:
            best = pr.fit(best.values, free, bounds, fw, start_values=best.start_values,
                          max_iter=max_iter // 2 - probe, length=half)
        values, vel = best.values, best.start_values
        res = pr.fit(values, free, bounds, fw, start_values=vel, max_iter=max_iter)
        # A joint LM step can throw one window's start values into a poor local minimum that the
        # global cost hides; re-fit every fit window's start values from the data (parameters fixed, as
        # for held-out windows) and keep, per window, the better of the two.
        again = pr.fit_starts(res.values, fw, max_iter=25)
        e_joint = self.weighted(pr.window_errors(res.values, fw, res.start_values))
        e_again = self.weighted(pr.window_errors(res.values, fw, again.start_values))
        res.start_values = np.where((e_again < e_joint)[:, None], again.start_values, res.start_values)
        held = pr.fit_starts(res.values, hw, max_iter=25) if hw.size else res
        fitted_model = model.with_values({k: res.values[k] for k in free}, res.std)
        return Fitted(fitted_model, res.values, res, held, pr,
                      pr.window_errors(res.values, hw, held.start_values) if hw.size else {},
                      pr.window_errors(res.values, fw, res.start_values))

    def weighted(self, ms: dict[str, np.ndarray]) -> np.ndarray:
        """Per window: the mean-square error of all outputs, each in units of its noise."""
        return sum(v / self.m.sigma[k] ** 2 for k, v in ms.items())

    @staticmethod
    def _new_keys(old: Model, new: Model) -> set[str]:
        return set(new.params()) - set(old.params())

    # ------------------------------------------------------------------ forward simulation and noise floor

    def free_run(self, fitted: Fitted) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """The fitted model simulated over the whole record from the first window's start (no re-starts).

        Returns (sample indices, predicted outputs, states, aux). Phase drifts away from
        the data: compare cycle features (frequency, amplitude, stick fraction), not points.
        """
        pr = fitted.problem
        sim = pr.sim(fitted.values)
        w0 = 0
        s0 = self.rd.start_state(sim, self.m, int(self.win.starts[w0]))
        fitted_w = list(fitted.fit.windows)
        if w0 in fitted_w:
            s0[pr.slots] = fitted.fit.start_values[fitted_w.index(w0)]
        i0 = int(self.win.starts[w0])
        n = self.m.n - i0
        ch = sim.advance(s0, float(pr.rt[i0]), pr.h, pr.n_sub, n, pr.rt, pr.rv)
        return np.arange(i0, self.m.n), self.rd.predict(sim, ch.states), ch.states, ch.aux

    def noise_floor(self, fitted: Fitted, seed: int = 12345) -> dict[str, float]:
        """The error a perfect model shows on data like this: the fitted model scored on its own noisy output.

        The fitted model's forward run becomes a synthetic recording with the measured
        noise levels (same drive, temperature and other columns); the same windows
        procedure then scores the same model on it, start values fitted as always.
        """
        idx, pred, states, aux = self.free_run(fitted)
        rng = np.random.default_rng(seed)
        ch = {k: np.asarray(v, dtype=float)[idx] for k, v in self.rec.channels.items()}
        for k, x in pred.items():
            ch[k] = x + rng.normal(0.0, self.m.sigma[k], x.size)
        ch.update(self.rd.synthetic_extras(fitted.problem.sim(fitted.values), states, aux, ch, rng))
        syn = Recording(self.rec.rig, self.m.t[idx], ch, self.rec.units, {}, {})
        s = Session(syn, f"{self.source} (synthetic)", self.cfg, max_windows=self.win.starts.size)
        s.m.sigma = dict(self.m.sigma)  # same noise model, not a re-estimate
        pr = s.problem(fitted.model)
        allw = s.win.select(None)
        vel = pr.fit_starts(fitted.values, allw, max_iter=25)
        ms = pr.window_errors(fitted.values, allw, vel.start_values)
        # A window whose start-velocity fit ran away (seen once in 90 windows on a 600 s record) is
        # not what a perfect model shows: windows more than 5x the median rms are left out.
        wsum = self.weighted(ms)
        keep = wsum <= 25.0 * np.median(wsum)
        return {k: float(math.sqrt(np.mean(v[keep]))) for k, v in ms.items()}


def switched_off(model: Model, keys: set[str]) -> dict[str, float]:
    """Start values for an effect added to a fitted model: its strength at neutral, so the fit
    starts exactly where the smaller model ended and can only improve on it."""

    out = {}
    for k in keys:
        _, name, key = k.split(".", 2)
        spec = CATALOG.get(name)
        if spec is None:
            continue
        plist = spec.params_for(model.rig)
        if plist and plist[0].key == key and model.params()[k].free:
            out[k] = plist[0].neutral  # the first parameter of every catalog effect is its strength
    return out
