"""Effective friction of paper 001's eq. (10) from a recording, and a fit of friction law (7).

Why the rig's own equations: the friction force comes from the compiled brake-2dof model with friction
off (daq.estimation.rigmodels.BrakeModel, no second copy of eqs. 5-6): F = m (a_without_friction - x1''),
N from eq. (6) with the measured x1, y1 = r phi and y1', mu = F/N, and eq. (10)'s left-hand side
mu_eff = F/(m g).

Why the fit is restricted: law (7)'s mu0 and gamma are fitted by least squares on slip samples with
|V_rel| >= 6/alpha (there tanh(alpha V) = 1 and beta/cosh(alpha V) < 0.4 %, so alpha and beta do not
enter) and farther than the *measured* bias distance from every stick-slip transition. alpha and beta are
held at the rig config's values: they shape |V_rel| < 25 mm/s only, i.e. the creep phase and the
transitions, and there the differentiated velocity's error (~1e-3 m/s rms, ringing after each re-stick)
is as large as V_rel itself; a creep-phase fit of (alpha, beta) on simulated data missed the truth by a
factor >2 with a claimed uncertainty of 0.3 % (recorded in docs/analyses-001.md), so we do not claim them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from pydantic import Field
from scipy.optimize import least_squares

from daq.config import RigConfig
from daq.errors import InputError
from daq.estimation.regime import classify, switch_distance, switch_positions
from daq.estimation.rigmodels import BrakeModel
from daq.physics import brake2dof
from daq.physics.friction import mu_brake
from daq.sim.effectset import effect_vector
from daq.sim.rigs import make_sim
from daq.strict import Closed

from .kinematics import VB_WINDOW_S, derivatives, differentiator_name, sample_rate, smooth_line

BIAS_TOL = 0.005  # |median residual| in mu allowed in a distance bin (1 % of mu0 ~ 0.5)
BIAS_RMS_FACTOR = 1.5  # and its rms at most this times the far-field residual rms


@dataclass
class FrictionSeries:
    """Per-sample inverse dynamics of a brake-2dof recording (arrays of one length)."""

    t: np.ndarray
    x1: np.ndarray
    x1d: np.ndarray
    y1: np.ndarray
    y1d: np.ndarray
    vb: np.ndarray
    v_rel: np.ndarray  # x1' - vb [m/s]
    F: np.ndarray  # friction force on the block [N], eq. (5a) convention (+ opposes +x1 motion rel. to belt)
    N: np.ndarray  # normal load, eq. (6) [N]
    mu: np.ndarray  # F / N: law (7)'s coefficient
    mu_eff: np.ndarray  # F / (m g): eq. (10)'s left-hand side
    slip: np.ndarray  # 1 = slip, 0 = stick/creep (|V_rel| against v_stick with hysteresis)
    dist_s: np.ndarray  # time to the nearest stick-slip transition [s]
    n_switches: int
    mg: float


def brake_params(cfg: RigConfig) -> np.ndarray:
    """The rig's compiled parameter vector (as the simulator builds it)."""

    return make_sim(cfg, effect_vector(cfg)[0]).p.copy()


def friction_series(cfg: RigConfig, t: np.ndarray, x1: np.ndarray, phi: np.ndarray, vb: np.ndarray,
                    window_s: float = 0.02, hysteresis: float = 0.3) -> FrictionSeries:
    """Friction force, normal load, mu and mu_eff from measured x1, phi, vb via the rig's own equations."""

    model = BrakeModel(cfg)
    r = float(model.p[brake2dof.P.r])
    xs, xd, xdd = derivatives(t, x1, window_s)
    ps, pd, _ = derivatives(t, phi, window_s)
    vbs = smooth_line(t, vb, VB_WINDOW_S)
    est = model.infer({"x1": xs, "x1'": xd, "x1''": xdd, "phi": ps, "phi'": pd, "vb": vbs,
                       "vb'": np.gradient(vbs, t)})
    slip = classify(est.v_rel, model.v_stick, hysteresis, -1)
    idx = np.arange(t.size)
    sw = switch_positions(slip, idx, -1)
    rate = sample_rate(t)
    dist = switch_distance(idx, sw) / rate
    mg = float(model.p[brake2dof.P.m] * model.p[brake2dof.P.g])
    return FrictionSeries(t, xs, xd, r * ps, r * pd, vbs, est.v_rel, est.F, est.N, est.mu, est.F / mg, slip, dist,
                          int(sw.size), mg)


