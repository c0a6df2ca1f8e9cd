"""Running fit of the friction law's parameters over a sliding window of (v_rel, mu) pairs.

Why a window and a periodic refit: the operator wants to see the law drift (wear,
temperature) as it happens; least squares over the last ~10 s, redone every ~1 s,
tracks it. The window is kept decimated (at most ~20 000 samples) with the regime
switches listed separately, so preparing a fit costs well under a millisecond even at
10 kHz; the fit itself is a pure function of arrays (picklable) and runs off the hot
path, in another process.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from pydantic import ConfigDict
from scipy.optimize import least_squares

from daq.strict import Closed

from .laws import LawDef
from .regime import switch_distance, switch_positions


class RunningLawFit(Closed):
    """One fit of the law over one window of the online estimator: values, standard errors, quality.

    (Not the model fit of daq/models/fit/shooting.py, whose result is a ShootingFit.)
    """

    model_config = ConfigDict(frozen=True)
    rig: str
    t_start: float
    t_end: float
    n_points: int
    params: dict[str, float]  # every parameter of the law (held ones at their nominal value)
    free: list[str]
    stderr: dict[str, float]  # of the free ones; inf = not determined by this window (or at a bound)
    rms: float  # residual rms in mu
    success: bool
    message: str = ""
    seconds: float = 0.0


@dataclass
class FitData:
    """The samples one fit uses (picklable, so the fit can run in another process)."""

    t_start: float
    t_end: float
    v: np.ndarray
    mu: np.ndarray
    growing: np.ndarray


class FitWindow:
    """The last ``seconds`` of estimates (decimated) and the regime switches among them."""

    ROWS = 6  # sample number, t, v_rel, mu, growing, slip

    def __init__(self, seconds: float, rate_hz: float, v_slip: float, settle_samples: int,
                 max_stored: int = 20_000) -> None:
        span = max(1, int(math.ceil(seconds * rate_hz)))
        self.step = max(1, int(math.ceil(span / max_stored)))
        self.cap = max(16, int(math.ceil(span / self.step)))
        self.span = span
        self.buf = np.full((self.ROWS, self.cap), np.nan)
        self.n = 0  # samples ever stored
        self.switches: deque[float] = deque()
        self._slip = -1
        self.v_slip = v_slip
        self.settle = settle_samples

    def append(self, index: np.ndarray, t: np.ndarray, v: np.ndarray, mu: np.ndarray, growing: np.ndarray,
               slip: np.ndarray) -> None:
        """O(block): note the regime switches, store every ``step``-th sample in the ring."""
        if index.size == 0:
            return
        self.switches.extend(switch_positions(slip, index, self._slip).tolist())
        self._slip = int(slip[-1])
        oldest = index[-1] - self.span - self.settle
        while self.switches and self.switches[0] < oldest:
            self.switches.popleft()
        keep = index % self.step == 0
        rows = np.stack([index[keep], t[keep], v[keep], mu[keep], growing[keep], slip[keep]])[:, -self.cap:]
        m = rows.shape[1]
        start = self.n % self.cap
        first = min(m, self.cap - start)
        self.buf[:, start:start + first] = rows[:, :first]
        self.buf[:, :m - first] = rows[:, first:]
        self.n += m

    def ordered(self) -> np.ndarray:
        """The stored samples, oldest first (ROWS x n)."""
        if self.n < self.cap:
            return self.buf[:, :self.n]
        k = self.n % self.cap
        return np.concatenate([self.buf[:, k:], self.buf[:, :k]], axis=1)

    def select(self, max_points: int) -> FitData | None:
        """Slip samples faster than ``v_slip`` and ``settle`` samples from any regime switch, decimated evenly.

        Why slip only: near v_rel = 0 the laws are steep (brake: d mu/dv = alpha mu0 (1 + beta)
        = 170 s/m), so velocity noise of 1e-3 m/s becomes 0.1 in mu there, an errors-in-variables
        bias that would drag the whole fit; in a true stick (belt-ndof) there is no law at all.
        """
        idx, t, v, mu, grow, slip = self.ordered()
        if t.size == 0:
            return None
        ok = np.isfinite(v) & np.isfinite(mu) & (slip > 0.5) & (np.abs(v) > self.v_slip)
        ok &= switch_distance(idx, np.fromiter(self.switches, float, len(self.switches))) >= self.settle
        sel = np.flatnonzero(ok)
        if sel.size > max_points:
            sel = sel[np.linspace(0, sel.size - 1, max_points).astype(np.int64)]
        return FitData(t_start=float(t[0]), t_end=float(t[-1]), v=v[sel], mu=mu[sel], growing=grow[sel])


def fit_law(law: LawDef, data: FitData, min_points: int = 50) -> RunningLawFit:
    """Least squares of mu(v_rel; theta) on the window; standard errors from the Jacobian."""
    t0 = time.perf_counter()
    free = list(law.free)
    n = data.v.size
    if n < max(min_points, len(free) + 2):
        return RunningLawFit(rig=law.rig, t_start=data.t_start, t_end=data.t_end, n_points=n, params=dict(law.nominal),
                         free=free, stderr={}, rms=float("nan"), success=False,
                         message=f"only {n} settled slip samples")
    x0 = np.array([law.nominal[k] for k in free])
    lo = np.array([law.bounds[k][0] for k in free])
    hi = np.array([law.bounds[k][1] for k in free])
    x0 = np.clip(x0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    fixed = dict(law.nominal)

    def resid(x: np.ndarray) -> np.ndarray:
        th = dict(fixed)
        th.update(zip(free, x))
        return law.fn(th, data.v, data.growing) - data.mu

    # soft_l1 with f_scale 0.05 (in mu): quadratic for ordinary residuals, robust to the few
    # samples that a switch the window did not exclude still biases
    sol = least_squares(resid, x0, bounds=(lo, hi), x_scale="jac", loss="soft_l1", f_scale=0.05, max_nfev=200)
    r = sol.fun
    s2 = float(r @ r) / max(1, n - len(free))
    jac = np.asarray(sol.jac, dtype=float)
    col = np.linalg.norm(jac, axis=0)
    seen = (col > 1e-9 * max(col.max(), 1e-300)) & (sol.active_mask == 0)
    se = np.full(len(free), np.inf)
    if seen.any():
        js = jac[:, seen]
        se[seen] = np.sqrt(np.clip(np.diag(np.linalg.pinv(js.T @ js)) * s2, 0.0, None))
    params = dict(fixed)
    params.update({k: float(x) for k, x in zip(free, sol.x)})
    return RunningLawFit(rig=law.rig, t_start=data.t_start, t_end=data.t_end, n_points=n, params=params, free=free,
                     stderr={k: float(s) for k, s in zip(free, se)}, rms=float(np.sqrt(np.mean(r * r))),
                     success=bool(sol.success), message=str(sol.message)[:200], seconds=time.perf_counter() - t0)
