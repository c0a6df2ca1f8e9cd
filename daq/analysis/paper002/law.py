"""Paper 002 step 2: law (3) fitted to mu(t) by nonlinear least squares in v = |v_wz|.

    mu(v) = A [1 - exp(-B v)] exp(-C v) + D v + E,

evaluated with the shared physics law ``daq.physics.friction.mu_drum`` (sgn regularised over the
rig's eps = 0.2 mm/s, far below the samples used), by variable projection: A, D, E are linear
given B, C, so a log grid over (B, C) and then scipy least_squares over (log B, log C) with A, D,
E solved at every step. Standard errors from the five-parameter Jacobian, inflated by the
residuals' integrated autocorrelation time (samples 1 ms apart are not independent).

The result is a ``DrumLawFit`` (paper 001 has its own ``BrakeLawFit`` for law (7)).
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field
from scipy.optimize import least_squares

from daq.physics.friction import mu_drum
from daq.strict import Closed

PARAMS = ("A", "B", "C", "D", "E")
UNITS = {"A": "-", "B": "s/m", "C": "s/m", "D": "s/m", "E": "-"}
LAW = "mu(v) = A [1 - exp(-B v)] exp(-C v) + D v + E,  v = v_wz = (omega - phi') R  [m/s]"
REL_SE_IDENTIFIED = 0.25  # a coefficient with se/|value| above this is reported as not identified
LOG_BOUNDS = ((0.1, 1e5), (0.01, 1e5))  # [s/m] search ranges of B and C (log scale)


def law(v: np.ndarray, th: np.ndarray | tuple, eps: float) -> np.ndarray:
    """Law (3) at sliding speeds v >= 0 through the shared physics law (plus D v)."""
    A, B, C, D, E = (float(x) for x in th)
    return mu_drum(np.asarray(v, dtype=float), A, B, C, E, eps, 1.0) + D * np.asarray(v, dtype=float)


class Coef(Closed):
    value: float
    se: float | None = Field(description="standard error (Jacobian, inflated by the residual autocorrelation)")
    unit: str
    identified: bool = Field(description=f"se / |value| < {REL_SE_IDENTIFIED}")


class DrumLawFit(Closed):
    """Law (3) fitted to (v, mu) samples: coefficients with standard errors, R^2, residual rms."""

    coefficients: dict[str, Coef]
    R2: float
    R: float = Field(description="sqrt(R2), the correlation coefficient paper 002 prints (R = 0.7837 in Fig. 5)")
    rms: float
    n: int
    n_eff: float = Field(description="samples / integrated autocorrelation time of the residuals")
    v_range_m_per_s: tuple[float, float]
    converged: bool
    message: str
    correlation: dict[str, dict[str, float]]

    def theta(self) -> np.ndarray:
        return np.array([self.coefficients[k].value for k in PARAMS])


def _basis(v: np.ndarray, B: float, C: float, eps: float) -> np.ndarray:
    """Columns multiplying A, E and D in law (3), from the shared law itself (A, E, D enter linearly)."""
    return np.column_stack([mu_drum(v, 1.0, B, C, 0.0, eps, 1.0), mu_drum(v, 0.0, B, C, 1.0, eps, 1.0), v])


def _project(v: np.ndarray, mu: np.ndarray, B: float, C: float, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """(theta, residual) with A, E, D by linear least squares for given B, C (variable projection)."""
    X = _basis(v, B, C, eps)
    coef, *_ = np.linalg.lstsq(X, mu, rcond=None)
    return np.array([coef[0], B, C, coef[2], coef[1]]), X @ coef - mu


def _start(v: np.ndarray, mu: np.ndarray, eps: float) -> np.ndarray:
    """The best (B, C) of a log grid, A, D, E projected out (a subsample: it only has to find the valley)."""
    step = max(1, v.size // 6000)
    vs, ms = v[::step], mu[::step]
    best = (np.inf, None)
    for B in np.geomspace(LOG_BOUNDS[0][0], LOG_BOUNDS[0][1], 31):
        for C in np.geomspace(LOG_BOUNDS[1][0], LOG_BOUNDS[1][1], 31):
            th, r = _project(vs, ms, B, C, eps)
            ss = float(r @ r)
            if ss < best[0]:
                best = (ss, th)
    return best[1]


def integrated_autocorrelation(r: np.ndarray, max_lag: int = 2000) -> float:
    """1 + 2 sum of the residuals' autocorrelation up to its first non-positive lag (>= 1)."""
    r = r - r.mean()
    n = r.size
    if n < 10:
        return 1.0
    m = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(r, m)
    ac = np.fft.irfft(f * np.conj(f), m)[: min(n, max_lag)]
    ac = ac / ac[0]
    tau = 1.0
    for k in range(1, ac.size):
        if ac[k] <= 0:
            break
        tau += 2.0 * ac[k]
    return max(1.0, float(tau))