def kappas(p: np.ndarray) -> tuple[float, float]:
    """kappa1, kappa2 of eq. (10), read back from brake2dof.mu_effective (mu_eff = (1+k1) mu / (1+k2 mu))."""
    a = float(brake2dof.mu_effective(1e-9, p)) / 1e-9  # 1 + kappa1
    b = float(brake2dof.mu_effective(1.0, p))  # (1 + k1) / (1 + k2)
    return a - 1.0, a / b - 1.0


class ParamEstimate(Closed):
    """A fitted parameter with its standard error (Jacobian of the least-squares problem)."""

    value: float
    std: float


class BrakeLawFit(Closed):
    """Least-squares fit of the brake's friction law (7) (directly, or through eq. (10)) on the chosen samples."""

    target: str = Field(description="what was fitted: 'mu = F/N' (law 7) or 'mu_eff = F/(m g)' (eq. 10 of law 7)")
    params: dict[str, ParamEstimate]
    held: dict[str, float] = Field(description="law parameters held at the rig config's values")
    n_points: int
    rms: float = Field(description="residual rms, in the target's units")
    success: bool


def _fit(model: Callable[[np.ndarray, float, float], np.ndarray], v: np.ndarray, y: np.ndarray, x0: list[float],
         target: str, held: dict[str, float], source: str = "(recording)") -> BrakeLawFit:
    """(mu0, gamma) of ``model(v, mu0, gamma)`` by plain least squares; standard errors from J^T J."""
    if v.size < 10:
        raise InputError(source, "x1", f"only {v.size} settled slip samples (|V_rel| >= 6/alpha) to fit the "
                                       "friction law: no stick-slip with fast enough slips in this run")

    def resid(th: np.ndarray) -> np.ndarray:
        return model(v, th[0], th[1]) - y

    sol = least_squares(resid, np.array(x0, dtype=float), bounds=([0.0, 0.0], [5.0, 100.0]), x_scale="jac")
    r = sol.fun
    s2 = float(r @ r) / max(1, v.size - 2)
    cov = np.linalg.pinv(sol.jac.T @ sol.jac) * s2
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return BrakeLawFit(target=target, params={"mu0": ParamEstimate(value=float(sol.x[0]), std=float(std[0])),
                                              "gamma": ParamEstimate(value=float(sol.x[1]), std=float(std[1]))},
                       held=held, n_points=int(v.size), rms=float(np.sqrt(np.mean(r * r))),
                       success=bool(sol.success))


class BiasBin(Closed):
    """Residual of mu against the preliminary fit, for slip samples at a given distance from a transition."""

    d_from_s: float
    d_to_s: float
    n: int
    median: float
    rms: float


class FrictionResult(Closed):
    """Eq. (10) effective friction and the fit of law (7), with the measured transition bias."""

    diff_window_s: float
    differentiator: str
    v_stick_m_per_s: float
    v_min_m_per_s: float = Field(description="slip samples used have |V_rel| >= 6/alpha")
    n_transitions: int
    bias_profile: list[BiasBin]
    bias_tolerance: float
    exclusion_s: float = Field(description="chosen: slip samples closer than this to a transition are not fitted")
    fit: BrakeLawFit = Field(description="law (7) fitted to mu = F/N with N from eq. (6): the primary result")
    fit_eq10: BrakeLawFit = Field(description="law (7) through eq. (10) fitted to F/(m g): quasi-static, biased")
    kappa1: float
    kappa2: float
    mu_eff_range: tuple[float, float] = Field(description="1st and 99th percentile of F/(m g)")


