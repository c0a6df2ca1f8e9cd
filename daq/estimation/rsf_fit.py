"""The standard reduction of one velocity step or one slide-hold-slide cycle: a, b, Dc and the machine stiffness
with standard errors, by each state law, as RSFit3000 reports them; and the healing rate over a series of holds.

Why each event on its own window: that is how the field reports a, b and Dc (one row per step, so a lab sees
them change with slip, speed or hold), and it keeps each fit small (5 parameters, a few thousand samples).
The window starts in the latter half of the plateau before the change (PRE_FRACTION), where the slider is
taken to slide steadily at v1: the fit starts there at steady state with v0 = v1, so mu0 is the steady level
at v1 and a - b moves it to v2.

The window need not start at steady state: the slider's friction and state where the window starts (mu_s,
psi_s) are fitted too (a slide of a few Dc after the last hold leaves a transient of a few noise levels, which
biased a, b and Dc by up to 40 standard errors when the start was taken as steady).

Parameters are fitted as (mu0, a, b, ln Dc, ln k', mu_s, psi_s) by trust-region least squares on the samples
averaged in bins that widen with the distance from the programme's nearest corner (BIN_FRACTION of it, at least
one sample): a 100 s hold at 1 kHz becomes ~600 bins, the transients keep every sample, and each bin's residual
is weighted by the square root of its count so the sum of squares is the full data's to the bins' curvature.
Standard errors from the Jacobian at the optimum and the residuals' variance (white noise assumed; a correlated
noise makes them too small, which the coverage test would show). Dc and k' carry their errors through the log.

Which law: both are fitted to every event; with the same number of parameters the difference of their sums of
squares in units of the noise variance is twice the log-likelihood ratio. LAW_MARGIN (10, a likelihood ratio of
~150) names one; below it the event says "undecided" (decision 31).
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field
from scipy.optimize import least_squares

from daq.physics.rsf import simulate
from daq.strict import Closed

from .rsf_programme import Event

LAW_MARGIN = 10.0  # Delta RSS / sigma^2 (= 2 ln likelihood ratio) to name one state law over the other
BIN_FRACTION = 0.01  # bin width / distance from the nearest corner of the programme
N_PARAM = 7


class Estimate(Closed):
    value: float
    se: float = Field(description="standard error (1 sigma); inf where the data do not determine it")


class LawFit(Closed):
    """One state law fitted to one event."""

    law: str
    ok: bool
    mu0: Estimate = Field(description="steady-state friction at v1")
    a: Estimate
    b: Estimate
    a_minus_b: Estimate
    Dc_m: Estimate
    k_per_m: Estimate = Field(description="machine stiffness k' = k / N: friction per metre of load-point travel")
    mu_start: float = Field(description="friction where the window starts (fitted: it need not be steady)")
    psi_start: float = Field(description="state ln(v1 theta / Dc) where the window starts (0: steady at v1)")
    sigma: float = Field(description="the residuals' standard deviation per sample (friction units), from the bins")
    rss: float = Field(description="weighted sum of squares over the bins")
    n: int = Field(description="bins fitted")
    n_samples: int
    message: str = ""


def friction_curve(x: np.ndarray, t0: float, t: np.ndarray, rt: np.ndarray, rv: np.ndarray, v1: float,
                   law: str) -> np.ndarray:
    """mu at the times t of the slider started at t0 in (mu_s, psi_s)."""
    mu0, a, b, ldc, lk, mu_s, psi_s = x
    mu, _ = simulate(np.concatenate([[t0], t]), rt, rv, mu0=mu0, a=a, b=b, dc=math.exp(ldc), kp=math.exp(lk), v0=v1, law=law, rtol=1e-7,
                     start=(mu_s, psi_s))
    return mu[1:]


def bins(t: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Start indices of the bins: each at most BIN_FRACTION of its distance from the nearest corner wide."""
    dt = float(np.median(np.diff(t)))
    k = np.clip(np.searchsorted(corners, t), 1, corners.size - 1)
    dist = np.minimum(np.abs(t - corners[k - 1]), np.abs(corners[k] - t)) if corners.size > 1 else t - t[0]
    width = np.maximum(BIN_FRACTION * dist, dt)
    # each sample's next bin start, were a bin to start there, all at once (the same arithmetic per element): one
    # searchsorted per bin, in a loop, was 18 % of the coverage test's CPU
    nxt = np.maximum(np.searchsorted(t, t + width * (1 - 1e-9), side="left"), np.arange(1, t.size + 1)).tolist()
    starts, i = [], 0
    while i < t.size:
        starts.append(i)
        i = nxt[i]
    return np.asarray(starts)


