"""Stage 1 of the law identification: equation error, the paper's own least squares on f(w) points.

Why it is kept although biased: it is the paper's method, it needs no simulation, and
it gives the start values of the output-error stage (output_error.py), which is
where the reported law comes from.

Per slipping sample the friction f = x'' + d x' + (K x)_i / F0 from centred cubic
Savitzky-Golay derivatives (+-3 samples) of the measured positions, classified as
accelerating (|w| growing) or decelerating relative motion by the sign of w w'.
Measured on simulated records against the simulator's true friction
(docs/analyses-000.md): within 7 samples of a stick-slip transition or a branch
switch (where the friction jumps by 2 amp f_k) the smoothing filter straddles the
jump, error rms 0.08-0.14 and up to 0.6 (a third of the law); beyond, noise only
(rms 0.03, mean < 0.01). Those samples are left out ("kept" points are the figure's
f(w) points). Fitted with the whole law (break-away drop from the force needed at the
detected stick end), this still misses the branch amplitude by 5 % (0.106 for 0.1, 5
of its own std), alpha_drop by 6-8 % and k_fall by 5 %: the drop and the switch live
inside the excluded samples (docs/decisions/0002-output-error-by-multiple-shooting.md).

Also here, shared by every fit of the paper: the parameter names (LAW) and the
least-squares result (LsqFit) with its standard deviations from the Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from daq.physics import beltndof
from daq.physics.friction import f_pwl_piece
from daq.signals import savgol

from .preparation import BeltRun, Stick


def chain_force_dimless(xd: np.ndarray) -> np.ndarray:
    """(K x)_i / F0 of the chain for dimensionless positions xd (n, N): beltndof's own chain_force, row by row."""
    n = xd.shape[0]
    zero = np.zeros(xd.shape[1])
    out = np.empty_like(xd)
    for i in range(n):
        left = xd[i - 1] if i > 0 else zero
        right = xd[i + 1] if i < n - 1 else zero
        out[i] = beltndof.chain_force(left, xd[i], right, 1.0, i < n - 1)
    return out


@dataclass
class FrictionPoints:
    """Friction samples of slipping masses from the equation of motion (equation error), dimensionless."""

    w: np.ndarray  # relative velocity
    f: np.ndarray  # friction (same sign convention as w: f(w) odd)
    growing: np.ndarray  # +1 while |w| grows (accelerating relative motion), -1 while it shrinks
    s: np.ndarray  # dimensionless belt speed at the sample
    mass: np.ndarray
    run: np.ndarray  # index of the recording
    t: np.ndarray  # time [s]
    kept: np.ndarray  # bool: not near a transition (used in the fit)
    fs_ep: np.ndarray  # force needed at the detected end of the preceding stick (~ its break-away level; 0: none)


def friction_points(run: BeltRun, sticks: list[list[Stick]], run_index: int = 0, half: int = 3,
                    margin: int | None = None, masses: list[int] | None = None) -> FrictionPoints:
    """The paper's f(w) points: f = x'' + d x' + (K x)_i / F0 while slipping (all dimensionless).

    ``margin`` samples around every detected stick/slip transition and every branch switch
    (sign change of w w') are marked not kept: there the smoothing filter straddles a jump
    of the friction and its estimate is biased (docs/analyses-000.md has the measured size).
    """
    mech = run.mech
    margin = 2 * half + 1 if margin is None else margin
    dtd = 1.0 / run.rate / mech.tau0  # dimensionless sample interval
    xd = run.x / mech.x_unit
    vel = savgol(xd, half, 1, dtd)
    acc = savgol(xd, half, 2, dtd)
    chain = chain_force_dimless(savgol(xd, half, 0))
    s = run.vb / mech.v_unit
    ds = np.gradient(s, dtd)
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("w", "f", "growing", "s", "mass", "t", "kept", "fs_ep")}
    n_samples = run.t.size
    for i in (masses if masses is not None else range(run.n)):
        f = acc[i] + mech.d * vel[i] + chain[i]
        w = s - vel[i]
        wdot = ds - acc[i]
        slip = np.ones(n_samples, bool)
        near = np.zeros(n_samples, bool)
        for st in sticks[i]:
            slip[st.start:st.end + 1] = False
            for j in (st.start, st.end):
                near[max(0, j - margin):j + margin + 1] = True
        grow = np.where(w * wdot > 0, 1.0, -1.0)
        sw = np.flatnonzero(slip[1:] & slip[:-1] & (grow[1:] != grow[:-1]))
        for j in sw:
            near[max(0, j - margin):j + margin + 2] = True
        near[:margin] = True
        near[-margin:] = True
        fs_ep = np.zeros(n_samples)
        need = chain[i] + mech.d * s
        for st in sticks[i]:
            if not st.open_end:
                fs_ep[st.end + 1:] = abs(need[max(st.end - 1, st.start)])
        idx = np.flatnonzero(slip)
        out["w"].append(w[idx])
        out["f"].append(f[idx])
        out["growing"].append(grow[idx])
        out["s"].append(s[idx])
        out["mass"].append(np.full(idx.size, i))
        out["t"].append(run.t[idx])
        out["kept"].append(~near[idx])
        out["fs_ep"].append(fs_ep[idx])
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in out.items()}
    return FrictionPoints(cat["w"], cat["f"], cat["growing"], cat["s"], cat["mass"].astype(int),
                          np.full(cat["w"].size, run_index), cat["t"], cat["kept"].astype(bool), cat["fs_ep"])