def choose_exclusion(profile: list[BiasBin], far_rms: float, fallback: float, min_n: int = 50) -> float:
    """Smallest bin edge from which every bin's |median| <= BIAS_TOL and rms <= BIAS_RMS_FACTOR far_rms.

    A bin's median carries sampling noise ~1.25 rms/sqrt(n): three of those are allowed on top of
    BIAS_TOL, and bins with fewer than min_n samples are not judged (a handful of far samples from
    the start-up must not push the exclusion out to where nothing is left to fit).
    """
    good = [b.n < min_n or (abs(b.median) <= BIAS_TOL + 3.75 * b.rms / math.sqrt(b.n)
                            and b.rms <= BIAS_RMS_FACTOR * far_rms) for b in profile]
    for i in range(len(profile)):
        if all(good[i:]):
            return profile[i].d_from_s
    return fallback


def identify_friction(fs: FrictionSeries, p: np.ndarray, window_s: float, alpha: float, beta: float,
                      v_stick: float, source: str = "(recording)") -> FrictionResult:
    """Fit law (7)'s mu0, gamma on slip samples away from transitions; the distance is measured, not assumed.

    1. A preliminary fit uses a conservative exclusion d0 = max(window, 3 samples).
    2. The residual of every slip sample against it, binned by distance to the nearest transition,
       is the bias profile (the twice-differentiated displacement is biased where the motion kinks).
    3. The exclusion is the smallest distance beyond which every bin is unbiased (choose_exclusion).
    4. The final fit uses the slip samples beyond it; the same samples fit eq. (10) of law (7) to F/(m g).
    """
    rate = sample_rate(fs.t)
    v_min = 6.0 / alpha
    base = (fs.slip == 1) & (np.abs(fs.v_rel) >= v_min) & np.isfinite(fs.mu) & np.isfinite(fs.v_rel)
    held = {"alpha": float(alpha), "beta": float(beta)}

    def law(v, mu0, gamma):
        return mu_brake(v, mu0, gamma, alpha, beta)

    def law_eff(v, mu0, gamma):
        return brake2dof.mu_effective(mu_brake(v, mu0, gamma, alpha, beta), p)

    d0 = max(window_s, 3.0 / rate)
    sel0 = base & (fs.dist_s >= d0)
    x0 = [float(np.median(np.abs(fs.mu[sel0]))) if sel0.any() else 0.5, 1.0]  # data-driven start, not the config
    pre = _fit(law, fs.v_rel[sel0], fs.mu[sel0], x0, "mu = F/N", held, source)
    resid = fs.mu - law(fs.v_rel, pre.params["mu0"].value, pre.params["gamma"].value)
    step = max(1.0 / rate, window_s / 4.0)
    edges = list(np.arange(0.0, 3.0 * d0 + 0.5 * step, step)) + [np.inf]
    profile = []
    for a, b in zip(edges[:-1], edges[1:]):
        m = base & (fs.dist_s >= a) & (fs.dist_s < b)
        rr = resid[m]
        profile.append(BiasBin(d_from_s=float(a), d_to_s=float(b) if np.isfinite(b) else float("inf"), n=int(m.sum()),
                               median=float(np.median(rr)) if rr.size else 0.0,
                               rms=float(np.sqrt(np.mean(rr * rr))) if rr.size else 0.0))
    d_star = choose_exclusion(profile, pre.rms, d0)
    sel = base & (fs.dist_s >= d_star)
    fit = _fit(law, fs.v_rel[sel], fs.mu[sel], [pre.params["mu0"].value, pre.params["gamma"].value], "mu = F/N",
               held, source)
    fit10 = _fit(law_eff, fs.v_rel[sel], fs.mu_eff[sel], [fit.params["mu0"].value, fit.params["gamma"].value],
                 "mu_eff = F/(m g)", held, source)
    k1, k2 = kappas(p)
    lo, hi = np.nanpercentile(fs.mu_eff, [1, 99])
    return FrictionResult(diff_window_s=window_s, differentiator=differentiator_name(fs.t, window_s),
                          v_stick_m_per_s=v_stick, v_min_m_per_s=v_min, n_transitions=fs.n_switches,
                          bias_profile=profile, bias_tolerance=BIAS_TOL, exclusion_s=float(d_star), fit=fit,
                          fit_eq10=fit10, kappa1=k1, kappa2=k2, mu_eff_range=(float(lo), float(hi)))
