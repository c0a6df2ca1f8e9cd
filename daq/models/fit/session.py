"""One recording against models: load it, cut it into windows once, fit models on the same windows.

Why a session: compare, fit and diagnose all judge models on *the same* windows
of *the same* data (fit windows and held-out windows), so errors of different
model revisions can be compared at all.

Decision records: docs/decisions/0009-held-out-scoring-and-noise-floor.md, docs/decisions/0022-effects-confined-to-a-regime.md,
docs/decisions/0029-clock-jitter-in-the-floor.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from daq.config import RigConfig
from daq.errors import InputError, NumericalFailure
from daq.io.interchange import Recording
from daq.io.loading import load_data
from daq.physics.effects import CATALOG, TAIL
from daq.signals import timing_noise

from ..spec import Model, drive_source, rig_config_for, strength_key
from . import forked, robust
from .build import Builder
from .data import Measured, RigData, rig_data
from .shooting import Problem, ShootingFit
from .starts import added_chain, fit_key, free_strengths, neutral_strengths, second_starts, strength_starts
from .windows import Windows, make_windows, window_weights

MIN_CONTINUATION = 8  # samples
PROBE_ITER = 5  # iterations each start gets before the best one goes on
# A model's own fit (what compare and fit report, and the model diagnose judges every candidate against) goes on
# past its iteration limit, up to this many iterations in all, while it still converges. Why: a candidate fitted
# from an unconverged model gets the iterations the model did not, and takes the credit for them (seen in the
# demo, 3 runs of 9: accel-sign's fit stopped at 40 iterations at 6.6-7.7 um over a 5.2 um floor; round 2 then
# named stick-time or velocity-strengthening, which were not hidden; with 100 iterations the same fit reached
# 5.21 um). A candidate's own fit keeps the limit: stopping it early only makes a claim harder.
CONVERGE_ITER = 100
# An extension's fit is redone from the file's values (Session._restart_cold) only when the new parameters took
# at least half of the cost away: only then had the fit without them much to compensate for (the aging slider's
# extension took 64 %); a second fit for every small extension of a model's chain would double compare's cost
RESTART_GAIN = 0.5
# A model's own fit of an effect `model add` left at neutral also starts its strength at LADDER x the generic start
# (STRENGTH_START). Why: the fit without the effect compensates, and from a small strength the extension can stay
# in that compromise (recovery table, vel-strength/A at 1 kHz: D from 0.1 stopped at 0.14 for a hidden 0.8, 5 % of
# the excess; diagnose had reached D = 0.81 through a pair, so `model add` + `compare` fell short of what diagnose
# promised; from 1.0: D = 0.802, at the floor). Only the model's own fit: a candidate's fit with fewer starts only
# makes a claim harder, and costs the diagnosis nothing more.
LADDER = 10.0


@dataclass
class Fitted:
    """A model fitted on a session's fit windows and scored on its held-out windows."""

    model: Model  # with fitted values (and their std)
    values: dict[str, float]
    fit: ShootingFit  # fit windows
    held: ShootingFit  # held-out windows (start values only)
    problem: Problem
    ms_held: dict[str, np.ndarray]  # per held-out window, mean-square error per output
    ms_fit: dict[str, np.ndarray]
    _all_starts: np.ndarray | None = field(default=None, repr=False)  # start_values() of every window, once
    _jitter_s: float | None = field(default=None, repr=False)  # Session.timing_noise of this fit, once

    def rms(self, output: str, which: str = "held") -> float:
        """rms error of one output over the held-out windows ("held"; the fit windows when a record is too short
        to hold any out), the fit windows ("fit") or both ("all")."""
        held = self.ms_held.get(output, np.zeros(0))
        if which == "held" and held.size == 0:
            which = "fit"
        ms = held if which == "held" else (
            self.ms_fit[output] if which == "fit" else np.concatenate([self.ms_fit[output], held]))
        return float(math.sqrt(np.mean(ms))) if ms.size else float("nan")

    def start_values(self, windows: np.ndarray | None = None) -> np.ndarray:
        """Start values (the free start-state entries) of every window of the session, or of ``windows``: the fit
        windows' from the fit, the held-out ones' from theirs, any other (a flagged transient) fitted here."""
        if self._all_starts is not None:
            return self._all_starts if windows is None else self._all_starts[windows]
        n = int(self.problem.win.starts.size)
        vel = np.full((n, self.fit.start_values.shape[1]), np.nan)
        vel[self.fit.windows] = self.fit.start_values
        if self.held is not self.fit:
            vel[self.held.windows] = self.held.start_values
        rest = np.flatnonzero(np.isnan(vel[:, 0]))
        if rest.size:
            vel[rest] = self.problem.fit_starts(self.values, rest, max_iter=25).start_values
        self._all_starts = vel
        return vel if windows is None else vel[windows]