def start_values(ev: Event, t: np.ndarray, mu: np.ndarray, travel: np.ndarray, k_per_m: float | None) -> np.ndarray:
    """Starting point from the event's own shape: the level before it, the peak, the level after, the distance
    over which the peak decays, the loading slope right after the change."""
    i_ev = ev.i_event - ev.i_start
    pre = mu[:max(i_ev, 2)]
    mu_ref = float(np.median(pre))
    after = mu[i_ev:]
    tail = after[-max(after.size // 5, 2):]
    lnr = math.log(ev.v2 / ev.v1)
    d_ss = float(np.median(tail)) - mu_ref
    up = ev.v2 > ev.v1 or ev.kind == "hold"
    i_pk = int(np.argmax(after) if up else np.argmin(after))
    d_pk = float(after[i_pk]) - mu_ref
    # the decay from the peak to the new level, in load-point travel
    excess = (after[i_pk:] - (mu_ref + d_ss)) * (1 if up else -1)
    gone = np.flatnonzero(excess < abs(d_pk - d_ss) / math.e)
    trav = travel[i_ev:]
    dc = float(trav[i_pk + gone[0]] - trav[i_pk]) if gone.size else float(trav[-1] - trav[i_pk]) / 5
    dc = max(dc, 1e-8)
    if k_per_m is None:  # the slope of the loading just after the change, over its first third to the peak
        n_fit = max(3, min(i_pk // 3, 50))
        slope = np.polyfit(t[i_ev:i_ev + n_fit] - t[i_ev], after[:n_fit], 1)[0]
        dv = (ev.v2 - ev.v1) if ev.kind == "step" else ev.v2
        k_per_m = max(abs(slope / dv), 1e-3) if dv else 1e3
    if ev.kind == "step":
        a = max(abs(d_pk) / abs(lnr) * 1.3, 1e-5)
        b = a - d_ss / lnr
    else:
        scale = max(math.log(max(ev.v1 * ev.hold_s / dc, math.e)), 1.0)
        b = max(abs(d_pk) / scale, 1e-5)
        a = 0.8 * b
    mu_s = float(np.median(mu[:min(mu.size, 20)]))
    return np.array([mu_ref, a, b, math.log(dc), math.log(k_per_m), mu_s, 0.0])


def fit_law(ev: Event, t: np.ndarray, mu: np.ndarray, rt: np.ndarray, rv: np.ndarray, law: str,
            x0: np.ndarray, k_fixed: float | None = None) -> LawFit:
    """Least squares of one law on one event's window (t, mu); k' fixed when ``k_fixed`` is given."""
    free = np.ones(N_PARAM, dtype=bool)
    if k_fixed is not None:
        free[4] = False
        x0 = x0.copy()
        x0[4] = math.log(k_fixed)
    starts = bins(t, rt)
    count = np.diff(np.append(starts, t.size)).astype(float)
    t_bin = np.add.reduceat(t, starts) / count
    mu_bin = np.add.reduceat(mu, starts) / count
    weight = np.sqrt(count)
    scale = np.array([1e-3, 1e-3, 1e-3, 0.1, 0.1, 1e-3, 0.1])
    lo = np.array([-np.inf, 1e-7, -1.0, math.log(1e-10), math.log(1e-3), -np.inf, -50.0])
    hi = np.array([np.inf, 1.0, 1.0, math.log(1.0), math.log(1e12), np.inf, 50.0])
    x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)
    failed = np.full(t_bin.size, 1e3)

    def residual(xf: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[free] = xf
        try:
            return weight * (friction_curve(x, t[0], t_bin, rt, rv, ev.v1, law) - mu_bin)
        except ValueError:
            return failed

    sol = least_squares(residual, x0[free], bounds=(lo[free], hi[free]), x_scale=scale[free], method="trf",
                        diff_step=1e-6, max_nfev=400)
    x = x0.copy()
    x[free] = sol.x
    r = sol.fun
    n, p = r.size, int(free.sum())
    rss = float(r @ r)
    cov = np.full((N_PARAM, N_PARAM), np.inf)
    try:
        j = sol.jac
        cov = np.zeros((N_PARAM, N_PARAM))
        cov[np.ix_(free, free)] = np.linalg.inv(j.T @ j) * rss / max(n - p, 1)
    except np.linalg.LinAlgError:
        cov = np.full((N_PARAM, N_PARAM), np.inf)
    var = np.diag(cov)
    se = np.sqrt(np.where(var >= 0, var, np.inf))
    v_amb = cov[1, 1] + cov[2, 2] - 2 * cov[1, 2]
    se_amb = math.sqrt(v_amb) if math.isfinite(v_amb) and v_amb >= 0 else math.inf
    dc, kp = math.exp(x[3]), math.exp(x[4])
    ok = bool(sol.success and np.all(np.isfinite(se[free])) and rss < failed @ failed / 4)
    return LawFit(law=law, ok=ok, mu0=Estimate(value=x[0], se=se[0]), a=Estimate(value=x[1], se=se[1]),
                  b=Estimate(value=x[2], se=se[2]), a_minus_b=Estimate(value=x[1] - x[2], se=se_amb),
                  Dc_m=Estimate(value=dc, se=dc * se[3]), k_per_m=Estimate(value=kp, se=kp * se[4]),
                  mu_start=float(x[5]), psi_start=float(x[6]), sigma=math.sqrt(rss / max(n - p, 1)), rss=rss, n=n, n_samples=int(t.size),
                  message="" if sol.success else str(sol.message))


def law_verdict(fits: dict[str, LawFit]) -> tuple[str, float]:
    """Which state law the event favours and by how much (Delta RSS / sigma^2); 'undecided' under LAW_MARGIN."""
    ok = {k: f for k, f in fits.items() if f.ok}
    if len(ok) < 2:
        return (next(iter(ok)) if ok else "none"), math.inf if ok else 0.0
    (l1, f1), (l2, f2) = sorted(ok.items(), key=lambda kv: kv[1].rss)
    sigma2 = f1.rss / max(f1.n - N_PARAM, 1)
    margin = (f2.rss - f1.rss) / sigma2
    return (l1 if margin >= LAW_MARGIN else f"undecided between {l1} and {l2}"), float(margin)


class Healing(Closed):
    """beta = d(Delta mu_peak) / d log10(t_hold) over one recording's holds (Dieterich 1972; Marone 1998)."""

    beta: Estimate
    intercept: float
    holds_s: list[float]
    peak_changes: list[float]
    n: int


def healing_rate(holds_s: list[float], peak_changes: list[float]) -> Healing | None:
    """Straight line of the peak change against log10 of the hold time; None with fewer than two holds."""
    if len(holds_s) < 2:
        return None
    x = np.log10(np.asarray(holds_s))
    y = np.asarray(peak_changes)
    coef = np.polyfit(x, y, 1)
    sxx = float(((x - x.mean()) ** 2).sum())
    r = y - np.polyval(coef, x)
    se = math.sqrt(float(r @ r) / (x.size - 2) / sxx) if x.size > 2 and sxx > 0 else math.inf
    return Healing(beta=Estimate(value=float(coef[0]), se=se), intercept=float(coef[1]), holds_s=list(map(float, holds_s)),
                   peak_changes=list(map(float, peak_changes)), n=len(holds_s))
