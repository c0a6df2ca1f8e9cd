"""Levenberg-Marquardt on the block structure of multiple shooting: the solver :class:`shooting.Problem` drives.

Laid out as scipy's ``_ivp`` lays out a solver: what a fit is about (an objective: residuals, loss, Jacobian,
bounds; :class:`Joint` for the free parameters and every window's start values, :class:`Starts` for the start
values alone) stays fixed; what it has reached (a state dataclass: iterate, residuals, Jacobian, damping, how it
ended) changes; small functions take one step (normal equations, a trial step, its acceptance) and a loop calls
them until a step says the fit is done. Nothing is read from a loop's locals after it: whatever the end needs
is in the state.

Joint fit: the start values of one window touch only that window's residuals, so the normal equations are solved
through the Schur complement over the free parameters (cost linear in the number of windows). The Jacobian is by
finite differences (one simulation of all windows per free parameter and per start slot); with ``broyden`` it
is carried along accepted steps by per-window Broyden rank-one updates (the update keeps the block structure),
and computed afresh whenever a step fails or convergence is to be declared. A robust loss enters as iteratively
reweighted least squares: each sample's weight at the current iterate (robust.evaluate), a trial accepted only
if the loss itself falls. Start values alone: one Levenberg-Marquardt per window, each with its own damping,
the simulations batched over the windows still iterating. Decision record:
docs/decisions/0002-output-error-by-multiple-shooting.md; the layout: docs/decisions/0041-models-core-as-a-solver.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import linalg, robust

STAGE_SHIFT = 0.1  # a stage from a previous one's end (another loss) stops where its Gauss-Newton step would move
# the parameters by less than this many standard errors (jointly): the refreshes that confirm a small relative
# decrease (1e-4) on a fresh Jacobian cost 2.7 finite-difference Jacobians a stage, 17 % of a diagnosis
# Initial Levenberg-Marquardt damping of a window's own fit (fit_starts). Why high: the start comes
# from the data and is close; a near-Gauss-Newton first step through a break-away can jump to another
# basin that is better than the start but far from the best (seen on one 100 Hz window: 865 um after
# 30 trials from damping 1e-2, 4.7 um from 100). Damping falls 5x per accepted step.
START_DAMPING = 100.0
# The same from a start that is no estimate but a state the model passed through (a predicted record's own
# simulation, design._TruthRecord): where the damping falls from 100 the fits end in the same windows' optima,
# for a quarter less CPU (design._TruthRecord._own_states has the figures).
NEAR_DAMPING = 1.0

# A scaled residual this large (in noise standard deviations) is no prediction: a window the integrator gave up on
# (NaN), or a simulation that diverged. Problem.scaled caps every residual here. Why cap a finite one too: a fixed-step
# simulation that diverges runs to 1e300 before it reaches inf; such a window reached a forward difference as
# (1e300 - r) / 1e-7, overflowed to inf, and made the normal equations NaN ("SVD did not converge", decision 50).
NO_PREDICTION = 1e6


def capped(z: np.ndarray) -> np.ndarray:
    """Scaled residuals with NaN as NO_PREDICTION and every value within +-NO_PREDICTION."""
    return np.clip(np.nan_to_num(z, nan=NO_PREDICTION), -NO_PREDICTION, NO_PREDICTION)

# what a fit simulates: Problem.scaled(values, windows, start values, length) -> (n_win, n_out, n_samples)
Scaled = Callable[[dict, np.ndarray, np.ndarray | None, int | None], np.ndarray]


def bounded_step(S: np.ndarray, rhs: np.ndarray, theta: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The damped Gauss-Newton step S d = rhs with the parameters held at a bound that the step would push past
    it left out (an active set): d = 0 for them, the others solved with them fixed.

    Why not the full step, clipped: it assumes the held parameters move, so it is no descent direction for the
    others when parameters are coupled, and the fit crawls along the bound (seen: Dieterich's Dc at its upper
    bound, 40 iterations of tiny decreases, 63 % of the excess removed; with the active set Dc left the bound
    and 95 % went, tests/test_models.py has the quadratic case)."""
    held = ((theta <= lo) & (rhs < 0)) | ((theta >= hi) & (rhs > 0))
    d = np.zeros_like(theta)
    free = ~held
    if free.any():
        d[free] = linalg.solve(S[np.ix_(free, free)], rhs[free], "the parameters' step")
    return d