@dataclass
class Portable:
    """A fit as plain parts a forked process can send back (Session.restore makes it a Fitted again): the model as
    given (its Problem is rebuilt from it) and as fitted, values, both ShootingFits, the window errors and the window
    and sample weights the fit settled on."""

    given: Model
    model: Model
    values: dict[str, float]
    fit: ShootingFit
    held: ShootingFit
    ms_held: dict[str, np.ndarray]
    ms_fit: dict[str, np.ndarray]
    weights: np.ndarray | None
    sample_weights: np.ndarray | None


def portable(f: Fitted) -> Portable:
    """The fit ``f`` as Portable parts."""
    return Portable(given=f.problem.builder.model, model=f.model, values=f.values, fit=f.fit, held=f.held,
                    ms_held=f.ms_held, ms_fit=f.ms_fit, weights=f.problem.weights,
                    sample_weights=f.problem.sample_weights)


def no_prediction(ms_fit: dict[str, np.ndarray], ms_held: dict[str, np.ndarray]) -> None:
    """A fit whose model, at its end, predicts nothing (NaN) in some window is no fit: NumericalFailure, saying in
    how many windows. Why not go on: that window's error is NaN, so is every score made of it, and a NaN score
    passes no gate and fails none: a candidate would drop out of a diagnosis unreported (decision 50)."""
    def bad(ms: dict[str, np.ndarray]) -> tuple[int, int]:
        if not ms:
            return 0, 0
        ok = np.all(np.isfinite(np.stack(list(ms.values()))), axis=0)
        return int(ok.size - ok.sum()), int(ok.size)
    (bf, nf), (bh, nh) = bad(ms_fit), bad(ms_held)
    if bf or bh:
        raise NumericalFailure(f"the fitted model's simulation is not finite in {bf} of {nf} fit windows and {bh} of "
                               f"{nh} held-out windows")


def _joint_task(session: Session, args: tuple, _: object) -> Portable:
    """The chain's joint path in a forked process (Session._fit_own): ``session`` and ``args`` inherited by fork."""
    return portable(session._fit_warm(*args, restart=True))