def merge_points(pts: list[FrictionPoints]) -> FrictionPoints:
    return FrictionPoints(*(np.concatenate([getattr(p, k) for p in pts]) for k in
                            ("w", "f", "growing", "s", "mass", "run", "t", "kept", "fs_ep")))


KINETIC = ("f_k0", "k_fall", "w_min", "k_rise", "amp")  # kinetic characteristic and branch amplitude
LAW = ("alpha_drop",) + KINETIC  # what the output-error stage shares between all slip windows


@dataclass
class LsqFit:
    names: tuple[str, ...]
    values: np.ndarray
    std: np.ndarray
    rms: float
    n: int
    extra: dict[str, object] = field(default_factory=dict)

    def as_dict(self) -> dict[str, dict[str, float]]:
        return {k: {"value": float(v), "std": float(s)} for k, v, s in zip(self.names, self.values, self.std)}


def std_from_jac(jac: np.ndarray, resid: np.ndarray, n_par: int) -> np.ndarray:
    """Parameter standard deviations: inverse of J^T J scaled by the residual variance."""
    jac = jac.toarray() if hasattr(jac, "toarray") else np.asarray(jac)
    dof = max(resid.size - jac.shape[1], 1)
    s2 = float(resid @ resid) / dof
    jtj = jac.T @ jac
    try:
        cov = np.linalg.pinv(jtj) * s2
    except np.linalg.LinAlgError:
        return np.full(n_par, np.nan)
    return np.sqrt(np.clip(np.diag(cov)[:n_par], 0.0, None))


def pwl_law(u: np.ndarray, growing: np.ndarray, f_s: np.ndarray, alpha_drop: float, f_k0: float, k_fall: float,
            w_min: float, k_rise: float, amp: float) -> np.ndarray:
    """|f| of paper 000's law on both branches, with the break-away drop from f_s: daq.physics.friction.f_pwl_piece."""

    return f_pwl_piece(np.asarray(u, dtype=float), np.asarray(growing, dtype=float), np.asarray(f_s, dtype=float),
                       alpha_drop, f_k0, k_fall, w_min, k_rise, amp)


def fit_kinetic_points(pts: FrictionPoints) -> LsqFit:
    """Least squares of the law on the kept f(w) points (the paper's method, equation error).

    f on the growing branch is max(f_s - alpha_drop |w|, (1 + amp) kinetic line), with
    f_s the force needed at the detected end of the preceding stick, on the shrinking
    branch (1 - amp) times the kinetic line; the kinetic line falls with k_fall up to
    w_min and rises with k_rise beyond. The drop is in the model because with a slow
    rig (tau0 = 0.1 s) a tenth of the kept points still sit on it. Soft-L1 loss; w_min
    is started from a grid. Returns LAW = (alpha_drop, f_k0, ...).
    """

    k = pts.kept & (np.abs(pts.w) > 1e-6)
    u = np.abs(pts.w[k])
    g = pts.growing[k]
    fs = pts.fs_ep[k]
    f = pts.f[k] * np.sign(pts.w[k])
    if u.size < 20:
        raise ValueError("fewer than 20 usable slip samples")

    def resid(th):
        return pwl_law(u, g, fs, *th) - f

    lo = np.array([0.2, 0.01, -5.0, 1e-3, -5.0, -0.5])
    hi = np.array([50.0, 10.0, 5.0, max(10.0, 2 * u.max()), 5.0, 0.5])
    best = None
    for wm in np.quantile(u, [0.2, 0.35, 0.5, 0.65, 0.8]):
        for ad in (2.0, 8.0):
            th0 = np.array([ad, float(np.median(f[u < wm])) if np.any(u < wm) else 1.0, 0.1, wm, 0.05, 0.0])
            th0 = np.clip(th0, lo + 1e-9, hi - 1e-9)
            r = least_squares(resid, th0, bounds=(lo, hi), loss="soft_l1", f_scale=0.05, x_scale="jac")
            if best is None or r.cost < best.cost:
                best = r
    res = resid(best.x)
    return LsqFit(LAW, best.x, std_from_jac(best.jac, res, 6), float(np.sqrt(np.mean(res**2))), int(u.size),
                  {"w_max": float(u.max())})
