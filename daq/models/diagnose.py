"""Which physical effect is the model missing? Score every catalog effect it lacks on held-out data.

Why held-out: an effect with free parameters always fits the fit windows a little
better; only an error that falls on windows the fit never saw is evidence. The
score is the fraction of the *excess* error (above the noise floor) that the
effect removes on the held-out windows, less a small charge per added parameter,
and it must be consistent across windows (Wilcoxon signed-rank, as a z score), not carried by
one lucky window.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from dataclasses import dataclass

import numpy as np
from scipy import stats

from daq.physics.effects import CATALOG

from .session import Fitted, Session
from .shooting import FitResult
from .spec import Model, add_effect

PENALTY_PER_PARAM = 0.02  # reduction an added free parameter must earn
MIN_REDUCTION = 0.5  # a missing effect must remove at least half the excess error...
MIN_T = 2.33  # ...consistently across held-out windows (Wilcoxon z, one-sided p < 0.01)
MIN_EXCESS = 0.10  # and there must be an excess to explain: error > 1.1 x noise floor


@dataclass
class Candidate:
    effect: str
    reduction: float
    score: float
    error: float
    t_stat: float
    params_added: int
    values: dict[str, float]
    std: dict[str, float]
    fitted: Fitted | None = None


def lacking(model: Model) -> list[str]:
    """Catalog effects that apply to the model's rig and are not in it."""
    return [n for n, s in CATALOG.items() if model.rig in s.rigs and n not in model.effects]


def consistency(d: np.ndarray) -> float:
    """How consistently the held-out windows improved: the Wilcoxon signed-rank statistic as a z score.

    Why not a t statistic: per-window improvements are heavy-tailed (a few windows carry
    most of the error), which shrinks t even when every window improves.
    """
    d = d[d != 0]
    if d.size < 3:
        return 0.0
    res = stats.wilcoxon(d, alternative="greater")
    p = min(max(float(res.pvalue), 1e-300), 1.0)
    return float(stats.norm.isf(p))


def score(base: Fitted, cand: Fitted, effect: str, floor: float, session: Session) -> Candidate:
    primary = session.primary
    e0, e1 = base.rms(primary), cand.rms(primary)
    excess = e0 - floor
    reduction = (e0 - e1) / excess if excess > 0 else 0.0
    d = session.weighted(base.ms_held) - session.weighted(cand.ms_held)
    t = consistency(d)
    added = [k for k in cand.model.free_names() if k not in base.model.params()]
    new = {k: v for k, v in cand.values.items() if k.startswith(f"effects.{effect}.")}
    return Candidate(effect, float(reduction), float(reduction - PENALTY_PER_PARAM * len(added)), float(e1), t,
                     len(added), new, {k: v for k, v in cand.fit.std.items() if k in new}, cand)


# --------------------------------------------------------------------------- parallel candidates

_STATE: dict[str, object] = {}


FLOOR = "(noise floor)"  # the pool's one task that is not a candidate


def _fit_candidate(name: str) -> tuple:
    s: Session = _STATE["session"]  # type: ignore[assignment]
    base: Fitted = _STATE["base"]  # type: ignore[assignment]
    model: Model = _STATE["model"]  # type: ignore[assignment]
    if name == FLOOR:
        return name, s.noise_floor(base)
    f = s.fit(add_effect(model, name), warm=base)
    return name, f.values, f.fit.start_values, f.held.start_values, f.fit.std, f.ms_held, f.ms_fit


def fit_candidates(session: Session, model: Model, base: Fitted, names: list[str], workers: int | None = None,
                   on_done=None, floors: dict | None = None) -> dict[str, Fitted]:
    """Refit the model once per candidate effect, from the model file's values and from the base fit.

    ``model`` is the model as written (its values are the cold start, what `model add` + refit
    would use); ``base`` its fit (the warm start). In parallel processes if we can. Given a dict
    ``floors``, the base fit's noise floor is computed too (filled in): in the pool it fills the gap
    an odd number of candidates leaves on two cores.
    """
    workers = workers or min(len(names) + (floors is not None), os.cpu_count() or 1)
    out: dict[str, Fitted] = {}
    if workers > 1 and "fork" in mp.get_all_start_methods():
        _STATE.update(session=session, base=base, model=model)
        tasks = ([FLOOR] if floors is not None else []) + list(names)
        try:
            with mp.get_context("fork").Pool(workers) as pool:
                for name, *rest in pool.imap_unordered(_fit_candidate, tasks):
                    if name == FLOOR:
                        floors.update(rest[0])  # type: ignore[union-attr]
                        continue
                    values, vel, vel_held, std, ms_held, ms_fit = rest
                    cand = add_effect(model, name)
                    free = cand.free_names()
                    fr = FitResult(values, free, std, vel, session.win.select(False), float("nan"), 0, True)
                    hr = FitResult(values, [], {}, vel_held, session.win.select(True), float("nan"), 0, True)
                    out[name] = Fitted(cand.with_values({k: values[k] for k in free}, std), values, fr, hr,
                                       session.problem(cand), ms_held, ms_fit)
                    if on_done:
                        on_done(name)
        finally:
            _STATE.clear()
        return out
    if floors is not None:
        floors.update(session.noise_floor(base))
    for name in names:
        out[name] = session.fit(add_effect(model, name), warm=base)
        if on_done:
            on_done(name)
    return out


# --------------------------------------------------------------------------- correlations