def parameter_gain(A: np.ndarray, B: np.ndarray, C: np.ndarray, ga: np.ndarray, gc: np.ndarray) -> float:
    """The part of the undamped Gauss-Newton decrease 0.5 g^T H^-1 g that the free parameters bring, every window's
    start values profiled out (Schur complement): 0.5 d^T Cov^-1 d for the step d, with Cov^-1 = J^T W J."""
    if not ga.size:
        return 0.0
    nv = C.shape[1]
    # a window whose start values the data do not fix (seen: a constant-speed record with a strength held fixed,
    # daq demo --closed-loop): linalg.inverse falls back to the pseudo-inverse, which profiles it
    Ci = linalg.inverse(C + 1e-12 * np.eye(nv)[None], "the start values' blocks (parameter gain)", ridge=False)
    BCi = np.einsum("wij,wjk->wik", B, Ci)
    S = A - np.einsum("wij,wkj->ik", BCi, B)
    rhs = ga - np.einsum("wij,wj->i", BCi, gc)
    return 0.5 * float(rhs @ linalg.lstsq(S, rhs, "the parameters' Schur complement (parameter gain)"))


def no_prediction(z: np.ndarray) -> np.ndarray:
    """Per window (rows of ``z``, residuals flattened after the first axis): has it no prediction (NO_PREDICTION)?"""
    return np.abs(z.reshape(z.shape[0], -1)).max(axis=1, initial=0.0) >= NO_PREDICTION


def difference(resid, r: np.ndarray, step: float, at) -> np.ndarray:
    """A forward difference (resid(at(step)) - r) / step of one column, per window; where the stepped simulation has no
    prediction and the iterate's has one, the backward difference there instead (one simulation more), and where
    that has none either, 0: that window says nothing of this direction. Why: near the edge of a fixed-step
    integrator's stability a step of 1e-4 of a parameter can make a window diverge; a difference across that edge is
    no derivative, and it made the whole fit's normal equations NaN (decision 50)."""
    rp = resid(at(step))
    col = (rp - r) / step
    off = no_prediction(rp) & ~no_prediction(r)
    if off.any():
        rm = resid(at(-step))
        col[off] = ((r - rm) / step)[off]
        col[off & no_prediction(rm)] = 0.0
    return col


def start_jacobian(resid, V: np.ndarray, r: np.ndarray, vscale: np.ndarray) -> np.ndarray:
    """Per window, d(residuals)/d(start values) by forward differences: one simulation per start slot (difference)."""
    j = np.empty(r.shape + (V.shape[1],))
    for q in range(V.shape[1]):
        def at(dv: float, q: int = q) -> np.ndarray:
            vp = V.copy()
            vp[:, q] += dv
            return vp
        j[..., q] = difference(resid, r, 1e-4 * vscale[q], at)
    return j


# ----------------------------------------------------------------------------- free parameters and start values


