"""Output-error fitting by multiple shooting: simulate the model over short windows of the data.

Why this and not inverse dynamics: friction from twice-differentiated noisy
positions is biased exactly at stick-slip transitions. Here the model is
integrated from each window's start and compared with the *measured* signals,
so transitions are judged by what the model predicts, not by a derivative.
Windows are short (about one stick-slip cycle and a half) so phase drift cannot
build up; each window's initial velocities are free (they are not measured; at
slow sampling the start positions too, see RigData.start_slots: the "start
values"), and the model's free parameters are shared by all windows. Our own
Levenberg-Marquardt (:meth:`Problem.fit`) solves the normal equations through the Schur
complement over the per-window start values, so one Jacobian costs (free parameters + start
values per window) batched simulations however many windows there are, and Broyden updates
carry it between refreshes. Decision record: docs/decisions/0002-output-error-by-multiple-shooting.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from daq.physics.contact import N_AUX

from . import robust
from .build import Builder
from .cycle_features import load_cycles
from .data import Measured, RigData

WINDOW_CYCLES = 1.5  # window length in stick-slip periods
BROYDEN = True  # carry the Jacobian by rank-one updates between finite-difference refreshes (see Problem.fit)
MIN_WINDOW_SAMPLES = 12
MIN_CYCLES = 10  # fewer load cycles than this in a record: its windows are cut by the spectral line alone
MIN_WINDOWS = 12  # fewer windows starting in stick than this: windows start anywhere the drive moves
# Initial Levenberg-Marquardt damping of a window's own fit (fit_starts). Why high: the start comes
# from the data and is close; a near-Gauss-Newton first step through a break-away can jump to another
# basin that is better than the start but far from the best (seen on one 100 Hz window: 865 um after
# 30 trials from damping 1e-2, 4.7 um from 100). Damping falls 5x per accepted step.
START_DAMPING = 100.0


TRANSIENT_SLOPE = 10.0  # a window whose drive command changes this many times faster than the median is a transient


@dataclass
class Windows:
    starts: np.ndarray  # sample index of each window's start
    length: int  # samples per window, start included
    held_out: np.ndarray  # bool per window: scored but not fitted
    transient: np.ndarray | None = None  # bool per window: the drive accelerates from rest or stops (flagged)

    def select(self, held_out: bool | None) -> np.ndarray:
        """Fit (False) or held-out (True) windows, transients left out; None: every window, transients too."""
        if held_out is None:
            return np.arange(self.starts.size)
        keep = self.held_out == held_out
        if self.transient is not None:
            keep &= ~self.transient
        return np.flatnonzero(keep)

    def scored(self) -> np.ndarray:
        """Every window a score reads: the fit windows, then the held-out ones (flagged transients left out)."""
        return np.concatenate([self.select(False), self.select(True)])


def dominant_period(m: Measured, fmin: float = 0.5) -> float:
    """Period of the strongest oscillation of the primary signal (detrended) [s]."""
    x = m.outputs[m.primary]
    x = x - np.polynomial.polynomial.polyval(np.arange(x.size), np.polynomial.polynomial.polyfit(
        np.arange(x.size), x, 3))
    n = 1 << int(math.ceil(math.log2(max(x.size, 16))))
    spec = np.abs(np.fft.rfft(x * np.hanning(x.size), n))
    f = np.fft.rfftfreq(n, 1.0 / m.rate)
    ok = f >= fmin
    if not ok.any():
        return 1.0
    fpk = f[ok][np.argmax(spec[ok])]
    return 1.0 / fpk if fpk > 0 else 1.0


def cycle_period(m: Measured) -> float:
    """The stick-slip period windows are cut by [s]: the strongest spectral line, unless the record's load cycles
    (cycle_features.load_cycles, at least MIN_CYCLES of them) say otherwise by more than a factor 1.5; then their
    median period. Why: on a real record the strongest line need not be the cycle. The lab's spring-slider at
    1.1 mm/s wanders slowly (line at 0.67 Hz; cycles every 24 ms): windows of 2.2 s held ~90 cycles and the seed
    model's error was 9.0x its floor, 1.7x with windows of 1.5 cycles; at 42 um/s a 50 Hz line (cycles every
    0.6 s) made windows of 30 ms that saw almost no slip. Only cycles that fill at least half the record count:
    on the brake's ramp-B record with velocity strengthening hidden, 24 cycles of 0.12 s fill 3 s of 52 (the
    stick-slip dies out), and windows cut by them made the diagnosis name temperature before the hidden effect;
    the lab's records are 99 % cycles."""
    spectral = dominant_period(m)
    cycles = load_cycles(m.t, m.outputs[m.primary], m.sigma[m.primary])["period_s"]
    if cycles.size < MIN_CYCLES or np.sum(cycles) < 0.5 * (m.t[-1] - m.t[0]):
        return spectral  # too few, or cycles that fill less than half the record: not its rhythm
    median = float(np.median(cycles))
    return spectral if median / 1.5 <= spectral <= 1.5 * median else median


