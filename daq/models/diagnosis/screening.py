"""Which candidates are worth a full fit: the score test of each, from one linearisation of the current fit.

Why: a full refit costs hundreds of window simulations, and a diagnosis has many candidates (every
catalog effect in every form, the mechanics parameters, their pairs) in every step of a forward
selection. At the current fit the residual r is (to first order) orthogonal to the Jacobian of the
fitted parameters and of every window's start values; a candidate adds a column c = dr/d(strength)
at its neutral point (one simulation of the fit windows), and the largest decrease of the cost
0.5 |r|^2 that the linearised extended model can reach is 0.5 b^T S^-1 b over the extended columns,
with the per-window start values eliminated by their Schur complement (as in the fit itself). A pair
is two columns: screening pairs is as cheap as screening singles. The prediction is first order:
it ranks; only full fits scored on held-out windows decide.

Decision record: docs/decisions/0015-diagnosis-forward-selection.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..candidates import Candidate
from ..fit.lm import start_jacobian
from ..fit.session import Fitted, Session

MIN_STEP = 1e-3  # finite-difference step of a strength, relative to its range (or value, for mechanics)


@dataclass
class Linearisation:
    """A fitted model on its fit windows: residuals and the Jacobian of its free parameters and start values."""

    r: np.ndarray  # (n_win, n_res) noise-scaled residuals
    jg: np.ndarray  # (n_win, n_res, k) d r / d free parameters
    jv: np.ndarray  # (n_win, n_res, n_start) d r / d start values (per window)
    cost: float

    @property
    def n_residuals(self) -> int:
        return int(self.r.size)


def linearise(fitted: Fitted) -> Linearisation:
    """Residuals and Jacobian at the fit (k + n_start + 1 simulations of the fit windows)."""
    pr = fitted.problem
    fw = fitted.fit.windows
    V = fitted.fit.start_values
    values = dict(fitted.values)
    free = fitted.model.free_names()
    params = fitted.model.params()

    def resid(vals: dict[str, float], vel: np.ndarray) -> np.ndarray:
        return pr.residuals(vals, fw, vel).reshape(fw.size, -1)

    r = resid(values, V)
    jg = np.empty(r.shape + (len(free),))
    for i, name in enumerate(free):
        lo = params[name].lo if params[name].lo is not None else -np.inf
        hi = params[name].hi if params[name].hi is not None else np.inf
        span = hi - lo if np.isfinite(hi - lo) else 1.0
        h = 1e-4 * max(abs(values[name]), 1e-3 * span, 1e-8)
        if values[name] + h > hi:
            h = -h
        jg[..., i] = (resid({**values, name: values[name] + h}, V) - r) / h
    vscale = np.maximum(np.abs(V).mean(axis=0), 1e-3)
    jv = start_jacobian(lambda vp: resid(values, vp), V, r, vscale)
    return Linearisation(r, jg, jv, 0.5 * float(np.sum(r * r)))


@dataclass
class Column:
    """One candidate's column at the current fit, and which way its strength may move from neutral."""

    candidate: Candidate
    c: np.ndarray  # (n_win, n_res)
    sign: int  # +1: only increases allowed (at the lower bound), -1: only decreases, 0: either
    switch: bool = False  # a structural switch: c is r(on) - r(off), not a derivative


def column(session: Session, current: Fitted, cand: Candidate, lin: Linearisation | None = None) -> Column:
    """d r / d strength of a candidate at its neutral point (a structural switch: r(on) - r(off)).

    At neutral the extended model is the current one: its residuals are ``lin.r`` (one simulation saved)."""
    model = cand.apply(current.model)
    pr = session.problem(model)
    pr.weights = current.problem.weights  # the same windows count as in the fit
    pr.sample_weights = current.problem.sample_weights  # ... and the same samples (the fit's robust loss)
    fw = current.fit.windows
    values = dict(pr.builder.base_values)
    values.update({k: v for k, v in current.values.items() if k in values})
    V = current.fit.start_values
    key = cand.strength(model)
    if key is None or not model.params()[key].free:
        # a structural switch, the column r(on) - r(off): no parameter (belt-speed driven by the measured speed), or
        # one added at a fixed value (normal-load: the load is followed, or it is not; spec.FIXED). Read as a
        # derivative, normal-load's secant from off to 0.8 ranked it 4th-5th of the phenomena on 4 of 10 noise seeds
        # (brake, 100 Hz, seed model without it): never fitted, and a spring and a mass named in its place
        r_off = lin.r if lin is not None else current.problem.residuals(current.values, fw, V).reshape(fw.size, -1)
        return Column(cand, pr.residuals(values, fw, V).reshape(fw.size, -1) - r_off, +1, switch=True)
    p = model.params()[key]
    lo = p.lo if p.lo is not None else -np.inf
    hi = p.hi if p.hi is not None else np.inf
    v0 = values[key]
    span = (hi - lo) if np.isfinite(hi - lo) else max(abs(v0), 1.0)
    h = MIN_STEP * (abs(v0) if cand.kind == "mechanics" else span)
    sign = +1 if v0 <= lo else (-1 if v0 >= hi else 0)
    step = h if sign >= 0 else -h
    r0 = lin.r if lin is not None else pr.residuals(values, fw, V).reshape(fw.size, -1)
    r1 = pr.residuals({**values, key: v0 + step}, fw, V).reshape(fw.size, -1)
    return Column(cand, (r1 - r0) / step, sign)