@dataclass
class Joint:
    """A fit of the free parameters and every window's start values: what stays fixed while it runs."""

    scaled: Scaled
    values: dict[str, float]  # every parameter (the free ones' entries are the iterate's)
    free: list[str]
    windows: np.ndarray
    length: int | None  # samples per window (None: the windows' own)
    n_out: int
    ww: np.ndarray  # each window's weight (window_weights)
    loss_name: str
    lo: np.ndarray
    hi: np.ndarray
    vscale: np.ndarray  # the start values' scale (finite-difference steps)
    broyden: bool
    handed: bool  # the first Jacobian and residuals are a previous stage's (its end under another loss)
    nfev: int = 0  # batched simulations so far

    def at(self, th: np.ndarray) -> dict[str, float]:
        vals = dict(self.values)
        vals.update({n: float(th[i]) for i, n in enumerate(self.free)})
        return vals

    def resid(self, th: np.ndarray, vel: np.ndarray) -> np.ndarray:
        self.nfev += 1
        return self.scaled(self.at(th), self.windows, vel, self.length).reshape(self.windows.size, -1)

    def loss(self, z: np.ndarray) -> tuple[float, np.ndarray]:
        """The loss (windows' weights applied) and each residual's weight in the weighted squares."""
        nw = self.windows.size
        per_window, w = robust.evaluate(z.reshape(nw, self.n_out, -1), self.loss_name)
        return float(np.sum(self.ww * per_window)), self.ww[:, None] * w.reshape(nw, -1)

    def jacobian(self, th: np.ndarray, vel: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """d(residuals)/d(free parameters) and d(residuals)/d(start values), by forward differences."""
        lo, hi = self.lo, self.hi
        jg = np.empty(r.shape + (len(self.free),))
        for i in range(len(self.free)):
            hstep = 1e-4 * max(abs(th[i]), 1e-3 * (hi[i] - lo[i]), 1e-8)
            if th[i] + hstep > hi[i]:
                hstep = -hstep

            def at(h: float, i: int = i) -> np.ndarray:
                tp = th.copy()
                tp[i] += h
                return tp
            jg[..., i] = difference(lambda tp: self.resid(tp, vel), r, hstep, at)
        return jg, start_jacobian(lambda vp: self.resid(th, vp), vel, r, self.vscale)


@dataclass
class JointState:
    """Where a joint fit is: the iterate, its residuals, loss and weights, the Jacobian, the damping; how it ended."""

    theta: np.ndarray
    V: np.ndarray
    R: np.ndarray
    cost: float
    W: np.ndarray
    Jg: np.ndarray
    Jv: np.ndarray
    lam: float = 1e-2
    fresh: bool = True  # the Jacobian is a finite-difference one at the iterate (not carried by Broyden)
    success: bool = False
    message: str = "iteration limit"


@dataclass
class Blocks:
    """The weighted normal equations' blocks: parameters (A), parameters x start values (B, per window), start values
    (C, per window), and the gradients (ga, gc)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    ga: np.ndarray
    gc: np.ndarray


def normal_equations(st: JointState) -> Blocks:
    sw = np.sqrt(st.W)[..., None]
    Jgw, Jvw = st.Jg * sw, st.Jv * sw
    Rw = st.R * sw[..., 0]
    return Blocks(np.einsum("wri,wrj->ij", Jgw, Jgw), np.einsum("wri,wrj->wij", Jgw, Jvw),
                  np.einsum("wri,wrj->wij", Jvw, Jvw), np.einsum("wri,wr->i", Jgw, Rw), np.einsum("wrj,wr->wj", Jvw, Rw))


def trial_step(ob: Joint, st: JointState, b: Blocks) -> tuple[np.ndarray, np.ndarray]:
    """The damped step from the iterate (parameters at a bound held: bounded_step): new parameters and start values."""
    k, nv, lam = len(ob.free), st.V.shape[1], st.lam
    Ad = b.A + lam * np.diag(np.diag(b.A) + 1e-12)
    Cd = b.C + lam * (np.einsum("wii->wi", b.C)[:, :, None] * np.eye(nv)[None] + 1e-12 * np.eye(nv)[None])
    Ci = linalg.inverse(Cd, "the start values' blocks")
    BCi = np.einsum("wij,wjk->wik", b.B, Ci)
    S = Ad - np.einsum("wij,wkj->ik", BCi, b.B) if k else np.zeros((0, 0))
    rhs = -b.ga + np.einsum("wij,wj->i", BCi, b.gc) if k else np.zeros(0)
    dth = bounded_step(S, rhs, st.theta, ob.lo, ob.hi) if k else np.zeros(0)
    dV = -np.einsum("wij,wj->wi", Ci, b.gc + np.einsum("wij,i->wj", b.B, dth))
    return np.clip(st.theta + dth, ob.lo, ob.hi), st.V + dV


def accept(ob: Joint, st: JointState, th_new: np.ndarray, V_new: np.ndarray, R_new: np.ndarray, cost_new: float,
           W_new: np.ndarray) -> float:
    """Move the state to an accepted trial (the Jacobian carried by Broyden); the relative decrease of the loss."""
    rel = (st.cost - cost_new) / max(st.cost, 1e-300)
    if ob.broyden:  # per window: J_w += (dR_w - J_w d_w) d_w^T / |d_w|^2, d_w = (dtheta, dV_w)
        sth, sV = th_new - st.theta, V_new - st.V
        pred = np.einsum("wri,i->wr", st.Jg, sth) + np.einsum("wrj,wj->wr", st.Jv, sV)
        norm2 = float(sth @ sth) + np.einsum("wj,wj->w", sV, sV)
        with np.errstate(over="ignore", invalid="ignore"):  # (a step of 1e-160: the update is skipped, below)
            u = (R_new - st.R - pred) / np.maximum(norm2, 1e-300)[:, None]
            Jg = st.Jg + u[:, :, None] * sth[None, None, :]
            Jv = st.Jv + u[:, :, None] * sV[:, None, :]
        if np.all(np.isfinite(Jg)) and np.all(np.isfinite(Jv)):
            st.Jg, st.Jv = Jg, Jv
    st.theta, st.V, st.R, st.cost, st.W = th_new, V_new, R_new, cost_new, W_new
    st.lam = max(st.lam / 5.0, 1e-7)
    return rel


def try_steps(ob: Joint, st: JointState, b: Blocks) -> tuple[int | None, float]:
    """Trials at rising damping until one lowers the loss (14 on a fresh Jacobian, 2 on a carried one): which trial
    was accepted (None: none) and its relative decrease."""
    for n in range(14 if st.fresh else 2):
        th_new, V_new = trial_step(ob, st, b)
        R_new = ob.resid(th_new, V_new)
        cost_new, W_new = ob.loss(R_new)
        if np.isfinite(cost_new) and cost_new < st.cost:
            return n, accept(ob, st, th_new, V_new, R_new, cost_new, W_new)
        st.lam *= 4.0
    return None, 0.0


def refresh(ob: Joint, st: JointState) -> None:
    """A finite-difference Jacobian at the iterate."""
    st.Jg, st.Jv = ob.jacobian(st.theta, st.V, st.R)
    st.fresh = True


def iterate(ob: Joint, st: JointState) -> bool:
    """One iteration; True when the fit is done (st.success and st.message say how)."""
    b = normal_equations(st)
    if ob.handed and parameter_gain(b.A, b.B, b.C, b.ga, b.gc) <= 0.5 * STAGE_SHIFT**2:
        st.success, st.message = True, f"converged (no parameter would move by {STAGE_SHIFT:g} of its error)"
        return True
    accepted, rel = try_steps(ob, st, b)
    improved = accepted is not None
    small = improved and (rel < 1e-6 or (rel < 1e-4 and accepted == 0))  # small decrease from a full step
    if improved and not small:
        if not ob.broyden:
            st.Jg, st.Jv = ob.jacobian(st.theta, st.V, st.R)
        st.fresh = not ob.broyden
        return False
    if ob.handed and improved:  # a stage from a previous one's end stops on the parameters' gain (above), not on a
        st.fresh = False  # small relative decrease: 1e-4 of a cost of N/2 is a fraction of a standard error (seen:
        return False  # 0.6 of one short of scipy's Huber estimate)
    if not st.fresh:  # a failed or tiny step on a carried Jacobian: judge it on a fresh one
        refresh(ob, st)
        return False
    st.success, st.message = True, ("converged (relative cost decrease < 1e-4)" if improved else "no further decrease")
    return True


def solve(ob: Joint, st: JointState, max_iter: int) -> JointState:
    """Iterate up to ``max_iter`` times; then, unless the Jacobian is fresh (or a handed stage converged on its carried
    one), one at the end for the uncertainties."""
    for _ in range(max_iter):
        if iterate(ob, st):
            break
    if not st.fresh and not (ob.handed and st.success):  # (a handed stage's uncertainties: its carried Jacobian, a
        st.Jg, st.Jv = ob.jacobian(st.theta, st.V, st.R)  # few Broyden steps from a finite-difference one)
    return st


# ----------------------------------------------------------------------------- start values alone, per window


@dataclass
class Starts:
    """A fit of each window's start values with the model fixed: what stays fixed while it runs."""

    scaled: Scaled
    values: dict[str, float]
    windows: np.ndarray
    n_out: int
    ww: np.ndarray  # each window's weight (window_weights)
    loss_name: str
    vscale: np.ndarray
    broyden: bool = False  # carry each window's Jacobian by rank-one updates (StartsState.fresh says where it is)
    nfev: int = 0

    def resid(self, vel: np.ndarray, rows: np.ndarray) -> np.ndarray:
        self.nfev += 1
        return self.scaled(self.values, self.windows[rows], vel, None).reshape(rows.size, -1)

    def loss(self, z: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per window (``rows``), the loss (its weight applied), and each residual's weight in the weighted squares."""
        per_window, w = robust.evaluate(z.reshape(rows.size, self.n_out, -1), self.loss_name)
        return self.ww[rows] * per_window, self.ww[rows, None] * w.reshape(rows.size, -1)

    def jac(self, vel: np.ndarray, rows: np.ndarray, r: np.ndarray) -> np.ndarray:
        return start_jacobian(lambda vp: self.resid(vp, rows), vel, r, self.vscale)


@dataclass
class StartsState:
    """Where each window's fit is: start values, residuals, loss, weights, Jacobian, damping, failed trials in a
    row, and whether it still iterates. ``enough``: a predicted decrease below it (and below 1e-6 of the loss) ends
    a window."""

    V: np.ndarray
    R: np.ndarray
    cost: np.ndarray
    W: np.ndarray
    J: np.ndarray
    lam: np.ndarray
    enough: float
    active: np.ndarray
    fails: np.ndarray
    fresh: np.ndarray | None = None  # per window: J is a finite-difference one at V (None: every window's is)

    def __post_init__(self) -> None:
        if self.fresh is None:
            self.fresh = np.ones(self.V.shape[0], bool)

    @property
    def success(self) -> bool:
        return not self.active.any()


def refresh_rows(ob: Starts, st: StartsState, rows: np.ndarray) -> None:
    """Finite-difference Jacobians at the windows ``rows`` (one batched simulation per start slot)."""
    if rows.size:
        st.J[rows] = ob.jac(st.V[rows], rows, st.R[rows])
        st.fresh[rows] = True


def converged_rows(st: StartsState, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mark the windows (of ``rows``) where even the undamped (Gauss-Newton) step promises next to nothing as done (a
    small actual decrease is no test while the damping is still high); the others, with their blocks C, g, diag C."""
    nv = st.V.shape[1]
    sw = np.sqrt(st.W[rows])
    Jr, Rr = st.J[rows] * sw[..., None], st.R[rows] * sw
    C = np.einsum("wri,wrj->wij", Jr, Jr)
    g = np.einsum("wri,wr->wi", Jr, Rr)
    D = np.einsum("wii->wi", C) + 1e-12
    gn = 0.5 * np.einsum("wi,wi->w", g, linalg.solve(C + 1e-9 * D[:, :, None] * np.eye(nv)[None], g[..., None],
                                                       "a window's start values (convergence test)")[..., 0])
    conv = gn <= np.maximum(1e-6 * st.cost[rows], st.enough)
    carried = conv & ~st.fresh[rows]  # judged on a carried Jacobian: judged again on a fresh one next time round
    st.active[rows[conv & ~carried]] = False
    keep = ~conv
    return rows[keep], C[keep], g[keep], D[keep], rows[carried]


def starts_trial(ob: Starts, st: StartsState, rows: np.ndarray, C: np.ndarray, g: np.ndarray, D: np.ndarray) -> np.ndarray:
    """One damped trial per window of ``rows`` (one batched simulation); accepted where its loss falls; a window
    ends on a tiny decrease, 12 failures in a row or a damping past 1e10, each judged on a fresh Jacobian. The
    windows that go on get a fresh Jacobian, or with ``ob.broyden`` a Broyden update after an accepted step; a
    failure on a carried one is no failure yet. Returns the windows that need a fresh Jacobian now."""
    nv = st.V.shape[1]
    Cd = C + st.lam[rows, None, None] * (D[:, :, None] * np.eye(nv)[None])
    dV = -linalg.solve(Cd, g[..., None], "a window's start values")[..., 0]
    Vt = st.V[rows] + dV
    Rt = ob.resid(Vt, rows)
    ct, Wt = ob.loss(Rt, rows)
    ok = np.isfinite(ct) & (ct < st.cost[rows])
    rel = np.where(ok, (st.cost[rows] - ct) / np.maximum(st.cost[rows], 1e-300), 0.0)
    fresh = st.fresh[rows].copy()
    acc = rows[ok]
    if ob.broyden and acc.size:  # per window: J += (dR - J dV) dV^T / |dV|^2
        d = dV[ok]
        with np.errstate(over="ignore", invalid="ignore"):  # (a window whose update is not finite keeps its Jacobian)
            u = (Rt[ok] - st.R[acc] - np.einsum("wrj,wj->wr", st.J[acc], d)) / np.maximum(
                np.einsum("wj,wj->w", d, d), 1e-300)[:, None]
            Jn = st.J[acc] + u[:, :, None] * d[:, None, :]
        fin = np.all(np.isfinite(Jn.reshape(acc.size, -1)), axis=1)
        st.J[acc[fin]] = Jn[fin]
        st.fresh[acc] = False
    st.V[acc], st.R[acc], st.cost[acc], st.W[acc] = Vt[ok], Rt[ok], ct[ok], Wt[ok]
    st.lam[acc] = np.maximum(st.lam[acc] / 5.0, 1e-7)
    st.lam[rows[~ok]] *= 4.0
    st.fails[acc] = 0
    st.fails[rows[~ok & fresh]] += 1
    done = ok & (rel < 1e-9) & fresh
    done |= ~ok & fresh & ((st.fails[rows] >= 12) | (st.lam[rows] > 1e10))
    st.active[rows[done]] = False
    if ob.broyden:
        return rows[~done & ((~ok & ~fresh) | (ok & (rel < 1e-9)))]
    return rows[ok & ~done]


def solve_starts(ob: Starts, st: StartsState, max_iter: int) -> StartsState:
    """Every window's fit until each has ended, or ``3 max_iter`` trials (a failed trial costs one simulation, a
    success 1 + the start values' count)."""
    for _ in range(max_iter * 3):
        rows = np.flatnonzero(st.active)
        again = np.zeros(0, int)
        if rows.size:
            rows, C, g, D, again = converged_rows(st, rows)
        if not rows.size and not again.size:
            break
        if rows.size:
            again = np.concatenate([again, starts_trial(ob, st, rows, C, g, D)])
        refresh_rows(ob, st, again)
    refresh_rows(ob, st, np.flatnonzero(~st.fresh))  # (the next stage starts from this Jacobian)
    return st