def make_windows(m: Measured, v_stick: float, window_s: float | None = None, max_windows: int = 160,
                 held_out_every: int = 3) -> Windows:
    """Non-overlapping windows spread over the whole record, starting where the contact sticks if it does.

    Why start in stick: there the block moves with the belt, so the unknown start
    velocities are well estimated from the data even at 100 Hz sampling.
    """
    if window_s is None:
        window_s = WINDOW_CYCLES * cycle_period(m)
    L = max(MIN_WINDOW_SAMPLES, int(round(window_s * m.rate)) + 1)
    L = min(L, m.n // 4)
    edge = max(3, int(0.01 * m.rate))  # smoothing filters are less accurate at the very ends
    stuck = np.abs(m.v_rel) < v_stick if m.v_rel is not None else np.zeros(m.n, bool)
    # only where the belt moves: a recording that starts before the drive (or runs on after it stops)
    # says nothing about friction, and there the command and the belt disagree about when motion starts
    moving = np.abs(m.drive_measured) > 0.05 * np.max(np.abs(m.drive_measured))
    moving &= np.abs(m.drive_command) > 0.05 * np.max(np.abs(m.drive_command))
    starts = _window_starts(m.n, L, edge, stuck, moving, in_stick=stuck.mean() > 0.05)
    if len(starts) < MIN_WINDOWS:  # sticks too rare to start enough windows in them: start them anywhere
        starts = max(starts, _window_starts(m.n, L, edge, stuck, moving, in_stick=False), key=len)
    if not starts:
        starts = [edge]
    s = np.asarray(starts, dtype=int)
    if s.size > max_windows:  # evenly spaced subset: the cost stays bounded on long records
        s = s[np.unique(np.linspace(0, s.size - 1, max_windows).round().astype(int))]
    held = (np.arange(s.size) % held_out_every) == held_out_every - 1
    if s.size < 3:
        held[:] = False
    return Windows(s, L, held, transient_windows(m, s, L))


def _window_starts(n: int, L: int, edge: int, stuck: np.ndarray, moving: np.ndarray, in_stick: bool) -> list[int]:
    """Window starts, one window length apart at least; with ``in_stick`` each at the first stuck sample after
    that (a search that finds none within a window length skips it)."""
    starts: list[int] = []
    i = edge
    while i + L + edge <= n:
        if in_stick:
            j = i
            limit = min(n - L - edge, i + L)
            while j < limit and not (stuck[j] and stuck[max(j - 2, 0)] and moving[j] and moving[min(j + L, n - 1)]):
                j += 1
            if j >= limit:
                i = limit + 1
                continue
            i = j
        if not in_stick and not (moving[i] and moving[min(i + L, n - 1)]):
            i += 1
            continue
        starts.append(i)
        i += L
    return starts


def transient_windows(m: Measured, starts: np.ndarray, length: int) -> np.ndarray:
    """Windows in which the drive command changes much faster than over the record's typical window
    (the lead-in from rest, an abrupt stop): the model's drive there is least certain (a regulator ramps
    within its own limits) and one such window can carry more error than all the others together. They
    are flagged, scored in the all-window error and in the report, but neither fit nor decide.
    Both the command (noise-free; a step in it is what a drive lags behind) and the measured speed
    (smoothed over +-0.25 s; it shows the drive's own ramp after a step that came before the window).
    """
    slope = np.maximum(np.abs(np.gradient(m.drive_command, 1.0 / m.rate)),
                       np.abs(np.gradient(m.drive_measured, 1.0 / m.rate)))
    idx = starts[:, None] + np.arange(length)[None, :]
    per_window = slope[idx].max(axis=1)
    typical = float(np.median(per_window))
    scale = max(typical, 1e-3 * float(np.max(np.abs(m.drive_command))))  # a constant drive: tiny median
    out = per_window > TRANSIENT_SLOPE * scale
    if out.sum() > 0.25 * out.size:  # a record that is mostly transients: nothing is flagged
        out[:] = False
    return out


WINDOW_CAP = 3.0  # in a fit, no window's cost counts for more than this many times the median window's


def window_weights(costs: np.ndarray, windows: np.ndarray, n_windows: int, cap: float = WINDOW_CAP) -> np.ndarray:
    """Per-window weights that cap each window's share of a fit's cost at ``cap`` x the median window's.

    Why: a few windows (a transient from the record's initial state, a window whose start values sit
    in a poor local minimum) can carry more cost than all the others together; a least-squares fit then
    bends the model's parameters to them and gets worse everywhere else (seen: two windows of 19 at
    170x and 80x the median moved beta to its bound and doubled the held-out error). A window's weight
    is min(1, cap x median / cost): a capped loss at the level of windows, the windows' own start values
    still fitted as before. Windows not in ``windows`` keep weight 1.
    """
    w = np.ones(n_windows)
    if costs.size >= 3:
        m = float(np.median(costs))
        if m > 0:
            w[windows] = np.minimum(1.0, cap * m / np.maximum(costs, 1e-300))
    return w


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
        d[free] = np.linalg.solve(S[np.ix_(free, free)], rhs[free])
    return d


STAGE_SHIFT = 0.1  # a stage from a previous one's end (another loss) stops where its Gauss-Newton step would move
# the parameters by less than this many standard errors (jointly): the refreshes that confirm a small relative
# decrease (1e-4) on a fresh Jacobian cost 2.7 finite-difference Jacobians a stage, 17 % of a diagnosis


def _parameter_gain(A: np.ndarray, B: np.ndarray, C: np.ndarray, ga: np.ndarray, gc: np.ndarray) -> float:
    """The part of the undamped Gauss-Newton decrease 0.5 g^T H^-1 g that the free parameters bring, every window's
    start values profiled out (Schur complement): 0.5 d^T Cov^-1 d for the step d, with Cov^-1 = J^T W J."""
    if not ga.size:
        return 0.0
    nv = C.shape[1]
    try:
        Ci = np.linalg.inv(C + 1e-12 * np.eye(nv)[None])
    except np.linalg.LinAlgError:  # a window whose start values the data do not fix (seen: a constant-speed record
        Ci = np.linalg.pinv(C)  # with a strength held fixed, daq demo --closed-loop): the pseudo-inverse profiles it
    BCi = np.einsum("wij,wjk->wik", B, Ci)
    S = A - np.einsum("wij,wkj->ik", BCi, B)
    rhs = ga - np.einsum("wij,wj->i", BCi, gc)
    return 0.5 * float(rhs @ np.linalg.lstsq(S, rhs, rcond=1e-12)[0])


def start_jacobian(resid, V: np.ndarray, r: np.ndarray, vscale: np.ndarray) -> np.ndarray:
    """Per window, d(residuals)/d(start values) by forward differences: one simulation per start slot."""
    j = np.empty(r.shape + (V.shape[1],))
    for q in range(V.shape[1]):
        dv = 1e-4 * vscale[q]
        vp = V.copy()
        vp[:, q] += dv
        j[..., q] = (resid(vp) - r) / dv
    return j


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
        weights: (n_win, n_out, L - r0); a window the integrator gave up on is 1e6 everywhere."""
        shot = self.shoot(values, windows, start_values, length)
        z = np.stack([(shot.pred[k][:, self.r0:] - shot.meas[k][:, self.r0:]) / self.m.sigma[k]
                      for k in self.outputs], axis=1)
        return np.nan_to_num(z, nan=1e6, posinf=1e6, neginf=-1e6)

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

        Levenberg-Marquardt on the block structure of multiple shooting: the start
        values of one window touch only that window's residuals, so the normal
        equations are solved through the Schur complement over the global parameters
        (cost linear in the number of windows). The Jacobian is by finite differences
        (one simulation of all windows per free parameter and per start slot); with
        ``BROYDEN`` it is then carried along accepted steps by per-window Broyden
        rank-one updates (each window's residuals see only the globals and that window's
        start values, so the update keeps the block structure), and re-computed by finite
        differences whenever a step fails or convergence is to be declared. Simulations
        are the whole cost: this cuts them per iteration from k + n_start + 1 to about 1.
        The reported uncertainties come from a finite-difference Jacobian (a stage handed one by a previous stage
        that converged: that one, carried by Broyden over the stage's few steps). A robust loss enters as
        iteratively reweighted least squares: the step is the weighted Gauss-Newton step with each sample's weight
        at the current iterate (robust.evaluate), a trial is accepted only if the loss itself falls, and the
        Jacobian is carried for the unweighted residuals (the weights change from one iterate to the next).
        """
        broyden = BROYDEN
        values = dict(values)
        k, nw, nv = len(free), windows.size, self.n_start
        lo = np.array([bounds[n][0] for n in free], dtype=float)
        hi = np.array([bounds[n][1] for n in free], dtype=float)
        theta = np.clip(np.array([values[n] for n in free], dtype=float), lo, hi)
        V = (self.default_starts(windows) if start_values is None else np.array(start_values, dtype=float))
        nfev = 0
        ww = self.weights[windows] if self.weights is not None else np.ones(nw)
        loss_name = loss or self.loss

        def resid(th: np.ndarray, vel: np.ndarray) -> np.ndarray:
            nonlocal nfev
            nfev += 1
            vals = dict(values)
            vals.update({n: float(th[i]) for i, n in enumerate(free)})
            return self.scaled(vals, windows, vel, length).reshape(nw, -1)

        def loss(z: np.ndarray) -> tuple[float, np.ndarray]:
            """The loss (windows' weights applied) and each residual's weight in the weighted squares."""
            per_window, w = robust.evaluate(z.reshape(nw, len(self.outputs), -1), loss_name)
            return float(np.sum(ww * per_window)), ww[:, None] * w.reshape(nw, -1)

        vscale = np.maximum(np.abs(V).mean(axis=0), 1e-3)

        def jacobian(th: np.ndarray, vel: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            jg = np.empty(r.shape + (k,))
            for i in range(k):
                hstep = 1e-4 * max(abs(th[i]), 1e-3 * (hi[i] - lo[i]), 1e-8)
                if th[i] + hstep > hi[i]:
                    hstep = -hstep
                tp = th.copy()
                tp[i] += hstep
                jg[..., i] = (resid(tp, vel) - r) / hstep
            return jg, start_jacobian(lambda vp: resid(th, vp), vel, r, vscale)

        keeps_weights = length is None or length == self.win.length  # (a shorter fit's weights are not the windows')
        handed = (after is not None and after.jac is not None and after.z is not None
                  and after.jac[0].shape == after.z.shape + (k,) and after.jac[1].shape == after.z.shape + (nv,))
        R = after.z if handed else resid(theta, V)
        cost, W = loss(R)
        if handed and not robust.contaminated(R.reshape(nw, len(self.outputs), -1), loss_name):
            vals = {**values, **{n: float(theta[i]) for i, n in enumerate(free)}}
            if keeps_weights:
                self._keep_weights(windows, (W / ww[:, None]).reshape(nw, len(self.outputs), -1))
            return ShootingFit(vals, list(free), dict(after.std), V.copy(), windows, cost, 0, True,
                               "no more samples beyond the threshold than noise puts there: least squares' end",
                               jac=after.jac, z=R)
        lam = 1e-2
        success, message = False, "iteration limit"
        Jg, Jv = after.jac if handed else jacobian(theta, V, R)
        fresh = True
        it = 0
        while it < max_iter:
            it += 1
            sw = np.sqrt(W)[..., None]
            Jgw, Jvw = Jg * sw, Jv * sw
            Rw = R * sw[..., 0]
            A = np.einsum("wri,wrj->ij", Jgw, Jgw)
            B = np.einsum("wri,wrj->wij", Jgw, Jvw)
            C = np.einsum("wri,wrj->wij", Jvw, Jvw)
            ga = np.einsum("wri,wr->i", Jgw, Rw)
            gc = np.einsum("wrj,wr->wj", Jvw, Rw)
            if handed and _parameter_gain(A, B, C, ga, gc) <= 0.5 * STAGE_SHIFT**2:
                success, message = True, f"converged (no parameter would move by {STAGE_SHIFT:g} of its error)"
                break
            improved = False
            for _try in range(14 if fresh else 2):
                Ad = A + lam * np.diag(np.diag(A) + 1e-12)
                Cd = C + lam * (np.einsum("wii->wi", C)[:, :, None] * np.eye(nv)[None] + 1e-12 * np.eye(nv)[None])
                Ci = np.linalg.inv(Cd)
                BCi = np.einsum("wij,wjk->wik", B, Ci)
                S = Ad - np.einsum("wij,wkj->ik", BCi, B) if k else np.zeros((0, 0))
                rhs = -ga + np.einsum("wij,wj->i", BCi, gc) if k else np.zeros(0)
                dth = bounded_step(S, rhs, theta, lo, hi) if k else np.zeros(0)
                dV = -np.einsum("wij,wj->wi", Ci, gc + np.einsum("wij,i->wj", B, dth))
                th_new = np.clip(theta + dth, lo, hi)
                V_new = V + dV
                R_new = resid(th_new, V_new)
                cost_new, W_new = loss(R_new)
                if np.isfinite(cost_new) and cost_new < cost:
                    improved = True
                    rel = (cost - cost_new) / max(cost, 1e-300)
                    if broyden:  # per window: J_w += (dR_w - J_w d_w) d_w^T / |d_w|^2, d_w = (dtheta, dV_w)
                        st, sV = th_new - theta, V_new - V
                        pred = np.einsum("wri,i->wr", Jg, st) + np.einsum("wrj,wj->wr", Jv, sV)
                        norm2 = float(st @ st) + np.einsum("wj,wj->w", sV, sV)
                        u = (R_new - R - pred) / np.maximum(norm2, 1e-300)[:, None]
                        Jg = Jg + u[:, :, None] * st[None, None, :]
                        Jv = Jv + u[:, :, None] * sV[:, None, :]
                    theta, V, R, cost, W = th_new, V_new, R_new, cost_new, W_new
                    lam = max(lam / 5.0, 1e-7)
                    break
                lam *= 4.0
            small = improved and (rel < 1e-6 or (rel < 1e-4 and _try == 0))  # small decrease from a full step
            if improved and not small:
                if not broyden:
                    Jg, Jv = jacobian(theta, V, R)
                fresh = not broyden
                continue
            if handed and improved:  # a stage from a previous one's end stops on the parameters' gain (above), not
                fresh = False  # on a small relative decrease: 1e-4 of a cost of N/2 is a fraction of a standard
                continue  # error (seen: 0.6 of one short of scipy's Huber estimate)
            if not fresh:  # a failed or tiny step on a carried Jacobian: judge it on a fresh one
                Jg, Jv = jacobian(theta, V, R)
                fresh = True
                continue
            success, message = True, ("converged (relative cost decrease < 1e-4)" if improved
                                      else "no further decrease")
            break
        if not fresh and not (handed and success):  # (a handed stage's uncertainties: its carried Jacobian, a few
            # Broyden steps from a finite-difference one)
            Jg, Jv = jacobian(theta, V, R)
        vals = dict(values)
        vals.update({n: float(theta[i]) for i, n in enumerate(free)})
        sw = np.sqrt(W)[..., None]
        std = self._stds(Jg * sw if k else None, Jv * sw, 0.5 * float(np.sum(W * R * R)), R.size, k, nv, nw, free)
        if keeps_weights:
            self._keep_weights(windows, (W / ww[:, None]).reshape(nw, len(self.outputs), -1))
        return ShootingFit(vals, list(free), std, V.copy(), windows, cost, nfev, success, message, jac=(Jg, Jv), z=R)

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

    def fit_starts(self, values: dict[str, float], windows: np.ndarray, max_iter: int = 10) -> ShootingFit:
        """Only the start unknowns (the model fixed): how well can this model follow these windows.

        Why a Levenberg-Marquardt per window and not one over all of them: with the model fixed the
        windows are independent, and a shared damping and a shared accept/reject let one window
        that needs small steps (near a break-away) stall while the summed cost still falls. Each
        window here keeps its own damping and stops on its own; the simulations stay batched
        (one call per trial over the windows still iterating). Least squares first, then the problem's loss from
        there, as Session fits the parameters (robust.py says why).
        """
        first = self._fit_starts(values, windows, self.default_starts(windows), robust.SQUARES, max_iter)
        if self.loss == robust.SQUARES:
            return first
        res = self._fit_starts(values, windows, first.start_values, self.loss, max_iter, after=first)
        res.nfev += first.nfev
        return res

    def _fit_starts(self, values: dict[str, float], windows: np.ndarray, V: np.ndarray, loss_name: str,
                    max_iter: int, after: ShootingFit | None = None) -> ShootingFit:
        """fit_starts' Levenberg-Marquardt per window from start values ``V`` under one loss (``after``: a previous
        stage that ended there: its Jacobian and residuals are this one's first)."""
        nw, nv = windows.size, self.n_start
        V = np.array(V, dtype=float)
        nfev = 0
        ww = self.weights[windows] if self.weights is not None else np.ones(nw)

        def resid(vel: np.ndarray, rows: np.ndarray) -> np.ndarray:
            nonlocal nfev
            nfev += 1
            return self.scaled(values, windows[rows], vel).reshape(rows.size, -1)

        def loss(z: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            per_window, w = robust.evaluate(z.reshape(rows.size, len(self.outputs), -1), loss_name)
            return ww[rows] * per_window, ww[rows, None] * w.reshape(rows.size, -1)

        vscale = np.maximum(np.abs(V).mean(axis=0), 1e-3) if nw else np.ones(nv)

        def jac(vel: np.ndarray, rows: np.ndarray, r: np.ndarray) -> np.ndarray:
            return start_jacobian(lambda vp: resid(vp, rows), vel, r, vscale)

        allr = np.arange(nw)
        handed = (nw > 0 and after is not None and after.z is not None and after.z.shape[0] == nw
                  and after.jac is not None)
        R = after.z.copy() if handed else (resid(V, allr) if nw else np.zeros((0, 0)))
        if handed and not robust.contaminated(R.reshape(nw, len(self.outputs), -1), loss_name):
            cost, W = loss(R, allr)
            self._keep_weights(windows, (W / ww[:, None]).reshape(nw, len(self.outputs), -1))
            return ShootingFit(dict(values), [], {}, V, windows, float(np.sum(cost)), 0, after.success,
                               after.message, jac=after.jac, z=R)
        cost, W = loss(R, allr) if nw else (np.zeros(0), np.zeros((0, 0)))
        J = after.jac[1].copy() if handed else (jac(V, allr, R) if nw else np.zeros((0, 0, nv)))
        # a stage from a previous one's end starts near its optimum (small steps, low damping) and stops where no
        # window's start values would move by STAGE_SHIFT of their errors (from a damping of 100 Huber's stage took
        # 39 batched simulations a call, half of least squares' own)
        lam = np.full(nw, 1e-2 if handed else START_DAMPING)
        enough = 0.5 * STAGE_SHIFT**2 if handed else 1e-4
        active = np.ones(nw, bool)
        fails = np.zeros(nw, int)
        for _ in range(max_iter * 3):  # a failed trial costs one simulation, a success 1 + nv
            rows = np.flatnonzero(active)
            if not rows.size:
                break
            sw = np.sqrt(W[rows])
            Jr, Rr = J[rows] * sw[..., None], R[rows] * sw
            C = np.einsum("wri,wrj->wij", Jr, Jr)
            g = np.einsum("wri,wr->wi", Jr, Rr)
            D = np.einsum("wii->wi", C) + 1e-12
            # converged where even the undamped (Gauss-Newton) step promises next to nothing; a small
            # actual decrease is no test while the damping is still high
            gn = 0.5 * np.einsum("wi,wi->w", g, np.linalg.solve(C + 1e-9 * D[:, :, None] * np.eye(nv)[None],
                                                                  g[..., None])[..., 0])
            conv = gn <= np.maximum(1e-6 * cost[rows], enough)
            active[rows[conv]] = False
            keep = ~conv
            rows, Jr, Rr, C, g, D = rows[keep], Jr[keep], Rr[keep], C[keep], g[keep], D[keep]
            if not rows.size:
                break
            Cd = C + lam[rows, None, None] * (D[:, :, None] * np.eye(nv)[None])
            dV = -np.linalg.solve(Cd, g[..., None])[..., 0]
            Vt = V[rows] + dV
            Rt = resid(Vt, rows)
            ct, Wt = loss(Rt, rows)
            ok = np.isfinite(ct) & (ct < cost[rows])
            rel = np.where(ok, (cost[rows] - ct) / np.maximum(cost[rows], 1e-300), 0.0)
            acc = rows[ok]
            V[acc], R[acc], cost[acc], W[acc] = Vt[ok], Rt[ok], ct[ok], Wt[ok]
            lam[acc] = np.maximum(lam[acc] / 5.0, 1e-7)
            lam[rows[~ok]] *= 4.0
            fails[acc] = 0
            fails[rows[~ok]] += 1
            done = ok & (rel < 1e-9)
            done |= ~ok & ((fails[rows] >= 12) | (lam[rows] > 1e10))
            active[rows[done]] = False
            redo = rows[ok & ~done]
            if redo.size:
                J[redo] = jac(V[redo], redo, R[redo])
        # summary over windows, as the joint fit reports it
        if nw:
            self._keep_weights(windows, (W / ww[:, None]).reshape(nw, len(self.outputs), -1))
        message = "converged" if not active.any() else "iteration limit"
        return ShootingFit(dict(values), [], {}, V, windows, float(np.sum(cost)), nfev, not active.any(), message,
                           jac=(np.zeros(R.shape + (0,)), J), z=R)

    # ------------------------------------------------------------------ scores

    def window_errors(self, values: dict[str, float], windows: np.ndarray, start_values: np.ndarray) -> dict[str, np.ndarray]:
        """Mean-square error per window and output (in the output's unit squared)."""
        shot = self.shoot(values, windows, start_values)
        return {k: np.mean((shot.pred[k][:, 1:] - shot.meas[k][:, 1:]) ** 2, axis=1) for k in self.outputs}