def _reach(lin: Linearisation, cols: list[np.ndarray], r: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """0.5 b^T S^-1 b for the fitted parameters plus ``cols``, start values eliminated; and the step.
    ``r``: other residuals than the fit's (a switched model's), the Jacobian kept."""
    g = np.concatenate([lin.jg] + [c[..., None] for c in cols], axis=2) if cols else lin.jg
    jv = lin.jv
    r = lin.r if r is None else r
    nv = jv.shape[2]
    cinv = np.linalg.inv(np.einsum("wri,wrj->wij", jv, jv) + 1e-12 * np.eye(nv)[None])
    jvg = np.einsum("wri,wrj->wij", jv, g)  # (w, nv, m)
    jvr = np.einsum("wri,wr->wi", jv, r)
    s = np.einsum("wri,wrj->ij", g, g) - np.einsum("wki,wkl,wlj->ij", jvg, cinv, jvg)
    b = np.einsum("wri,wr->i", g, r) - np.einsum("wki,wkl,wl->i", jvg, cinv, jvr)
    s += 1e-12 * np.eye(s.shape[0]) * max(float(np.trace(s)), 1e-300) / max(s.shape[0], 1)
    step = -np.linalg.solve(s, b) if s.size else np.zeros(0)
    return 0.5 * float(b @ -step) if s.size else 0.0, step


def predicted_gain(lin: Linearisation, cols: list[Column]) -> float:
    """How much the cost can fall by adding these columns (first order; a column whose best move breaks its
    bound is left out, as the bound would hold it at neutral).

    A structural switch (e.g. driving the model by the measured belt speed) is no derivative: its residuals
    are taken as they are, r(on), and the fitted parameters' best linear correction from there is added
    (the score test alone, on r(on) - r(off) as a column, under-rated it 20x on a rig whose regulator lags)."""
    switches = [c for c in cols if c.switch]
    if switches:
        r_on = lin.r + sum(c.c for c in switches)
        rest = [c for c in cols if not c.switch]
        after = 0.5 * float(np.sum(r_on * r_on)) - _reach(lin, [], r_on)[0] - (_gain_with(lin, rest, r_on)
                                                                                 if rest else 0.0)
        return max(lin.cost - after, 0.0)
    return _gain_with(lin, cols)


def gain_past_bound(lin: Linearisation, col: Column) -> float:
    """What a one-sided column (a strength at its bound) would predict if its step were allowed to cross the bound:
    0 for a two-sided column or a switch, and for one whose step already points inward (predicted_gain has it).

    Why it is asked: the fit it linearises may stand where other parameters make up for the missing effect, and
    there the first-order step of the effect can point out of its range while a full fit, moving those parameters
    back, takes it inward (the aging slider's two records, 4 and 16 mm/s: see selection.past_bound)."""
    if col.switch or not col.sign:
        return 0.0
    base, _ = _reach(lin, [])
    gain, step = _reach(lin, [col.c])
    return max(gain - base, 0.0) if np.sign(step[-1]) == -col.sign else 0.0


def _gain_with(lin: Linearisation, cols: list[Column], r: np.ndarray | None = None) -> float:
    """The decrease the columns add to the fitted parameters' own best linear correction of ``r``."""
    base, _ = _reach(lin, [], r)
    use = list(cols)
    while use:
        gain, step = _reach(lin, [c.c for c in use], r)
        k = lin.jg.shape[2]
        bad = [i for i, c in enumerate(use) if c.sign and np.sign(step[k + i]) == -c.sign]
        if not bad:
            return max(gain - base, 0.0)
        use = [c for i, c in enumerate(use) if i not in bad]
    return 0.0