def window_context(session: Session) -> dict[str, np.ndarray]:
    """Per window, the mean of quantities a residual might follow when no catalog effect explains it."""
    m = session.m
    idx = session.win.starts[:, None] + np.arange(session.win.length)[None, :]
    travel = np.concatenate([[0.0], np.cumsum(0.5 * (m.drive_measured[1:] + m.drive_measured[:-1]) / m.rate)])
    q = {"time": m.t, "belt travel": travel, "belt speed": m.drive_measured}
    if m.temp is not None:
        q["temperature"] = m.temp
    for k, x in m.outputs.items():
        q[k] = x
    if m.v_rel is not None:
        q["|v_rel|"] = np.abs(m.v_rel)
    return {k: v[idx].mean(axis=1) for k, v in q.items()}


def correlations(session: Session, base: Fitted) -> list[dict[str, float | str]]:
    """Spearman correlation of each window's error (base model) with measured quantities, strongest first."""
    ms = np.full(session.win.starts.size, np.nan)
    ms[base.fit.windows] = session.weighted(base.ms_fit)
    if base.ms_held:
        ms[session.win.select(True)] = session.weighted(base.ms_held)
    ok = np.isfinite(ms)
    out = []
    for name, x in window_context(session).items():
        if np.ptp(x[ok]) == 0:
            continue
        rho, p = stats.spearmanr(x[ok], ms[ok])
        if np.isfinite(rho):
            out.append({"quantity": name, "spearman_rho": float(rho), "p_value": float(p)})
    out.sort(key=lambda d: -abs(d["spearman_rho"]))
    return out


# --------------------------------------------------------------------------- the whole diagnosis


@dataclass
class Diagnosis:
    base: Fitted
    floor: float  # of the primary signal
    floors: dict[str, float]  # every output's
    candidates: list[Candidate]
    found: bool
    summary: str
    correlations: list[dict]

    def as_json(self, session: Session) -> dict:
        primary = session.primary
        unit = session.m.units[primary]
        best = self.candidates[0] if self.candidates else None
        return {
            "data": session.source,
            "model": self.base.model.describe(),
            "error": self.base.rms(primary),
            "error_unit": unit,
            "error_signal": primary,
            "noise_floor": self.floor,
            "excess": self.base.rms(primary) - self.floor,
            "missing_effect_found": self.found,
            "best": best.effect if (best and self.found) else None,
            "summary": self.summary,
            "candidates": [{"effect": c.effect, "reduction": c.reduction, "score": c.score, "error": c.error,
                            "consistency_z": c.t_stat, "params_added": c.params_added, "values": c.values, "std": c.std}
                           for c in self.candidates],
            "residual_correlations": self.correlations[:8],
            "windows": {"length_s": (session.win.length - 1) / session.m.rate, "fit": int((~session.win.held_out).sum()),
                        "held_out": int(session.win.held_out.sum())},
            "noise": {"sigma": session.m.sigma, "source": session.m.sigma_source},
        }


def diagnose(session: Session, model: Model, progress=None, workers: int | None = None,
             base: Fitted | None = None) -> Diagnosis:
    say = progress or (lambda msg: None)
    names = lacking(model)
    if base is None:
        say(f"fitting the model ({len(model.free_names())} free parameters) on {len(session.win.select(False))} windows")
        base = session.fit(model)
    e0 = base.rms(session.primary)
    say(f"model error {e0:.4g} {session.m.units[session.primary]}; noise floor and {len(names)} effects to try: "
        f"{', '.join(names)}")
    floors: dict[str, float] = {}
    fits = fit_candidates(session, model, base, names, workers, on_done=lambda n: say(f"  refitted with {n}"),
                          floors=floors)
    floor = floors[session.primary]
    say(f"noise floor {floor:.4g} {session.m.units[session.primary]}")
    cands = sorted((score(base, fits[n], n, floor, session) for n in names), key=lambda c: -c.score)
    excess_ratio = (e0 - floor) / floor if floor > 0 else float("inf")
    best = cands[0] if cands else None
    found = bool(best and excess_ratio > MIN_EXCESS and best.reduction >= MIN_REDUCTION and best.t_stat >= MIN_T)
    corr = correlations(session, base)
    unit = session.m.units[session.primary]
    if found:
        vals = ", ".join(f"{k.rsplit('.', 1)[-1]} = {v:.4g}" for k, v in best.values.items())
        summary = (f"The model misses '{best.effect}' ({CATALOG[best.effect].meaning}). Adding it removes "
                   f"{best.reduction:.0%} of the excess error on held-out windows ({e0:.3g} -> {best.error:.3g} {unit}, "
                   f"noise floor {floor:.3g}); fitted {vals or 'no parameters'}.")
        if len(cands) > 1 and cands[1].reduction >= MIN_REDUCTION:
            summary += f" Runner-up: '{cands[1].effect}' ({cands[1].reduction:.0%})."
    elif excess_ratio <= MIN_EXCESS:
        summary = (f"No missing effect: the model's error ({e0:.3g} {unit}) is within {MIN_EXCESS:.0%} of the noise "
                   f"floor ({floor:.3g} {unit}).")
    else:
        strong = [c for c in corr if abs(c["spearman_rho"]) > 0.3 and c["p_value"] < 0.01]
        follows = ", ".join(f"{c['quantity']} (rho {c['spearman_rho']:+.2f})" for c in strong[:4]) or "nothing measured"
        summary = (f"The model's error ({e0:.3g} {unit}) is {excess_ratio:.1f}x above the noise floor, but no catalog "
                   f"effect explains it (best: '{best.effect if best else '-'}', {best.reduction if best else 0:.0%}). "
                   f"The residual follows: {follows}.")
    return Diagnosis(base, floor, floors, cands, found, summary, corr)
