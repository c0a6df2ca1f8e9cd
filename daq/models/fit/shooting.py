"""Output-error fitting by multiple shooting: simulate the model over short windows of the data.

Why this and not inverse dynamics: friction from twice-differentiated noisy
positions is biased exactly at stick-slip transitions. Here the model is
integrated from each window's start and compared with the *measured* signals,
so transitions are judged by what the model predicts, not by a derivative.
Windows are short (about one stick-slip cycle and a half) so phase drift cannot
build up; each window's initial velocities are free (they are not measured; at
slow sampling the start positions too, see RigData.start_slots: the "start
values"), and the model's free parameters are shared by all windows. Our own
Levenberg-Marquardt (lm.py, driven by :meth:`Problem.fit` and :meth:`Problem.fit_starts`) solves the normal
equations through the Schur complement over the per-window start values, so one Jacobian costs (free parameters
+ start values per window) batched simulations however many windows there are, and Broyden updates carry it
between refreshes. The windows are cut in windows.py. Here: the Problem (a model, a record, its windows), its
simulations and residuals, and the fits' entry points. Decision records:
docs/decisions/0002-output-error-by-multiple-shooting.md, docs/decisions/0041-models-core-as-a-solver.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from daq.physics.contact import N_AUX

from . import lm, robust
from .build import Builder
from .data import Measured, RigData
from .lm import STAGE_SHIFT
from .windows import Windows

BROYDEN = True  # carry the Jacobian by rank-one updates between finite-difference refreshes (see Problem.fit)
# the same in each window's own start fit (fit_starts): off. On brake 100 Hz diagnoses it saved 10-30 % with the same
# conclusions, but `daq bench diagnose` (1 kHz, 600 s, hidden stick-time) removed 90 % of the excess with it against
# 98 % without: some windows' start fits end in another basin. Off until that is understood (decision 2), except
# from ``near`` (fit_starts): there the start is a state the model itself passed through (a proposal's predicted
# record, design._TruthRecord), which the window's optimum is next to. Measured 2026-11-28 (`daq propose`, the two
# cases of tests/test_propose_loop.py): 49.0 -> 44.0 CPU-s (null) and 52.1 -> 35.4 (tie); the same proposal, the same
# decided rivals and conclusions after the run; of 84 programmes' worst-pair z, 83 the same to 1e-4 and one
# 2.30 -> 2.38 (a programme that was not the best), separations within 1 % but two (8 % and 0.00 -> 0.04).
BROYDEN_STARTS = False




@dataclass
class ShootingFit:
    values: dict[str, float]  # all parameter values (fixed ones included)
    free: list[str]
    std: dict[str, float]
    start_values: np.ndarray  # (n_windows_fitted, n_start)
    windows: np.ndarray  # window indices fitted
    cost: float
    nfev: int
    success: bool
    message: str = ""
    # d(scaled residuals)/d(free parameters, start values) at the end, by finite differences, and the scaled
    # residuals there (n_win, n_res): what a next stage from here under another loss starts with
    jac: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    z: np.ndarray | None = field(default=None, repr=False)


@dataclass
class Shot:
    """Simulated windows: predictions and the measured values they are compared with."""

    windows: np.ndarray  # window indices
    pred: dict[str, np.ndarray]  # (n_win, L)
    meas: dict[str, np.ndarray]
    states: np.ndarray  # (n_win, L, n_state)
    aux: np.ndarray  # (n_win, L, N_AUX)
    index: np.ndarray  # (n_win, L) sample indices


@dataclass
class Problem:
    """A model, a recording and its windows: residuals, fits, predictions."""

    builder: Builder
    rd: RigData
    m: Measured
    win: Windows
    drive: str = "command"  # or "measured"
    weights: np.ndarray | None = None  # per window (all windows): its cost's weight in a fit (see window_weights)
    loss: str = robust.HUBER  # of every fit (robust.py)
    # (all windows, outputs, samples): each sample's weight in the weighted squares that stand for the loss at the
    # last fit of its window (robust.evaluate); what residuals() hands to the linearisation of a fit (screening)
    sample_weights: np.ndarray | None = None
    _cache: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        rate = self.m.rate
        self.n_sub = max(1, int(math.ceil((1.0 / rate) / self.rd.model_step() - 1e-9)))
        self.h = 1.0 / rate / self.n_sub
        v = self.m.drive_measured if self.drive == "measured" else self.m.drive_command
        self.rt = np.ascontiguousarray(self.m.t - self.m.t[0])
        self.rv = np.ascontiguousarray(v, dtype=float)
        self.outputs = list(self.m.outputs)
        self.idx = self.win.starts[:, None] + np.arange(self.win.length)[None, :]
        self.meas = {k: x[self.idx] for k, x in self.m.outputs.items()}
        self.slots = list(self.rd.start_slots(rate))
        self.n_start = len(self.slots)
        # with free start positions the start sample is a measurement like the others (it anchors them)
        self.r0 = 0 if len(self.slots) > len(self.rd.velocity_slots) else 1

    # ------------------------------------------------------------------ simulation

    def sim(self, values: dict[str, float]):
        key = tuple(sorted(values.items()))
        if self._cache.get("key") != key:
            self._cache = {"key": key, "sim": self.builder.sim(values)}
        return self._cache["sim"]

    def start_states(self, sim, windows: np.ndarray) -> np.ndarray:
        return np.array([self.rd.start_state(sim, self.m, int(self.win.starts[w])) for w in windows])

    def default_starts(self, windows: np.ndarray) -> np.ndarray:
        sim = self.sim(self.builder.base_values)
        s0 = self.start_states(sim, windows)
        return s0[:, self.slots].copy()

    def shoot(self, values: dict[str, float], windows: np.ndarray, start_values: np.ndarray | None = None,
              length: int | None = None) -> Shot:
        sim = self.sim(values)
        s0 = self.start_states(sim, windows)
        if start_values is not None:
            s0[:, self.slots] = start_values
        L = length or self.win.length
        states = np.empty((windows.size, L, s0.shape[1]))
        aux = np.full((windows.size, L, N_AUX), np.nan)
        for j, w in enumerate(windows):
            t0 = float(self.rt[self.win.starts[w]])
            self.rd.before_window(sim, self.m, int(self.win.starts[w]), s0[j])
            try:
                ch = sim.advance(s0[j], t0, self.h, self.n_sub, L, self.rt, self.rv)
            except RuntimeError:  # the hybrid integrator gives up (a chattering contact): this window has no
                states[j] = np.nan  # prediction, so its residuals are huge and a fit step that got here is refused
                continue
            states[j] = ch.states
            aux[j] = ch.aux
        pred = self.rd.predict(sim, states)
        meas = {k: v[windows, :L] for k, v in self.meas.items()}
        return Shot(windows, pred, meas, states, aux, self.idx[windows, :L])

    def scaled(self, values: dict[str, float], windows: np.ndarray, start_values: np.ndarray | None,
               length: int | None = None) -> np.ndarray:
        """(pred - meas)/sigma per window, output and sample (from the start sample when positions are free), no
        weights: (n_win, n_out, L - r0); a window the integrator gave up on is lm.NO_PREDICTION everywhere, and no
        residual is larger than that (lm.NO_PREDICTION says why)."""
        shot = self.shoot(values, windows, start_values, length)
        z = np.stack([(shot.pred[k][:, self.r0:] - shot.meas[k][:, self.r0:]) / self.m.sigma[k]
                      for k in self.outputs], axis=1)
        return lm.capped(z)

    def residuals(self, values: dict[str, float], windows: np.ndarray, start_values: np.ndarray | None,
                  length: int | None = None) -> np.ndarray:
        """The scaled residuals as the last fit of their windows weighted them (windows' weights, and the loss's
        sample weights), flattened: a linearisation at that fit sees the fit's own local least-squares problem."""
        z = self.scaled(values, windows, start_values, length)
        if self.sample_weights is not None:
            z = z * np.sqrt(self.sample_weights[windows][:, :, self.r0:self.r0 + z.shape[2]])
        r = z.reshape(windows.size, -1)  # (n_win, n_out*(L-r0))
        if self.weights is not None:
            r = r * np.sqrt(self.weights[windows])[:, None]
        return r.ravel()

    def window_costs(self, values: dict[str, float], windows: np.ndarray, start_values: np.ndarray) -> np.ndarray:
        """The loss per window, without the windows' weights."""
        return robust.evaluate(self.scaled(values, windows, start_values), self.loss)[0]

    def better_starts(self, values: dict[str, float], windows: np.ndarray, kept: np.ndarray,
                      other: np.ndarray) -> np.ndarray:
        """Per window, ``other``'s start values where their loss is strictly lower than ``kept``'s, else ``kept``'s:
        two start fits of the same windows, the better of each window kept (Session._better_starts, Session.held_out
        say why each fits twice)."""
        better = self.window_costs(values, windows, other) < self.window_costs(values, windows, kept)
        return np.where(better[:, None], other, kept)

    def settle_weights(self, values: dict[str, float], windows: np.ndarray, start_values: np.ndarray) -> None:
        """The loss's sample weights of ``windows`` at these values (after a fit's start values were exchanged)."""
        z = self.scaled(values, windows, start_values)
        self._keep_weights(windows, robust.evaluate(z, self.loss)[1])

    def _keep_weights(self, windows: np.ndarray, w: np.ndarray) -> None:
        """Store the loss's sample weights of whole ``windows`` (n_win, n_out, L - r0) for residuals()."""
        sw = (np.ones((self.win.starts.size, len(self.outputs), self.win.length)) if self.sample_weights is None
              else self.sample_weights.copy())  # (another problem may hold the same array: no writes into it)
        sw[windows, :, self.r0:] = w
        self.sample_weights = sw

    # ------------------------------------------------------------------ fitting

    def fit(self, values: dict[str, float], free: list[str], bounds: dict[str, tuple[float, float]],
            windows: np.ndarray, start_values: np.ndarray | None = None, max_iter: int = 25,
            length: int | None = None, loss: str | None = None,
            after: ShootingFit | None = None) -> ShootingFit:
        """The loss (``loss``, default the problem's: robust.py) over the free parameters and every window's start
        values. ``after``: a previous stage that ended at exactly these values and start values; its Jacobian and
        residuals are this stage's first (no simulation), and where its point already satisfies this loss (the
        Gauss-Newton step would move the parameters by less than STAGE_SHIFT standard errors) the stage ends there.

        Levenberg-Marquardt on the block structure of multiple shooting (lm.solve over an lm.Joint objective; lm.py
        says how): the Jacobian by finite differences, carried by per-window Broyden updates with ``BROYDEN``.
        Simulations are the whole cost: this cuts them per iteration from k + n_start + 1 to about 1. The reported
        uncertainties come from a finite-difference Jacobian (a stage handed one by a previous stage that converged:
        that one, carried by Broyden over the stage's few steps). A robust loss enters as iteratively reweighted
        least squares, the Jacobian carried for the unweighted residuals (the weights change from one iterate to
        the next).
        """
        values = dict(values)
        nw, nv = windows.size, self.n_start
        lo = np.array([bounds[n][0] for n in free], dtype=float)
        hi = np.array([bounds[n][1] for n in free], dtype=float)
        V = (self.default_starts(windows) if start_values is None else np.array(start_values, dtype=float))
        ww = self.weights[windows] if self.weights is not None else np.ones(nw)
        handed = (after is not None and after.jac is not None and after.z is not None
                  and after.jac[0].shape == after.z.shape + (len(free),) and after.jac[1].shape == after.z.shape + (nv,))
        ob = lm.Joint(self.scaled, values, list(free), windows, length, len(self.outputs), ww, loss or self.loss, lo, hi,
                      np.maximum(np.abs(V).mean(axis=0), 1e-3), BROYDEN, handed)
        theta = np.clip(np.array([values[n] for n in free], dtype=float), lo, hi)
        R = after.z if handed else ob.resid(theta, V)
        cost, W = ob.loss(R)
        keeps_weights = length is None or length == self.win.length  # (a shorter fit's weights are not the windows')
        if handed and not robust.contaminated(R.reshape(nw, len(self.outputs), -1), ob.loss_name):
            if keeps_weights:
                self._keep_weights(windows, (W / ww[:, None]).reshape(nw, len(self.outputs), -1))
            return ShootingFit(ob.at(theta), list(free), dict(after.std), V.copy(), windows, cost, 0, True,
                               "no more samples beyond the threshold than noise puts there: least squares' end",
                               jac=after.jac, z=R)
        Jg, Jv = after.jac if handed else ob.jacobian(theta, V, R)
        st = lm.solve(ob, lm.JointState(theta, V, R, cost, W, Jg, Jv), max_iter)
        if keeps_weights:
            self._keep_weights(windows, (st.W / ww[:, None]).reshape(nw, len(self.outputs), -1))
        return ShootingFit(ob.at(st.theta), list(free), self._joint_stds(ob, st), st.V.copy(), windows, st.cost,
                           ob.nfev, st.success, st.message, jac=(st.Jg, st.Jv), z=st.R)

    def _joint_stds(self, ob: lm.Joint, st: lm.JointState) -> dict[str, float]:
        """A joint fit's 1-sigma of its free parameters, from its end's Jacobian and weights."""
        k, nw = len(ob.free), ob.windows.size
        sw = np.sqrt(st.W)[..., None]
        return self._stds(st.Jg * sw if k else None, st.Jv * sw, 0.5 * float(np.sum(st.W * st.R * st.R)), st.R.size,
                          k, self.n_start, nw, ob.free)

    @staticmethod
    def _stds(Jg, Jv, cost: float, m: int, k: int, nv: int, nw: int, free: list[str]) -> dict[str, float]:
        """1-sigma of the free parameters: inverse Schur complement of J^T J over the nuisance start values."""
        if k == 0 or Jg is None:
            return {}
        A = np.einsum("wri,wrj->ij", Jg, Jg)
        B = np.einsum("wri,wrj->wij", Jg, Jv)
        C = np.einsum("wri,wrj->wij", Jv, Jv) + 1e-12 * np.eye(nv)[None]
        S = A - np.einsum("wij,wjk,wlk->il", B, np.linalg.inv(C), B)
        s2 = 2.0 * cost / max(m - k - nw * nv, 1)
        if not np.all(np.isfinite(S)):
            return {n: float("nan") for n in free}
        try:
            cov = np.linalg.pinv(S) * s2
        except np.linalg.LinAlgError:  # an ill-conditioned fit: it is a fit, its uncertainties are unknown
            return {n: float("nan") for n in free}
        return {n: float(math.sqrt(max(cov[i, i], 0.0))) for i, n in enumerate(free)}

    def fit_starts(self, values: dict[str, float], windows: np.ndarray, max_iter: int = 10,
                   near: np.ndarray | None = None) -> ShootingFit:
        """Only the start unknowns (the model fixed): how well can this model follow these windows.

        Why a Levenberg-Marquardt per window and not one over all of them: with the model fixed the
        windows are independent, and a shared damping and a shared accept/reject let one window
        that needs small steps (near a break-away) stall while the summed cost still falls. Each
        window here keeps its own damping and stops on its own; the simulations stay batched
        (one call per trial over the windows still iterating). Least squares first, then the problem's loss from
        there, as Session fits the parameters (robust.py says why). From the data's estimate with lm.START_DAMPING,
        or from ``near`` (n_win, n_start: states the model itself passed through) with lm.NEAR_DAMPING.
        """
        if near is None:
            first = self._fit_starts(values, windows, self.default_starts(windows), robust.SQUARES, max_iter)
        else:
            first = self._fit_starts(values, windows, near, robust.SQUARES, max_iter, near=True)
        if self.loss == robust.SQUARES:
            return first
        res = self._fit_starts(values, windows, first.start_values, self.loss, max_iter, after=first)
        res.nfev += first.nfev
        return res

    def _fit_starts(self, values: dict[str, float], windows: np.ndarray, V: np.ndarray, loss_name: str,
                    max_iter: int, after: ShootingFit | None = None, near: bool = False) -> ShootingFit:
        """fit_starts' Levenberg-Marquardt per window from start values ``V`` under one loss (``after``: a previous
        stage that ended there: its Jacobian and residuals are this one's first; ``near``: V are states the model
        passed through: lm.NEAR_DAMPING and Broyden, see BROYDEN_STARTS)."""
        nw, nv = windows.size, self.n_start
        V = np.array(V, dtype=float)
        ww = self.weights[windows] if self.weights is not None else np.ones(nw)
        ob = lm.Starts(self.scaled, values, windows, len(self.outputs), ww, loss_name,
                       np.maximum(np.abs(V).mean(axis=0), 1e-3) if nw else np.ones(nv), BROYDEN_STARTS or near)
        allr = np.arange(nw)
        handed = (nw > 0 and after is not None and after.z is not None and after.z.shape[0] == nw
                  and after.jac is not None)
        R = after.z.copy() if handed else (ob.resid(V, allr) if nw else np.zeros((0, 0)))
        if handed and not robust.contaminated(R.reshape(nw, len(self.outputs), -1), loss_name):
            cost, W = ob.loss(R, allr)
            self._keep_weights(windows, (W / ww[:, None]).reshape(nw, len(self.outputs), -1))
            return ShootingFit(dict(values), [], {}, V, windows, float(np.sum(cost)), 0, after.success,
                               after.message, jac=after.jac, z=R)
        cost, W = ob.loss(R, allr) if nw else (np.zeros(0), np.zeros((0, 0)))
        J = after.jac[1].copy() if handed else (ob.jac(V, allr, R) if nw else np.zeros((0, 0, nv)))
        # a stage from a previous one's end starts near its optimum (small steps, low damping) and stops where no
        # window's start values would move by STAGE_SHIFT of their errors (from a damping of 100 Huber's stage took
        # 39 batched simulations a call, half of least squares' own)
        damping = 1e-2 if handed else (lm.NEAR_DAMPING if near else lm.START_DAMPING)
        st = lm.solve_starts(ob, lm.StartsState(V, R, cost, W, J, np.full(nw, damping),
                                                0.5 * STAGE_SHIFT**2 if handed else 1e-4, np.ones(nw, bool),
                                                np.zeros(nw, int)), max_iter)
        if nw:  # summary over windows, as the joint fit reports it
            self._keep_weights(windows, (st.W / ww[:, None]).reshape(nw, len(self.outputs), -1))
        return ShootingFit(dict(values), [], {}, st.V, windows, float(np.sum(st.cost)), ob.nfev, st.success,
                           "converged" if st.success else "iteration limit", jac=(np.zeros(st.R.shape + (0,)), st.J),
                           z=st.R)

    # ------------------------------------------------------------------ scores

    def window_errors(self, values: dict[str, float], windows: np.ndarray, start_values: np.ndarray) -> dict[str, np.ndarray]:
        """Mean-square error per window and output (in the output's unit squared)."""
        shot = self.shoot(values, windows, start_values)
        return {k: np.mean((shot.pred[k][:, 1:] - shot.meas[k][:, 1:]) ** 2, axis=1) for k in self.outputs}