class Session:
    def __init__(self, rec: Recording, source: str, cfg: RigConfig, max_windows: int = 90,
                 loss: str = robust.HUBER, window_s: float | None = None) -> None:
        if loss not in robust.LOSSES:
            raise InputError("--loss", "--loss", f"{loss!r} is not one of {', '.join(robust.LOSSES)}")
        self.source = source
        self.cfg = cfg
        self.loss = loss  # of every fit of this session's models (robust.py)
        self.rd: RigData = rig_data(cfg, source)
        self.m: Measured = self.rd.prepare(rec, source)
        self.rec: Recording = self.m.recording  # what the model sees: spikes repaired, averaged to its rate
        self.win: Windows = make_windows(self.m, self.m.stick_threshold(cfg), window_s, max_windows=max_windows)
        self.law_guess: dict[str, float] = self.rd.law_guess(self.m)  # a start from the data (reported in the JSON)
        self._own_fits: dict[tuple, Fitted] = {}  # Session.fit without ``warm``, by fit_key and the fit's settings
        self._effect_guesses: dict[tuple, dict[str, float]] = {}  # RigData.effect_guess, per (effect, form, v_ref)

    @classmethod
    def open(cls, data: str | Path, model: Model, rig: str | None = None, **kw) -> "Session":
        rec, cfg = cls.load(data, model, rig)
        return cls(rec, str(data), cfg, **kw)

    @staticmethod
    def load(data: str | Path, model: Model, rig: str | None = None) -> tuple[Recording, RigConfig]:
        """A recording for ``model`` (its rig checked) and the rig config the model is fitted with."""
        own_file = model.rig_config is not None and Path(rig or "").resolve() == Path(model.rig_config).resolve()
        if rig is not None and rig != model.rig and not own_file:  # its rig's id, or the rig file it was made from
            raise InputError(str(data), "--rig", f"the model is for {model.rig}, not {rig}")
        cfg = rig_config_for(model)
        return load_data(data, model.rig, cfg), cfg

    @property
    def primary(self) -> str:
        return self.m.primary

    def problem(self, model: Model) -> Problem:
        return Problem(Builder(model), self.rd, self.m, self.win, drive_source(model), loss=self.loss)

    def fit(self, model: Model, warm: Fitted | None = None, max_iter: int = 40,
            cold: dict[str, float] | None = None, converge: bool | None = None) -> Fitted:
        """Fit the model's free parameters on the fit windows, then score it on the held-out ones.

        Starts (each probed for PROBE_ITER iterations on the windows' first halves; the best goes on):
        the model file's values (what `model add` + `compare` does: an added effect sits at its neutral
        value, i.e. exactly where the model without it is); the same with every free effect strength that
        sits at neutral moved to a generic non-zero start (an error surface flat at neutral, e.g. a
        symmetric term, would stall there); and, when refining a fitted model (``warm``), its fitted values
        with the new parameters at the file's values, and at the non-zero starts. Whatever wins, the result
        is never worse on the fit windows than the model it extends: a fit that ends above ``warm``'s cost
        is redone from the nested start. ``cold`` (values of the model as it was written, before any fit)
        adds the start a user's `model add` + `compare` makes: the fitted base can sit in a compromise the
        new effect cannot leave (seen: velocity weakening fitted away to gamma = 0 to mimic a hidden
        velocity-strengthening term; from there D never reached its value, from the file's gamma it did).
        A free parameter that never left its start value (and is not at a bound) marks a stalled fit: it is
        restarted from moved starts and the better one kept. ``converge`` (by default: a model's own fit, no
        ``warm``) lets the last stage go on past ``max_iter`` up to CONVERGE_ITER while it still converges.
        """
        if converge is None:
            converge = warm is None
        if warm is None:  # a model's own fit: the same model fitted twice in one session is one fit (diagnose's base
            # fit is the first link of the chain its promise is fitted through, delivered_fit: 12 s of the pair case)
            key = (fit_key(model, self.cfg), max_iter, converge, tuple(sorted((cold or {}).items())))
            if key not in self._own_fits:
                self._own_fits[key] = self._fit_own(model, max_iter, cold, converge)
            return self._own_fits[key]
        return self._fit_warm(model, warm, cold, max_iter, converge)

    def _fit_own(self, model: Model, max_iter: int, cold: dict[str, float] | None, converge: bool) -> Fitted:
        """Session.fit with no ``warm``: through the chain of what `model add` left at neutral, if any."""
        chain = added_chain(model, self.cfg)
        if chain:
            # what `model add` left at neutral (effects, in the file's order, and mechanics set free at their
            # config value): fit the model without them, then add them back one at a time, each fit starting
            # from the one before, the path diagnose took for single steps. From the file's values at once a
            # fit can fall into a poor basin (seen: accel-sign and the measured drive added together, 70 um
            # where the chain reaches 7.5 um; the order matters too: the drive first, then accel-sign, also
            # ended at 70 um). With two or more added, diagnose may have added them as a pair (both at once,
            # from the fit without them): that path is fitted too, and the lower cost on the fit windows
            # wins (seen at 100 Hz: accel-sign (body) alone falls into a basin the measured drive added
            # after it cannot leave, 39 um held out; both at once from the base fit 7.7 um, diagnose's fit).
            # The two paths are independent: with two cores the joint one runs in a forked process beside the
            # sequence (the same computation either way; the pair case's compare 43 s -> 29 s)
            cold = cold or dict(self.problem(model).builder.base_values)
            root = self.fit(chain[0], max_iter=max_iter, converge=converge)
            pool, job = None, None
            if len(chain) >= 2 and forked.can_fork():
                pool = forked.pool(1, partial(_joint_task, self, (model, root, cold, max_iter, converge)))
                job = pool.apply_async(forked.run, (None,))
            try:
                warm = root
                for link in chain[1:]:
                    warm = self._fit_warm(link, warm, cold, max_iter, converge, restart=True)
                seq = self._fit_warm(model, warm, cold, max_iter, converge, restart=True)
                if len(chain) < 2:
                    return seq
                joint = (self.restore(job.get()) if job is not None
                         else self._fit_warm(model, root, cold, max_iter, converge, restart=True))
            finally:
                if pool is not None:
                    pool.terminate()
                    pool.join()
            return joint if joint.fit.cost < seq.fit.cost else seq
        return self._fit_warm(model, None, cold, max_iter, converge)

    def _fit_warm(self, model: Model, warm: Fitted | None, cold: dict[str, float] | None, max_iter: int,
                  converge: bool = False, restart: bool = False) -> Fitted:
        """Session.fit from its starts (``warm``: the fit of a model with less, or None), no chain. ``restart``:
        once more from the file's values with the new parameters as fitted (_restart_cold; the chain of a
        model's own fit, i.e. `model add` + `compare`, does it; diagnose's candidate fits do not: it would
        cost each of them a second fit, and a candidate is judged on its own fit's held-out error anyway)."""
        pr = self.problem(model)
        params = model.params()
        free = model.free_names()
        bounds = {n: (params[n].lo if params[n].lo is not None else -np.inf,
                      params[n].hi if params[n].hi is not None else np.inf) for n in free}
        starts, nested, new = self._starts(model, dict(pr.builder.base_values), bounds, warm, cold, restart)
        fw, hw = self.win.select(False), self.win.select(True)
        if warm is not None and warm.problem.weights is not None:
            pr.weights = warm.problem.weights.copy()  # the same windows count as in the fit it extends
        res = self._fit_from(pr, starts, free, bounds, fw, max_iter, reweight=warm is None, converge=converge)
        extends = warm is not None and set(warm.model.free_names()) <= set(free)  # (not a model with less)
        if nested is not None and extends and res.cost > warm.fit.cost * (1.0 + 1e-9):
            again = self._fit_from(pr, [nested], free, bounds, fw, max_iter, converge=converge)
            res = again if again.cost < res.cost else res
        if restart and extends and cold and new and res.cost < RESTART_GAIN * warm.fit.cost:
            res = self._restart_cold(pr, res, cold, new, free, bounds, fw, max_iter, converge)
        stalled = self._stalled(res, starts, free, bounds)
        if stalled:
            kick = {}
            for k in stalled:
                lo, hi = bounds[k]
                span = (hi - lo) if np.isfinite(hi - lo) else max(abs(res.values[k]), 1.0)
                kick[k] = float(np.clip(res.values[k] + 0.05 * span, lo, hi))
            again = self._fit_from(pr, [({**res.values, **kick}, res.start_values)], free, bounds, fw, max_iter,
                                   converge=converge)
            if again.cost < res.cost:
                res = again
            res.message += f"; stalled in {', '.join(stalled)}: restarted"
        self._better_starts(pr, res, fw)
        also = warm.held.start_values if warm is not None and warm.problem.slots == pr.slots else None
        held, ms_held = self.held_out(pr, res.values, also=also) if hw.size else (res, {})
        fitted_model = model.with_values({k: res.values[k] for k in free}, res.std)
        ms_fit = pr.window_errors(res.values, fw, res.start_values)
        no_prediction(ms_fit, ms_held)
        return Fitted(fitted_model, res.values, res, held, pr, ms_held, ms_fit)

    def _starts(self, model: Model, file_values: dict[str, float], bounds: dict, warm: Fitted | None,
                cold: dict[str, float] | None, restart: bool) -> tuple[list, tuple | None, set[str]]:
        """_fit_warm's starts (values, start values or None: the data's), each once; the nested start (``warm``'s
        fitted values, the new parameters at the file's) and the new parameters' names."""
        moved = strength_starts(model, file_values)
        second = second_starts(model, moved, bounds)
        starts: list[tuple[dict[str, float], np.ndarray | None]] = []
        if warm is None:  # (with a warm fit the file's values are the ``cold`` start below: the same starts
            starts.append((file_values, None))  # as diagnose's candidate fits, so both paths end alike)
            if moved:
                starts.append(({**file_values, **moved}, None))
            if second:
                starts.append(({**file_values, **moved, **second}, None))
            guess = {k: float(np.clip(v, *bounds[k])) for k, v in self.law_guess.items() if k in bounds}
            if guess:  # the law's levels as the data show them: a contact far from the config's still converges;
                # once with the file's effects, once with every free effect at neutral (the guess is the bare law's
                # level: a seed's stick-time gain of 0.3 put the guessed break-away 10-25 % high and the fit, from
                # there, at 478 um against a 1.6 um floor)
                starts.append(({**file_values, **guess}, None))
                off = {full: neutral for _, full, neutral in free_strengths(model, file_values)}
                if off:
                    starts.append(({**file_values, **off, **guess}, None))
        from_data = self.effect_starts(model, file_values, bounds)
        if from_data and warm is None:
            starts.append(({**file_values, **from_data}, None))
        nested, new = None, set()
        if warm is not None:
            new = self._new_keys(warm.model, model)
            values = dict(file_values)
            values.update({k: v for k, v in warm.values.items() if k in values and k not in new})
            nested = (dict(values), warm.fit.start_values)
            starts.append(nested)
            moved_new = {k: v for k, v in moved.items() if k in new}
            cold_values = ({**values, **{k: v for k, v in cold.items() if k in values and k not in new}}
                           if cold else None)
            ladder = [moved_new]
            if restart and moved_new:  # a model's own fit: the new strengths a decade further too (see LADDER)
                ladder.append({k: float(np.clip(LADDER * v, *bounds[k])) for k, v in moved_new.items()})
            second_new = {k: v for k, v in second.items() if k in new}
            if second_new and moved_new:
                ladder.append({**moved_new, **second_new})
            for strengths in ladder:
                if strengths:
                    starts.append(({**values, **strengths}, warm.fit.start_values))
                if cold_values is not None:
                    starts.append(({**cold_values, **strengths}, None))
            if from_data:  # with the data's own window starts: the warm fit's were fitted to a model without it
                starts.append(({**values, **from_data}, None))
        # the same values twice (a model file that holds the fitted values of the model it extends): keep the
        # start with the warm start values, the later one
        unique: dict[tuple, tuple] = {}
        for values, vel in starts:
            unique[tuple(sorted(values.items()))] = (values, vel)
        return list(unique.values()), nested, new

    @staticmethod
    def _better_starts(pr: Problem, res: ShootingFit, fw: np.ndarray) -> None:
        """A joint LM step can throw one window's start values into a poor local minimum that the global cost
        hides; re-fit every fit window's start values from the data (parameters fixed, as for held-out windows)
        and keep, per window, the better of the two (the loss's sample weights settled there)."""
        again = pr.fit_starts(res.values, fw, max_iter=25)
        res.start_values = pr.better_starts(res.values, fw, res.start_values, again.start_values)
        pr.settle_weights(res.values, fw, res.start_values)

    def effect_starts(self, model: Model, values: dict[str, float], bounds: dict) -> dict[str, float]:
        """Starts read from the data (RigData.effect_guess) for the model's effects whose strength sits at neutral
        (just added), restricted to the free parameters and clipped to their bounds."""
        out: dict[str, float] = {}
        fresh = set(neutral_strengths(model))
        for name, eff in model.effects.items():
            key = strength_key(model.rig, name, eff.form) if name in CATALOG and eff.path is None else None
            if key is None or f"effects.{name}.{key}" not in fresh:
                continue
            v_ref = values.get(f"effects.{name}.v_ref", 0.0)
            cache = (name, eff.form, v_ref)
            if cache not in self._effect_guesses:
                self._effect_guesses[cache] = self.rd.effect_guess(self.m, name, eff.form, v_ref)
            out.update({k: float(np.clip(v, *bounds[k])) for k, v in self._effect_guesses[cache].items() if k in bounds})
        return out

    def held_out(self, pr: Problem, values: dict[str, float], near: np.ndarray | None = None,
                 also: np.ndarray | None = None) -> tuple[ShootingFit, dict[str, np.ndarray]]:
        """A model at fixed ``values`` on the held-out windows: each window's start values fitted (parameters
        fixed; from ``near`` if given, see Problem.fit_starts), then its mean-square errors per
        output: what every held-out score is made of. ``also``: start values a fit of a nearby model ended at on
        these windows (the model it extends); each window's start is fitted from there too and the lower loss
        kept. Why: a start fit can fall into a poor basin in one window and that window then decides the score
        (seen 2026-11-29, the recovery table's pair case at 100 Hz: the mass fitted, one window of 28 at 255 um
        from the data's start, 75 um from the base fit's; its held-out error 61 um, and 40 um once the windows
        were perturbed by 1e-12: the diagnosis took the mass as its first step in one run and not the other).
        The better of two starts per window costs one start fit and two simulations (0.25 s there)."""
        hw = self.win.select(True)
        held = pr.fit_starts(values, hw, max_iter=25, near=near)
        if also is not None and also.shape == held.start_values.shape and hw.size:
            other = pr.fit_starts(values, hw, max_iter=25, near=also)
            held.start_values = pr.better_starts(values, hw, held.start_values, other.start_values)
        return held, pr.window_errors(values, hw, held.start_values)

    def _fit_from(self, pr: Problem, starts: list, free: list[str], bounds: dict, fw: np.ndarray,
                  max_iter: int, reweight: bool = False, converge: bool = False) -> ShootingFit:
        """First on the windows' first halves (less nonlinear: a shifted break-away costs less; cheaper),
        each start PROBE_ITER iterations and only the best goes on, then on the whole windows. With
        ``reweight`` the windows' weights (window_weights) are set from the half-window result and, if
        they changed, once more from the full fit's, which then continues."""
        half = max(MIN_CONTINUATION, self.win.length // 2)
        probe = PROBE_ITER if len(starts) > 1 else max_iter // 2
        ls = robust.SQUARES
        probes, failed = [], []
        for values, vel in starts:  # a start whose fit fails numerically is left out; the others go on (decision 50)
            try:
                probes.append(pr.fit(values, free, bounds, fw, start_values=vel, max_iter=probe, length=half, loss=ls))
            except NumericalFailure as exc:
                failed.append(exc)
        if not probes:
            raise failed[0]
        best = min(probes, key=lambda f: f.cost)
        if probe < max_iter // 2:
            best = pr.fit(best.values, free, bounds, fw, start_values=best.start_values,
                          max_iter=max_iter // 2 - probe, length=half, loss=ls)
        if reweight:
            pr.weights = window_weights(pr.window_costs(best.values, fw, best.start_values), fw, self.win.starts.size)
        res = pr.fit(best.values, free, bounds, fw, start_values=best.start_values, max_iter=max_iter, loss=ls)
        if reweight:
            w = window_weights(pr.window_costs(res.values, fw, res.start_values), fw, self.win.starts.size)
            if np.any(np.abs(np.log(w[fw] / pr.weights[fw])) > math.log(2.0)):
                pr.weights = w
                res = pr.fit(res.values, free, bounds, fw, start_values=res.start_values, max_iter=max_iter // 2,
                             loss=ls)
        if converge and not res.success and CONVERGE_ITER > max_iter:
            more = pr.fit(res.values, free, bounds, fw, start_values=res.start_values, max_iter=CONVERGE_ITER - max_iter,
                          loss=ls)
            more.nfev += res.nfev
            more.message += f" (after {max_iter} iterations: {res.message})"
            res = more if more.cost <= res.cost else res
        if pr.loss != ls:  # the robust loss from where least squares converged (robust.py: why not from the start)
            robust_fit = pr.fit(res.values, free, bounds, fw, start_values=res.start_values, max_iter=max_iter,
                                loss=pr.loss, after=res)  # (least squares' last Jacobian and residuals)
            robust_fit.nfev += res.nfev
            robust_fit.success = robust_fit.success and res.success  # converged only if both stages did
            robust_fit.message = f"{res.message}; then {pr.loss} loss: {robust_fit.message}"
            res = robust_fit
        return res

    def _restart_cold(self, pr: Problem, res: ShootingFit, cold: dict[str, float], new: set[str], free: list[str],
                      bounds: dict, fw: np.ndarray, max_iter: int, converge: bool) -> ShootingFit:
        """An extension's fit once more: the new parameters at the values it found, every other one back at the
        model file's (``cold``); the lower cost wins. Why: a fit of the model without the effect compensates
        for it where it can, and the extension starts in that compromise; beside the new effect at its
        generic start (the other cold start) nothing pulls the others out. Seen on a spring-slider with
        Dieterich aging hidden, stepping 4 <-> 2 mm/s: the base fit put accel-sign at its bound (-0.5) and a
        damping of 1.6 in the place of aging; stick-time from there 33 um (floor 3.5 um), from the file's values
        with the gain and tau it had found, 5.9 um (accel-sign back to 0, damping 0.05)."""
        moved = {k for k in new if k in free and res.values[k] != pr.builder.base_values.get(k)}
        if not moved:
            return res
        values = {**res.values, **{k: v for k, v in cold.items() if k in res.values and k not in new}}
        values = {k: float(np.clip(v, *bounds[k])) if k in bounds else v for k, v in values.items()}
        again = self._fit_from(pr, [(values, None)], free, bounds, fw, max_iter, converge=converge)
        if again.cost < res.cost:
            again.message += "; restarted from the file's values with the new parameters as fitted"
            return again
        return res

    @staticmethod
    def _stalled(res: ShootingFit, starts: list, free: list[str], bounds: dict) -> list[str]:
        """Free parameters still exactly at the value every start gave them, and not at a bound."""
        out = []
        for k in free:
            v = res.values[k]
            if any(v != values.get(k) for values, _ in starts):
                continue
            lo, hi = bounds[k]
            if v <= lo or v >= hi:
                continue
            out.append(k)
        return out

    def restore(self, parts: Portable) -> Fitted:
        """A Fitted from portable()'s parts, on this session's windows."""
        pr = self.problem(parts.given)
        pr.weights, pr.sample_weights = parts.weights, parts.sample_weights
        return Fitted(parts.model, parts.values, parts.fit, parts.held, pr, parts.ms_held, parts.ms_fit)

    def weighted(self, ms: dict[str, np.ndarray], windows: np.ndarray) -> np.ndarray:
        """Per window (``windows``: the session's windows ``ms`` holds, in order): the mean-square error of all
        outputs, each in units of its noise (of its own record, in a MultiSession)."""
        return sum(v / self.m.sigma[k] ** 2 for k, v in ms.items())

    def window_t(self, windows: np.ndarray) -> np.ndarray:
        """Each window's start time [s]."""
        return self.m.t[self.win.starts[windows]]

    def where_view(self, fitted: Fitted) -> tuple[Session, Fitted]:
        """The session and fit where_it_lives reads (a MultiSession: the record that carries most of the error)."""
        return self, fitted

    @staticmethod
    def _new_keys(old: Model, new: Model) -> set[str]:
        """Parameters free in ``new`` that ``old`` does not have, or holds fixed."""
        was_free = set(old.free_names())
        return {k for k in new.free_names() if k not in was_free}

    # ------------------------------------------------------------------ forward simulation and noise floor

    def free_run(self, fitted: Fitted) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """The fitted model simulated over the whole record from the first window's start (no re-starts).

        Returns (sample indices, predicted outputs, states, aux). Phase drifts away from
        the data: compare cycle features (frequency, amplitude, stick fraction), not points.
        """
        pr = fitted.problem
        sim = pr.sim(fitted.values)
        w0 = int(np.argmin(self.win.starts))  # the earliest window (the list need not be in time order)
        s0 = self.rd.start_state(sim, self.m, int(self.win.starts[w0]))
        fitted_w = list(fitted.fit.windows)
        if w0 in fitted_w:
            s0[pr.slots] = fitted.fit.start_values[fitted_w.index(w0)]
        i0 = int(self.win.starts[w0])
        n = self.m.n - i0
        self.rd.before_window(sim, self.m, i0, s0)
        ch = sim.advance(s0, float(pr.rt[i0]), pr.h, pr.n_sub, n, pr.rt, pr.rv)
        return np.arange(i0, self.m.n), self.rd.predict(sim, ch.states), ch.states, ch.aux

    def timing_noise(self, fitted: Fitted) -> float:
        """Clock jitter [s] the fitted model's residual shows on the primary output (signals.timing_noise), 0
        where it shows none: samples taken early or late but stamped on the grid, which no model can undo. Read
        once per fit (the floor and compare's JSON both ask)."""
        if fitted._jitter_s is None:
            pr = fitted.problem
            scored = self.win.scored()
            shot = pr.shoot(fitted.values, scored, fitted.start_values(scored))
            k = self.primary
            rates = self.rd.output_rates(pr.sim(fitted.values), shot.states, float(self.m.t[1] - self.m.t[0]))
            fitted._jitter_s = timing_noise((shot.pred[k] - shot.meas[k])[:, 1:], rates[k][:, 1:])
        return fitted._jitter_s

    def noise_floor(self, fitted: Fitted, seed: int = 12345) -> dict[str, float]:
        """The error a perfect model shows on data like this: the fitted model scored on its own noisy output.

        The fitted model's forward run becomes a synthetic recording with the measured
        noise levels (same drive, temperature and other columns) and the clock jitter its
        residual shows (one error per sample instant, common to every output: a shared ADC
        clock); the same windows procedure then scores the same model on it, start values
        fitted as always. Why the jitter: at 100 Hz, 0.2 ms of it on a block moving with the
        belt at 0.17 m/s is 34 um a sample, seven noise levels; left out of the floor it was
        excess no effect could remove, and the brake's dirty aging record named nothing.
        """
        idx, pred, states, aux = self.free_run(fitted)
        rng = np.random.default_rng(seed)
        ch = {k: np.asarray(v, dtype=float)[idx] for k, v in self.rec.channels.items()}
        for k, x in pred.items():
            ch[k] = x + rng.normal(0.0, self.m.sigma[k], x.size)
        sim = fitted.problem.sim(fitted.values)
        jitter = self.timing_noise(fitted)
        if jitter > 0:
            early = rng.normal(0.0, jitter, idx.size)
            rates = self.rd.output_rates(sim, states, float(self.m.t[1] - self.m.t[0]))
            for k in pred:
                ch[k] = ch[k] + rates[k] * early
        ch.update(self.rd.synthetic_extras(sim, states, aux, ch, rng))
        dc = self.rd.drive_channel
        if fitted.problem.drive == "measured" and dc in ch:
            # a model driven by the measured speed also carries that measurement's error: the synthetic drive
            # channel is the smooth drive the model ran on plus the real one's noise, shifted in time (another
            # realisation, same level, quantisation and hold), so the floor includes what no model can undo
            raw = np.asarray(self.rec.channels[dc], dtype=float)[idx]
            scale = self.m.drive_measured[idx] / np.where(raw != 0, raw, 1.0)
            scale = float(np.median(scale[np.isfinite(scale) & (raw != 0)])) if np.any(raw != 0) else 1.0
            smooth_raw = self.m.drive_measured[idx] / scale  # the drive in the channel's own unit
            noise = raw - smooth_raw
            ch[dc] = smooth_raw + np.roll(noise, int(rng.integers(noise.size // 4, 3 * noise.size // 4 + 1)))
        if "temp" in ch and self.m.temp is not None:
            # the forward run heats the contact by its own thermal model, which a real contact need not follow:
            # the synthetic thermocouple reads the run's temperature (plus the real one's noise, shifted), so
            # its windows start from the temperature their data were made with
            noise = np.asarray(self.rec.channels["temp"], dtype=float)[idx] - self.m.temp[idx]
            ch["temp"] = states[:, sim.n_mech + TAIL.TEMP] + np.roll(noise, int(rng.integers(1, max(noise.size, 2))))
        syn = Recording(self.rec.rig, self.m.t[idx], ch, self.rec.units, {}, {})
        # windows as long as the data's: a model whose own cycles are slower (the lab's slider at 1.1 mm/s: 2 s
        # against 32 ms) was otherwise scored on windows of its own period, 4.6 noise levels for a perfect model
        s = Session(syn, f"{self.source} (synthetic)", self.cfg, max_windows=self.win.starts.size, loss=self.loss,
                    window_s=(self.win.length - 1) / self.m.rate)
        s.m.sigma = dict(self.m.sigma)  # same noise model, not a re-estimate
        pr = s.problem(fitted.model)
        allw = s.win.scored()  # transients left out, as in the scores
        vel = pr.fit_starts(fitted.values, allw, max_iter=25)
        ms = pr.window_errors(fitted.values, allw, vel.start_values)
        # A window whose start-velocity fit ran away (seen once in 90 windows on a 600 s record) is
        # not what a perfect model shows: windows more than 5x the median rms are left out.
        wsum = s.weighted(ms, allw)
        keep = wsum <= 25.0 * np.median(wsum)
        return {k: float(math.sqrt(np.mean(v[keep]))) for k, v in ms.items()}