def fit_law(v: np.ndarray, mu: np.ndarray, eps: float) -> DrumLawFit:
    """Law (3) by nonlinear least squares on samples in time order (v > 0 sliding speed, mu by eq. (2)).

    Variable projection: the search runs over (log B, log C) only, with A, D, E solved linearly
    at every step, so it cannot stall in the long curved A-B valley (A(1 - exp(-B v)) ~ A B v
    while B v is small) and needs no start values from the user. Standard errors come from the
    full five-parameter Jacobian at the optimum.
    """
    v = np.asarray(v, dtype=float)
    mu = np.asarray(mu, dtype=float)
    if v.size < 20:
        raise ValueError(f"only {v.size} samples to fit")
    x0 = _start(v, mu, eps)
    lo = np.log([LOG_BOUNDS[0][0], LOG_BOUNDS[1][0]])
    hi = np.log([LOG_BOUNDS[0][1], LOG_BOUNDS[1][1]])
    z0 = np.clip(np.log(x0[1:3]), lo + 1e-9, hi - 1e-9)
    res = least_squares(lambda z: _project(v, mu, math.exp(z[0]), math.exp(z[1]), eps)[1], z0, bounds=(lo, hi),
                        method="trf", x_scale=1.0, diff_step=1e-7, xtol=1e-12, ftol=1e-12, gtol=1e-12,
                        max_nfev=400)
    th, r = _project(v, mu, math.exp(res.x[0]), math.exp(res.x[1]), eps)
    n = v.size
    s2 = float(r @ r) / max(n - 5, 1)
    tau = integrated_autocorrelation(r)
    J = np.empty((n, 5))
    for i in range(5):
        h = 1e-6 * max(abs(th[i]), 1e-6)
        d = np.zeros(5)
        d[i] = h
        J[:, i] = (law(v, th + d, eps) - law(v, th - d, eps)) / (2 * h)
    try:
        cov = np.linalg.inv(J.T @ J) * s2 * tau
        se = np.sqrt(np.clip(np.diag(cov), 0, None))
        corr = cov / np.outer(se, se)
    except np.linalg.LinAlgError:
        se = np.full(5, np.nan)
        corr = np.full((5, 5), np.nan)
    ss_tot = float(np.sum((mu - mu.mean()) ** 2))
    r2 = 1.0 - float(r @ r) / ss_tot if ss_tot > 0 else float("nan")
    at_bound = bool(np.any(np.isclose(res.x, lo, atol=1e-6) | np.isclose(res.x, hi, atol=1e-6)))
    coefs = {}
    for k, val, s in zip(PARAMS, th, se):
        ok = bool(np.isfinite(s) and abs(val) > 0 and s / abs(val) < REL_SE_IDENTIFIED)
        coefs[k] = Coef(value=float(val), se=float(s) if np.isfinite(s) else None, unit=UNITS[k], identified=ok)
    return DrumLawFit(coefficients=coefs, R2=r2, R=math.sqrt(max(r2, 0.0)) if np.isfinite(r2) else float("nan"),
                  rms=float(np.sqrt(np.mean(r ** 2))), n=int(n), n_eff=n / tau,
                  v_range_m_per_s=(float(v.min()), float(v.max())), converged=bool(res.success) and not at_bound,
                  message=str(res.message) + (" (B or C at its bound)" if at_bound else ""),
                  correlation={a: {b: float(corr[i, j]) for j, b in enumerate(PARAMS) if j != i}
                               for i, a in enumerate(PARAMS)})
