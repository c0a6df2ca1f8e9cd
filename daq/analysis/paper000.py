"""Paper 000 (Bogacz & Ryczek, belt-ndof): identification of the friction law from trajectories.

Why a module of its own: the paper identifies its friction model from measured
trajectories of 1-3 masses on a belt (its Figs. 8-11): the kinetic characteristic
f(w) on an accelerating and a decelerating branch by least squares, the static
limit f_s against stick time t_s and force rate delta, and periodicity from a
Poincaré section. Here each step is a pure function over numpy arrays; the CLI
(daq/cli/paper000.py) does the I/O.

Units: everything the law sees is dimensionless as in the paper's eq. (2) and our
rig config: x = K X / F0, t = tau / tau0 with tau0 = sqrt(M/K), w = (S - X') / v_u with
v_u = F0 / sqrt(K M), f = F / F0. The stick-time and force-rate effects keep the
catalog's units (tau [s], Delta and q0 [N/s]) so that results compare with
``daq sim --effect stick-time:tau=...`` directly.

Method (``belt_law``). Two stages:

1. *Equation error* (the paper's least squares): per slipping sample the
   friction f = x'' + d x' + (K x)_i / F0 from centred cubic Savitzky-Golay
   derivatives (+-3 samples) of the measured positions, classified as accelerating
   (|w| growing) or decelerating relative motion by the sign of w w'. Measured on
   simulated records against the simulator's true friction (docs/analyses-000.md):
   within 7 samples of a stick-slip transition or a branch switch (where the
   friction jumps by 2 amp f_k) the smoothing filter straddles the jump, error rms
   0.08-0.14 and up to 0.6 (a third of the law); beyond, noise only (rms 0.03, mean
   < 0.01). Those samples are left out ("kept" points are the figure's f(w)
   points). Fitted with the whole law (break-away drop from the force needed at the
   detected stick end), this still misses the branch amplitude by 5 % (0.106 for
   0.1, 5 of its own std), alpha_drop by 6-8 % and k_fall by 5 %: the drop and the
   switch live inside the excluded samples. It gives the start values of stage 2.
2. *Output error over slip windows* (what the parameters come from): each slip
   episode of a mass is simulated with the rig's own hybrid integrator
   (daq.physics.beltndof.simulate; physics in one place) from before its
   break-away, where the mass moves with the belt and its state is known from the
   stick line, to just after it sticks again, and every mass's simulated position
   is compared with the measured one (see SlipWindow). Shared: alpha_drop, f_k0,
   k_fall, w_min, k_rise, amp; per window: the break-away level f_s at which the
   simulated stick ends and the start velocities of neighbours that slip at the
   window's start. Steps: f_s by a scan of the levels the data pass through,
   alpha_drop from a grid, then the kinetic part, then everything (scipy
   least_squares, block-sparse Jacobian, soft-L1 loss); a second pass places every
   window at the fitted law, and if a window that fits worse than 3x the median
   (a segmentation error) was in the fit, refits on the best-fitting windows. The
   break-away levels of all good windows, with their stick times and the load rate
   at the simulated break-away, are the data of the static fit (``fit_static``).

Damping d is a rig property, not part of the friction law: it comes from the rig
config (``[seed_effects] viscous-damping.d``) unless given. It matters: d x' shifts
f by d s.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict
from scipy.optimize import least_squares
from scipy.signal import savgol_coeffs, savgol_filter
from scipy.sparse import lil_matrix

from daq.config import BeltRig, config_for_recording
from daq.errors import InputError
from daq.io.interchange import Recording
from daq.physics import beltndof
from daq.physics.effects import TAIL, E, static_factor
from daq.physics.friction import f_pwl_piece
from daq.sim.effectset import environment_vector
from daq.sim.rigs import BeltSim

RIG = "belt-ndof"


# ----------------------------------------------------------------------------- data


class Mechanics(BaseModel):
    """What the analyses need to know about the rig: mechanics, damping, units of the scaling (2)."""

    model_config = ConfigDict(frozen=True)
    n_masses: int
    mass_kg: float
    stiffness_N_per_m: float
    normal_force_N: float
    d: float  # dimensionless viscous damping of eq. (3)
    q0_N_per_s: float  # force-rate reference rate (fixed in the static fit, as in daq.models)
    config_source: str

    @property
    def tau0(self) -> float:
        """Time unit sqrt(M/K) [s]."""
        return math.sqrt(self.mass_kg / self.stiffness_N_per_m)

    @property
    def x_unit(self) -> float:
        """Length unit F0/K [m]."""
        return self.normal_force_N / self.stiffness_N_per_m

    @property
    def v_unit(self) -> float:
        """Velocity unit F0/sqrt(K M) [m/s]."""
        return self.normal_force_N / math.sqrt(self.stiffness_N_per_m * self.mass_kg)


@dataclass
class BeltRun:
    """One belt-ndof recording prepared for the analyses (SI units; dimensionless helpers below)."""

    source: str
    cfg: BeltRig
    mech: Mechanics
    t: np.ndarray
    rate: float
    x: np.ndarray  # (n_masses, N) positions [m]
    vb: np.ndarray  # belt speed driving the analysis [m/s]
    vb_source: str
    sigma_x: np.ndarray  # position noise per mass [m]
    extra: dict[str, object] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return self.x.shape[0]

    @property
    def belt_travel(self) -> np.ndarray:
        """Belt travel [m] from the start (trapezoidal integral of vb)."""
        return np.concatenate([[0.0], np.cumsum(0.5 * (self.vb[1:] + self.vb[:-1]) * np.diff(self.t))])


def sg(x: np.ndarray, half: int, deriv: int = 0, dt: float = 1.0, degree: int = 3) -> np.ndarray:
    """Centred Savitzky-Golay smoothing/derivative over +-half samples (mode 'interp' at the ends)."""
    n = 2 * half + 1
    return savgol_filter(x, n, min(degree, n - 1), deriv=deriv, delta=dt, mode="interp", axis=-1)


def noise_sigma(x: np.ndarray) -> float:
    """White-noise level from third differences (MAD; robust to the sparse stick-slip kinks)."""
    d3 = np.diff(x, 3)
    mad = np.median(np.abs(d3 - np.median(d3)))
    return float(1.4826 * mad / math.sqrt(20.0))


def _config_for(rec: Recording, source: str, rig: str | None) -> BeltRig:
    """The rig config: --rig (id or TOML path), else the one stored in the recording, else the built-in."""
    return config_for_recording(rec.meta.get("rig_config"), source, rig, RIG,  # type: ignore[return-value]
                                "paper 000 analyses need")


def prepare(rec: Recording, source: str, rig: str | None = None, damping: float | None = None,
            min_samples: int = 200) -> BeltRun:
    """Check a recording and put it in the form the analyses need; bad input names the file and field."""
    if rec.rig not in (None, RIG):
        raise InputError(source, "rig", f"paper 000 analyses need a {RIG} recording, this is {rec.rig}")
    cfg = _config_for(rec, source, rig)
    masses = [f"x{i}" for i in (1, 2, 3) if f"x{i}" in rec.channels]
    if not masses or masses[0] != "x1" or masses != [f"x{i}" for i in range(1, len(masses) + 1)]:
        raise InputError(source, "x1", "missing column (need x1[, x2[, x3]] mass positions [m])")
    if "vb" not in rec.channels and "vb_set" not in rec.channels:
        raise InputError(source, "vb", "missing column (belt speed [m/s])")
    t = np.asarray(rec.t, dtype=float)
    if t.size < min_samples:
        raise InputError(source, "t", f"{t.size} samples: too few (need at least {min_samples})")
    dt = np.diff(t)
    rate = 1.0 / float(np.median(dt))
    if np.max(np.abs(dt * rate - 1.0)) > 0.01:
        raise InputError(source, "t", "samples must be evenly spaced (resample first)")
    for name in masses + [c for c in ("vb", "vb_set") if c in rec.channels]:
        if not np.all(np.isfinite(rec.channels[name])):
            raise InputError(source, name, "contains NaN or infinite values")
    x = np.vstack([np.asarray(rec.channels[m], dtype=float) for m in masses])
    if "vb_set" in rec.channels:
        vb, vsrc = np.asarray(rec.channels["vb_set"], dtype=float), "vb_set (command)"
    else:  # the tachometer's noise removed over +-0.05 s; belt programmes change slower than that
        vb, vsrc = sg(np.asarray(rec.channels["vb"], dtype=float), max(3, int(0.05 * rate)), degree=2), "vb (smoothed)"
    if not np.any(vb > 0):
        raise InputError(source, "vb", "the belt never moves: nothing to identify")
    mech_cfg = cfg.mechanics
    d = damping if damping is not None else float(
        (cfg.seed_effects.get("viscous-damping") or {}).get("d", 0.0))
    fr = cfg.seed_effects.get("force-rate") or cfg.effects.get("force-rate") or {}
    mech = Mechanics(n_masses=len(masses), mass_kg=mech_cfg.mass_kg, stiffness_N_per_m=mech_cfg.stiffness_N_per_m,
                     normal_force_N=mech_cfg.normal_force_N, d=d, q0_N_per_s=float(fr.get("q0", 2.0)),
                     config_source=rig or ("recording" if "rig_config" in rec.meta else RIG))
    sig = np.array([noise_sigma(xi) for xi in x])
    for i, m in enumerate(masses):
        ch = cfg.channels.get(m)
        if ch is not None and (ch.noise_std > 0 or ch.lsb > 0):  # the third-difference estimate is an upper bound
            sig[i] = min(sig[i], math.hypot(ch.noise_std, ch.lsb / math.sqrt(12.0))) if sig[i] > 0 else \
                math.hypot(ch.noise_std, ch.lsb / math.sqrt(12.0))
        sig[i] = max(sig[i], 1e-9)
    return BeltRun(source, cfg, mech, t, rate, x, vb, vsrc, sig)


# ----------------------------------------------------------------------------- stick / slip from data


def _sg_gain(half: int, deriv: int, degree: int = 3) -> float:
    """Noise gain of a centred Savitzky-Golay filter (per unit white input noise, per sample^deriv)."""

    c = savgol_coeffs(2 * half + 1, min(degree, 2 * half), deriv=deriv)
    return float(np.sqrt(np.sum(c * c)))


@dataclass
class Stick:
    """One stick episode of one mass: samples [start, end] (inclusive) move with the belt."""

    mass: int
    start: int  # first stuck sample
    end: int  # last stuck sample (the break-away follows)
    open_start: bool  # the stick began before the record (its stick time is unknown)
    open_end: bool  # the record ends stuck (no break-away)


def find_sticks(run: BeltRun, mass: int, half: int = 3, k_sigma: float = 4.0, min_len: int = 6) -> list[Stick]:
    """Stick episodes of one mass: where its velocity equals the belt's within the velocity noise.

    Velocity from a centred cubic Savitzky-Golay derivative over +-half samples; a
    sample is stuck when |x' - vb| < k_sigma * (its noise) + 1 % of the belt speed.
    The detected ends sit within ~half samples of the true transitions (the stage
    that needs the exact times, the output-error fit, finds them itself).
    """
    dt = 1.0 / run.rate
    v = sg(run.x[mass], half, 1, dt)
    sig_v = run.sigma_x[mass] * _sg_gain(half, 1) / dt
    stuck = np.abs(v - run.vb) < k_sigma * sig_v + 0.01 * np.abs(run.vb)
    edges = np.flatnonzero(np.diff(stuck.astype(np.int8)))
    starts = list(edges[stuck[edges + 1]] + 1)
    ends = list(edges[~stuck[edges + 1]])
    if stuck[0]:
        starts.insert(0, 0)
    if stuck[-1]:
        ends.append(stuck.size - 1)
    out = []
    travel = run.belt_travel
    for a, b in zip(starts, ends):
        if b - a + 1 < min_len:
            continue
        # a mass that only grazes the belt speed drifts against the belt: while truly stuck,
        # x - belt travel is constant within the noise (slope test over the inner samples)
        ia, ib = a + 1, b
        tt = run.t[ia:ib]
        if tt.size < 4:
            continue
        r = run.x[mass, ia:ib] - travel[ia:ib]
        slope = np.polyfit(tt - tt.mean(), r, 1)[0]
        se = run.sigma_x[mass] / math.sqrt(np.sum((tt - tt.mean()) ** 2))
        if abs(slope) > 5.0 * se:
            continue
        out.append(Stick(mass, int(a), int(b), a == 0, b >= stuck.size - 1 - half))
    return out


# ----------------------------------------------------------------------------- stage 1: equation error


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
    vel = sg(xd, half, 1, dtd)
    acc = sg(xd, half, 2, dtd)
    chain = chain_force_dimless(sg(xd, half, 0))
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


def _std_from_jac(jac: np.ndarray, resid: np.ndarray, n_par: int) -> np.ndarray:
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
    return LsqFit(LAW, best.x, _std_from_jac(best.jac, res, 6), float(np.sqrt(np.mean(res**2))), int(u.size),
                  {"w_max": float(u.max())})


# ----------------------------------------------------------------------------- stage 2: output error


F_BIG = 1e3  # static limit of every mass but the window's (see SlipWindow)
ST_TAU_FAR = 1e6  # [s] stick-time constant of the windows: the limit stays where it starts within a window
CLOCK_FAR = 1e12  # [s] a stick clock this far in the past (future) reads t_s/tau = 1e6 (0)
PRE_BREAK = 8  # window starts at least this many samples (and 0.6 tau0) before the detected end of the stick
POST_STICK = 4  # ... and ends this many samples after the detected start of the next stick
OTHER_BREAK_MARGIN = 8  # a window is cut this many samples before another mass's detected break
MIN_STICK_SAMPLES = 10  # shorter sticks are not used: a mass grazing the belt speed can pass the stick test


@dataclass
class SlipWindow:
    """One slip episode of one mass, simulated from a stuck start to just after it sticks again.

    Start state: the window's mass is stuck, so its velocity is the belt's and its
    position lies on the stick line (x - belt travel = const, averaged over the clean
    part of the stick: far more precise than one sample). Other masses: on their
    stick line if stuck, else Savitzky-Golay position, and a velocity that is a free
    (nuisance) parameter of the window started from the Savitzky-Golay estimate; all
    masses' positions are compared with the data.
    The simulator's static limit is f_s0 (1 + gain (1 - exp(-t_s/tau))) with t_s the
    time since the mass stuck. We set f_s0 = F_BIG, tau = ST_TAU_FAR and gain =
    f_s/F_BIG - 1 (f_s: the episode's break-away level, the nuisance), and put this
    mass's stick clock far in the past and the others' in the future: this mass breaks
    exactly when the force it needs reaches f_s, while every other mass keeps a limit
    of ~F_BIG, never breaks inside the window (the window is cut before another mass
    breaks in the data) and can always stick again (no zero-time stick/slip chatter).
    """

    run: int
    mass: int
    stick: Stick
    j0: int
    j1: int
    s0: np.ndarray  # full state at j0 (SI)
    modes: np.ndarray  # STICK/SLIP per mass at j0
    slip_dir: np.ndarray
    fs_guess: float
    fs_lo: float  # bounds of the break-away level (see slip_windows)
    fs_hi: float
    need_path: np.ndarray  # force [F0] the mass needs to stay stuck, from the data, samples j0..stick end + 2
    valid: bool  # False when the scan puts the break at the window's first sample (the window starts too late)
    x_meas: np.ndarray  # (n, L) measured positions of every mass, samples j0..j1 [m]
    sigma: np.ndarray  # (n,) their noise [m]
    free_v: np.ndarray  # masses slipping at j0 whose start velocity is a nuisance parameter
    v_guess: np.ndarray  # their start velocities [m/s] (updated by the fits)
    rt: np.ndarray
    rv: np.ndarray
    delta_mean: float = float("nan")  # mean load rate over the stick [N/s]


def _stick_line(run: BeltRun, st: Stick, travel: np.ndarray, trim_end: int) -> float:
    """x - belt travel during a stick (constant while stuck): mean over the stick's clean samples."""
    a = st.start + 1
    b = max(a + 1, st.end - trim_end)
    return float(np.mean(run.x[st.mass, a:b] - travel[a:b]))


def _stuck_at(sticks: list[Stick], j: int, trim_end: int) -> Stick | None:
    for st in sticks:
        if st.start + 1 <= j <= st.end - trim_end:
            return st
    return None


def need_dimless(run: BeltRun, xs: np.ndarray, mass: int) -> np.ndarray:
    """Friction [F0] a stuck mass needs: (K x)_i/F0 + d s (+ the belt's acceleration term), along samples."""
    mech = run.mech
    chain = chain_force_dimless(xs / mech.x_unit)[mass]
    s = run.vb / mech.v_unit
    acc = np.gradient(run.vb, 1.0 / run.rate) * mech.mass_kg / mech.normal_force_N
    return chain + mech.d * s + acc


def slip_windows(run: BeltRun, sticks: list[list[Stick]], run_index: int = 0, masses: list[int] | None = None,
                 max_periods: float = 3.0) -> tuple[list[SlipWindow], dict[str, int]]:
    """Cut a recording into slip windows (see SlipWindow); returns them and counts of what was left out."""
    mech = run.mech
    n = run.n
    travel = run.belt_travel
    half = 5
    dt = 1.0 / run.rate
    xs = sg(run.x, half)
    vs = sg(run.x, half, 1, dt)
    need = [need_dimless(run, np.where(np.isfinite(xs), xs, 0.0), i) for i in range(n)]
    period = 2 * math.pi * mech.tau0
    max_len = int(max_periods * period * run.rate)
    # the detected end of a stick is late by the time the slip takes to exceed the velocity noise,
    # which scales with tau0 (~0.3 tau0 for alpha_drop = 4): start the window well before it
    pre = max(PRE_BREAK, int(math.ceil(0.6 * mech.tau0 * run.rate)))
    skipped = {"open": 0, "no_next_stick": 0, "other_mass_breaks": 0, "neighbour_just_broke": 0, "too_long": 0}
    out = []
    for i in (masses if masses is not None else range(n)):
        lst = sticks[i]
        for k, st in enumerate(lst):
            if st.open_end or st.end - st.start < MIN_STICK_SAMPLES:
                skipped["open"] += 1
                continue
            if k + 1 >= len(lst):
                skipped["no_next_stick"] += 1
                continue
            j0 = max(st.start + 2, st.end - pre)
            j1 = min(lst[k + 1].start + POST_STICK, run.t.size - 1)
            if j1 - j0 > max_len:
                skipped["too_long"] += 1
                continue
            cut = j1
            recent = False
            for o in range(n):
                if o == i:
                    continue
                for so in sticks[o]:
                    if j0 < so.end <= j1 and not so.open_end:
                        cut = min(cut, so.end - OTHER_BREAK_MARGIN)
                    # a neighbour that broke away just before j0 may still be on its drop branch, which
                    # the window cannot start it on: leave such windows out
                    if j0 - pre - OTHER_BREAK_MARGIN <= so.end <= j0 and not so.open_end:
                        recent = True
            if recent:
                skipped["neighbour_just_broke"] += 1
                continue
            if cut < st.end + 10:  # not even the start of the slip left
                skipped["other_mass_breaks"] += 1
                continue
            j1 = cut
            s0 = np.zeros(beltndof.n_state(n))
            modes = np.full(n, beltndof.SLIP)
            sdir = np.ones(n)
            for o in range(n):
                so = st if o == i else _stuck_at(sticks[o], j0, 2)
                if so is not None:
                    s0[o] = _stick_line(run, so, travel, 4 if so is st else 2) + travel[j0]
                    s0[n + o] = run.vb[j0]
                    modes[o] = beltndof.STICK
                else:
                    s0[o] = xs[o, j0]
                    s0[n + o] = vs[o, j0]
                    sdir[o] = 1.0 if run.vb[j0] - vs[o, j0] >= 0 else -1.0
            free = np.flatnonzero(modes == beltndof.SLIP)
            tail = 2 * n
            s0[tail + TAIL.TEMP] = run.cfg.contact.t_ambient_C
            s0[tail + TAIL.VLAG] = run.vb[j0]
            s0[tail + TAIL.POS] = travel[j0]
            a, b = max(j0 - 1, 0), min(j1 + 2, run.t.size)
            rt = np.ascontiguousarray(run.t[a:b])
            rv = np.ascontiguousarray(run.vb[a:b])
            fs_guess = float(need[i][st.end - 1])
            # mean load rate while stuck [N/s]: slope of the needed force over the stick (the rate the static
            # law reads is the one at the break-away, from the fitted window: see _load_rate)
            F0 = mech.normal_force_N
            seg = slice(st.start + 1, max(st.start + 3, st.end - 2))
            tt = run.t[seg]
            d_mean = float(np.polyfit(tt, need[i][seg] * F0, 1)[0]) if tt.size >= 3 else float("nan")
            # bounds of f_s: the detected stick end is late, so f_s < guess
            fs_lo = max(0.05, 0.75 * fs_guess)
            fs_hi = max(fs_lo + 0.1, 1.1 * fs_guess)
            out.append(SlipWindow(run_index, i, st, j0, j1, s0, modes, sdir, fs_guess, fs_lo, fs_hi,
                                  np.abs(need[i][j0:min(st.end + 3, j1 + 1)]), True,
                                  run.x[:, j0:j1 + 1].copy(), run.sigma_x.copy(), free, s0[n + free].copy(),
                                  rt, rv, d_mean))
    return out, skipped


class WindowSimulator:
    """Simulates slip windows with given law parameters through daq.physics.beltndof.simulate."""

    def __init__(self, run: BeltRun, n_sub: int | None = None) -> None:

        self.run = run
        cfg_n = run.cfg.model_copy(update={"mechanics": run.cfg.mechanics.model_copy(
            update={"n_masses": run.n})})
        e = environment_vector(cfg_n)
        e[E.D_BELT] = run.mech.d
        e[E.ST_TAU] = ST_TAU_FAR
        e[E.FR_GAIN] = 0.0
        e[E.TEMP_COEF] = 0.0
        e[E.VB_TAU] = 0.0
        e[E.VB_RIPPLE] = 0.0
        e[E.VS_D] = 0.0
        self.e = e
        self.p = BeltSim(cfg_n, e).params()
        dt_cfg = run.cfg.integrator.dt_s
        self.n_sub = n_sub or max(1, int(math.ceil((1.0 / run.rate) / dt_cfg - 1e-9)))
        self.h = 1.0 / run.rate / self.n_sub

    def simulate(self, w: SlipWindow, law: np.ndarray, fs: float, fine: int = 1, v: np.ndarray | None = None):
        """States and modes at the window's samples (fine > 1: fine-times finer), law = LAW values.

        ``v``: start velocities of the window's free masses (default: their current guess).
        """

        P = beltndof.P
        H = beltndof.H
        p = self.p.copy()
        p[P.F_S0] = F_BIG
        p[P.ALPHA_DROP], p[P.F_K0], p[P.K_FALL], p[P.W_MIN], p[P.K_RISE] = law[:5]
        e = self.e.copy()
        e[E.AS_AMP] = law[5]
        e[E.ST_GAIN] = fs / F_BIG - 1.0
        n = self.run.n
        hs = beltndof.new_hybrid(n, fs, 1.0)
        t0 = float(self.run.t[w.j0])
        for o in range(n):
            hs[H.MODE, o] = w.modes[o]
            hs[H.SLIP_DIR, o] = w.slip_dir[o]
            hs[H.FS_BREAK, o] = (1.0 + law[5]) * law[1]
            hs[H.STICK_T0, o] = t0 - CLOCK_FAR if o == w.mass else t0 + CLOCK_FAR
        n_out = (w.j1 - w.j0) * fine + 1
        m = max(1, int(math.ceil(self.n_sub / fine)))  # internal steps per output, no longer than the config's
        dt = 1.0 / (self.run.rate * fine * m)
        s0 = w.s0.copy()
        s0[n + w.free_v] = w.v_guess if v is None else v
        states, _, _, modes, _ = beltndof.simulate(s0, t0, dt, m, n_out, p, e, w.rt, w.rv, hs)
        return states, modes


LOSS = "soft_l1"  # robust loss of the output-error fits
MAX_PASSES = 3  # refits on the best-fitting windows (see belt_law)
RMS_AT_NOISE = 1.15  # a law fit with a larger rms [noise units] is not at the noise
ALPHA_GRID = (1.0, 2.0, 4.0, 8.0, 16.0)  # start values of alpha_drop tried before the law fit
N_SUB = 2  # internal steps per output sample in the windows: the law is piecewise linear, RK4 between
# located events is exact to ~1e-8 of the amplitude at 2 ms steps (same fits as with the config's 0.5 ms)
LAW_LO = np.array([0.2, 0.05, 0.0, 0.02, 0.0, -0.5])
LAW_HI = np.array([50.0, 5.0, 5.0, 20.0, 5.0, 0.5])


def window_residual(w: SlipWindow, states: np.ndarray) -> np.ndarray:
    """Simulated minus measured positions of every mass after the start sample, in units of their noise."""
    n = w.x_meas.shape[0]
    return ((states[1:, :n] - w.x_meas[:, 1:].T) / w.sigma).ravel()


def scan_break_levels(runs: list[BeltRun], windows: list[SlipWindow], law: np.ndarray) -> None:
    """Start value and bounds of each window's f_s: the best of the levels the data's stick passes through.

    Why a scan: above the largest force the mass needs inside the window the simulated
    mass never breaks and the cost is flat in f_s; a gradient method started there stays
    there (a late-detected stick end in a chain, where the neighbour sticks and the need
    stops growing, puts the naive guess exactly there). Each candidate is the force the
    data says the mass needs at one sample; the bounds bracket the best by four samples.
    """
    sims = [WindowSimulator(r, n_sub=N_SUB) for r in runs]
    for w in windows:
        cand = np.asarray(w.need_path, dtype=float)
        if cand.size < 2:
            continue
        step = 1 if cand.size <= 12 else 2
        idx = np.arange(0, cand.size, step)
        costs = []
        for fs in cand[idx]:
            st, _ = sims[w.run].simulate(w, law, float(fs))
            costs.append(float(np.mean(window_residual(w, st) ** 2)))
        j = int(idx[int(np.argmin(costs))])
        w.valid = j != 0
        lo_j, hi_j = max(0, j - 4), min(cand.size - 1, j + 4)
        w.fs_guess = float(cand[j])
        w.fs_lo = float(max(0.05, min(cand[lo_j:hi_j + 1].min(), w.fs_guess) - 1e-3))
        w.fs_hi = float(max(cand[lo_j:hi_j + 1].max(), w.fs_guess) + 1e-3)


def fit_output_error(runs: list[BeltRun], windows: list[SlipWindow], law0: np.ndarray,
                     free: tuple[str, ...] = LAW, fs0: np.ndarray | None = None, progress=None,
                     max_nfev: int = 40, f_scale: float = 3.0) -> tuple[LsqFit, np.ndarray, np.ndarray]:
    """Least squares of the measured positions over slip windows: shared law, one f_s per window.

    ``free`` names the law parameters fitted (the rest stay at law0). Per window the
    break-away level f_s and the start velocities of the masses slipping at its start
    are nuisance parameters (the velocities are kept in the windows for the next fit).
    Returns the law fit (std 0 for fixed parameters), the fitted break-away levels and
    their standard deviations. Residuals: every mass's position in units of its noise,
    with a soft-L1 loss beyond ``f_scale`` noise units (a window the detection got
    wrong must not drag the law). The Jacobian is block-sparse (a window's residuals
    depend on the law and its own nuisances), so scipy differences all windows' own
    columns in 1 + (free velocities per window) passes.
    """

    sims = [WindowSimulator(r, n_sub=N_SUB) for r in runs]
    nw = len(windows)
    idx = [LAW.index(k) for k in free]
    nl = len(idx)
    law0 = np.asarray(law0, dtype=float)
    sizes = [(w.j1 - w.j0) * w.x_meas.shape[0] for w in windows]
    offs = np.concatenate([[0], np.cumsum(sizes)])
    npw = [1 + w.free_v.size for w in windows]  # parameters per window: f_s, then free start velocities
    poff = nl + np.concatenate([[0], np.cumsum(npw)])
    calls = [0]

    def law_of(th):
        law = law0.copy()
        law[idx] = th[:nl]
        return law

    def resid(th):
        law = law_of(th)
        out = np.empty(offs[-1])
        for k, w in enumerate(windows):
            a = poff[k]
            st, _ = sims[w.run].simulate(w, law, th[a], v=th[a + 1:poff[k + 1]])
            out[offs[k]:offs[k + 1]] = window_residual(w, st)
        calls[0] += 1
        if progress and calls[0] % 25 == 0:
            progress(f"output error: {calls[0]} evaluations of {nw} windows, rms {np.sqrt(np.mean(out**2)):.3g} "
                     "noise units")
        return out

    sp = lil_matrix((offs[-1], poff[-1]), dtype=int)
    if nl:
        sp[:, :nl] = 1
    lo, hi, th0 = list(LAW_LO[idx]), list(LAW_HI[idx]), list(law0[idx])
    for k, w in enumerate(windows):
        sp[offs[k]:offs[k + 1], poff[k]:poff[k + 1]] = 1
        lo.append(w.fs_lo)
        hi.append(w.fs_hi)
        th0.append(w.fs_guess if fs0 is None else float(fs0[k]))
        span = 0.2 * np.abs(w.v_guess) + 0.2 * float(np.max(np.abs(w.rv))) + 0.01
        lo += list(w.v_guess - span)
        hi += list(w.v_guess + span)
        th0 += list(w.v_guess)
    lo, hi, th0 = np.array(lo), np.array(hi), np.array(th0)
    th0 = np.clip(th0, lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo))
    r = least_squares(resid, th0, bounds=(lo, hi), jac_sparsity=sp, x_scale="jac", max_nfev=max_nfev,
                      diff_step=1e-5, loss=LOSS, f_scale=f_scale)
    res = r.fun
    std_all = _std_from_jac(r.jac, res, poff[-1])
    std = np.zeros(len(LAW))
    std[idx] = std_all[:nl]
    fit = LsqFit(LAW, law_of(r.x), std, float(np.sqrt(np.mean(res**2))), int(res.size),
                 {"evaluations": int(r.nfev), "status": int(r.status), "windows": nw})
    for k, w in enumerate(windows):
        w.v_guess = r.x[poff[k] + 1:poff[k + 1]].copy()
    return fit, r.x[poff[:-1]], std_all[poff[:-1]]




# ----------------------------------------------------------------------------- static limit


STATIC = ("f_s0", "stick_time_gain", "stick_time_tau_s", "force_rate_gain")


def static_law(t_s: np.ndarray, delta: np.ndarray, f_s0: float, g_t: float, tau: float, g_d: float,
               q0: float) -> np.ndarray:
    """f_s(t_s, Delta) of the stick-time and force-rate effects: daq.physics.effects.static_factor, vectorised."""

    return f_s0 * np.array([static_factor(float(a), float(b), g_t, tau, g_d, q0) for a, b in
                            zip(np.atleast_1d(t_s), np.atleast_1d(delta))])


def fit_static(t_s: np.ndarray, delta: np.ndarray, f_s: np.ndarray, q0: float) -> LsqFit:
    """Least squares of the break-away levels against stick time [s] and force rate [N/s].

    f_s = f_s0 (1 + g_t (1 - exp(-t_s/tau)) + g_d ln(1 + |Delta|/q0)), q0 fixed (with
    Delta >> q0 the log is ln Delta - ln q0 and q0 trades off against f_s0 and g_d; the
    model files fix it for the same reason). tau is started from a grid over the
    observed stick times; with g_t -> 0 it is undetermined and its std says so.
    """

    t_s, delta, f_s = (np.asarray(a, dtype=float) for a in (t_s, delta, f_s))
    if f_s.size < 5:
        raise ValueError(f"{f_s.size} break-away episodes: too few for the static law (need 5)")

    def resid(th):
        return static_law(t_s, delta, th[0], th[1], th[2], th[3], q0) - f_s

    lo = np.array([0.01, 0.0, 1e-3, 0.0])
    hi = np.array([20.0, 5.0, 100.0, 5.0])
    best = None
    for tau in np.geomspace(max(1e-3 * 2, 0.3 * np.min(t_s)), max(3.0 * np.max(t_s), 0.01), 5):
        th0 = np.array([float(np.min(f_s)) * 0.8, 0.2, tau, 0.05])
        r = least_squares(resid, np.clip(th0, lo + 1e-9, hi - 1e-9), bounds=(lo, hi), x_scale="jac")
        if best is None or r.cost < best.cost:
            best = r
    res = resid(best.x)
    return LsqFit(STATIC, best.x, _std_from_jac(best.jac, res, 4), float(np.sqrt(np.mean(res**2))), int(res.size),
                  {"q0_N_per_s": q0})


# ----------------------------------------------------------------------------- belt-law: the whole identification


class Estimate(BaseModel):
    value: float
    std: float | None  # None: not determined by the data (e.g. alpha_drop when no kept point lies on the drop)


class RecordingSummary(BaseModel):
    path: str
    n_masses: int
    belt_speed_m_per_s: float  # median drive speed
    belt_speed_s: float  # dimensionless s of eq. (2)
    drive: str
    sticks: int
    windows: int
    left_out: dict[str, int]
    w_max: float  # largest |w| seen while slipping (kept points)


class Episode(BaseModel):
    recording: int
    mass: int  # 1-based
    t_break_s: float
    t_s_s: float | None  # stick time [s] (None if the stick began before the record)
    delta_N_per_s: float  # load rate at the break-away [N/s]
    delta_mean_N_per_s: float  # mean load rate over the stick [N/s]
    f_s: float
    f_s_std: float


class BeltLawResult(BaseModel):
    """JSON of ``daq analyse belt-law``."""

    analysis: str = "belt-law"
    paper: str = "000"
    method: str
    recordings: list[RecordingSummary]
    mechanics: dict[str, float | int | str]
    law: dict[str, Estimate]  # output error: alpha_drop, f_k0, k_fall, w_min, k_rise, amp
    law_rms_noise_units: float
    equation_error: dict[str, Estimate]  # the paper's least squares on f(w) points (biased, see docs)
    equation_error_rms: float
    static: dict[str, Estimate] | None
    static_rms: float | None
    force_rate_q0_N_per_s: float
    episodes: list[Episode]
    points: dict[str, list[float]]  # the kept f(w) points: w, f, growing, s, mass, recording
    windows_in_law_fit: int
    warnings: list[str]
    seconds: float


@dataclass
class BeltLawAnalysis:
    result: BeltLawResult
    points: FrictionPoints
    runs: list[BeltRun]


def _spread_pick(items: list, k: int) -> list:
    if len(items) <= k:
        return list(items)
    return [items[int(i)] for i in np.unique(np.linspace(0, len(items) - 1, k).round())]


def belt_law(runs: list[BeltRun], masses: list[int] | None = None, windows_per_mass: int = 6,
             progress=None, max_nfev: int = 40) -> BeltLawAnalysis:
    """Identify paper 000's friction law from recordings (ideally at several constant belt speeds).

    See the module docstring for the two stages. ``masses`` (0-based) restricts which
    contacts are identified (all by default; every mass rides the same belt with the
    same law). ``windows_per_mass`` slip windows per recording and mass, spread over the
    record, enter the law fit (a limit cycle repeats itself; more windows cost time,
    not information); every window then gets its break-away level with the law fixed.
    """

    t_start = time.perf_counter()
    say = progress or (lambda msg: None)
    warnings: list[str] = []
    all_pts, all_windows, summaries = [], [], []
    for k, run in enumerate(runs):
        ms = [m for m in (masses if masses is not None else range(run.n)) if m < run.n]
        if not ms:
            raise InputError(run.source, "--mass", f"the recording has {run.n} mass(es)")
        sticks = [find_sticks(run, i) for i in range(run.n)]
        pts = friction_points(run, sticks, k, masses=ms)
        wins, left = slip_windows(run, sticks, k, masses=ms)
        all_pts.append(pts)
        all_windows += wins
        kept = pts.kept
        summaries.append(RecordingSummary(
            path=run.source, n_masses=run.n, belt_speed_m_per_s=float(np.median(run.vb)),
            belt_speed_s=float(np.median(run.vb) / run.mech.v_unit), drive=run.vb_source,
            sticks=sum(len(sticks[m]) for m in ms), windows=len(wins), left_out=left,
            w_max=float(np.max(np.abs(pts.w[kept]))) if kept.any() else 0.0))
        say(f"{run.source}: {run.n} mass(es), s = {summaries[-1].belt_speed_s:.3f}, "
            f"{summaries[-1].sticks} sticks, {len(wins)} slip windows")
    pts = merge_points(all_pts)
    if not all_windows:
        raise InputError(runs[0].source if len(runs) == 1 else ", ".join(r.source for r in runs), "x1",
                         "no stick-slip episode found (the law is identified from stick-slip cycles)")
    try:
        ee = fit_kinetic_points(pts)
    except ValueError as exc:
        raise InputError(runs[0].source, "x1", f"equation-error fit impossible: {exc}") from None
    say("equation error (paper's least squares): " + ", ".join(f"{k}={v:.4g}" for k, v in zip(ee.names, ee.values)))
    law0 = np.clip(ee.values, LAW_LO + 1e-6, LAW_HI - 1e-6)
    sub = []
    for k in range(len(runs)):
        for m in range(runs[k].n):
            sub += _spread_pick([w for w in all_windows if w.run == k and w.mass == m], windows_per_mass)
    say(f"output error over {len(sub)} slip windows: break-away levels, then the kinetic branches, then the "
        "whole law")
    # alpha_drop: the equation error rarely sees the drop (it is inside the excluded samples), and a
    # gradient started at a too steep drop finds a flat cost (the drop is over within one step):
    # start from the best of a grid, each with the break-away levels scanned
    best = None
    for ad in ALPHA_GRID:
        trial = law0.copy()
        trial[0] = ad
        scan_break_levels(runs, sub, trial)
        cost = float(np.sum(_window_rms(runs, sub, trial, np.array([w.fs_guess for w in sub])) ** 2))
        if best is None or cost < best[0]:
            best = (cost, ad)
    law0[0] = best[1]
    scan_break_levels(runs, sub, law0)
    sub = [w for w in sub if w.valid]
    f1, fs, _ = fit_output_error(runs, sub, law0, free=(), max_nfev=max_nfev)
    # the kinetic part first (alpha_drop held): the equation-error start is biased, and a drop fitted
    # against a biased kinetic line steepens to compensate, into a flat valley that is slow to leave
    f2, fs, _ = fit_output_error(runs, sub, law0, free=KINETIC, fs0=fs, max_nfev=max_nfev)
    scan_break_levels(runs, sub, f2.values)
    fs = np.array([w.fs_guess for w in sub])
    # windows the segmentation got structurally wrong (a graze taken for a stick, a neighbour's unseen
    # break, a window starting after the break) are off by tens of noise units even with the start law
    per = _window_rms(runs, sub, f2.values, fs)
    wrong = (per > max(10.0, 5.0 * float(np.median(per)))) | ~np.array([w.valid for w in sub])
    if wrong.any():
        say(f"{int(wrong.sum())} window(s) far off already at the start law: left out")
        sub = [w for w, b in zip(sub, wrong) if not b]
    law, fs, _ = fit_output_error(runs, sub, f2.values, progress=say, max_nfev=3 * max_nfev)

    def all_levels(law_values: np.ndarray):
        scan_break_levels(runs, all_windows, law_values)
        ok = np.array([w.valid for w in all_windows])
        out = np.full(len(all_windows), np.nan), np.full(len(all_windows), np.nan), np.full(len(all_windows), np.inf)
        idx = np.flatnonzero(ok)
        if idx.size:
            wins = [all_windows[j] for j in idx]
            _, f_, s_ = fit_output_error(runs, wins, law_values, free=(), max_nfev=max_nfev)
            out[0][idx], out[1][idx], out[2][idx] = f_, s_, _window_rms(runs, wins, law_values, f_)
        return out

    # further passes: with a law near the truth the windows the segmentation got wrong stand out (tens
    # of noise units against ~1); while a window worse than twice the median was in the fit, or the fit
    # is not at the noise (a local minimum), refit on windows of each recording and mass spread over
    # the record among those within twice the median
    j_of = {id(w): j for j, w in enumerate(all_windows)}
    for _ in range(MAX_PASSES):
        fs_all, fs_std, per_all = all_levels(law.values)
        fin = np.isfinite(per_all)
        limit = max(2.0, 2.0 * float(np.median(per_all[fin]))) if fin.any() else 2.0
        sub2 = []
        for k in range(len(runs)):
            for m in range(runs[k].n):
                # spread over the record among the good ones (picking the best-fitting would favour the
                # windows that agree with the current law, and lock it in)
                sub2 += _spread_pick([w for j, w in enumerate(all_windows)
                                      if w.run == k and w.mass == m and per_all[j] <= limit], windows_per_mass)
        bad_in_fit = any(not per_all[j_of[id(w)]] <= limit for w in sub)
        if not sub2 or (not bad_in_fit and law.rms <= RMS_AT_NOISE) or {id(w) for w in sub2} == {id(w) for w in sub}:
            break
        say(f"refit on {len(sub2)} windows that fit ({int(np.sum(~(per_all <= limit)))} of "
            f"{len(all_windows)} fit worse than twice the median; the fit had rms {law.rms:.3g})")
        law, _, _ = fit_output_error(runs, sub2, law.values, fs0=np.array([fs_all[j_of[id(w)]] for w in sub2]),
                                     progress=say, max_nfev=3 * max_nfev)
        sub = sub2
    else:
        fs_all, fs_std, per_all = all_levels(law.values)
        fin = np.isfinite(per_all)
        limit = max(2.0, 2.0 * float(np.median(per_all[fin]))) if fin.any() else 2.0
    n_bad = int(np.sum(~(per_all <= limit)))
    if n_bad:
        warnings.append(f"{n_bad} of {len(all_windows)} slip windows fit worse than twice the median (or could "
                        "not be placed): left out of the law and the static data")
    if law.rms > RMS_AT_NOISE:
        warnings.append(f"the law fit is at {law.rms:.3g} noise units, not at the noise: model error or a local "
                        "minimum (compare with --windows N)")
    say("law: " + ", ".join(f"{k}={v:.4g}" for k, v in zip(law.names, law.values))
        + f"; rms {law.rms:.3g} noise units")
    good = per_all <= limit
    episodes = []
    sims = [WindowSimulator(r, n_sub=N_SUB) for r in runs]
    for w, f_s, sd, ok in zip(all_windows, fs_all, fs_std, good):
        if not ok:
            continue
        run = runs[w.run]
        fine = 4
        states, modes = sims[w.run].simulate(w, law.values, f_s, fine=fine)
        slip = np.flatnonzero(modes[:, w.mass] == beltndof.SLIP)
        if not slip.size:
            continue
        t_break = float(run.t[w.j0] + (slip[0] - 0.5) / (run.rate * fine))
        t_stick0 = run.t[w.stick.start] - 0.5 / run.rate
        t_s = None if w.stick.open_start else t_break - t_stick0
        episodes.append(Episode(recording=w.run, mass=w.mass + 1, t_break_s=t_break, t_s_s=t_s,
                                delta_N_per_s=_load_rate(run, w, states[max(slip[0] - 1, 0)], t_break),
                                delta_mean_N_per_s=w.delta_mean, f_s=float(f_s), f_s_std=float(sd)))
    q0 = runs[0].mech.q0_N_per_s
    use = [e for e in episodes if e.t_s_s is not None and e.t_s_s > 0 and np.isfinite(e.delta_N_per_s)]
    static = None
    if len(use) >= 5:
        static = fit_static(np.array([e.t_s_s for e in use]), np.array([e.delta_N_per_s for e in use]),
                            np.array([e.f_s for e in use]), q0)
        # conditions: (t_s, Delta) pairs distinct by more than 10 % in either; a limit cycle repeats one
        cond = {(round(math.log(e.t_s_s) / 0.1), round(math.log1p(abs(e.delta_N_per_s)) / 0.1)) for e in use}
        if len(cond) < 4:
            warnings.append(f"only {len(cond)} distinct (stick time, force rate) conditions: the static law's "
                            "4 parameters are not all determined (vary belt speed and spring stiffness)")
        if any(r.n > 1 for r in runs):
            warnings.append("static law from a chain of masses: measured unreliable on simulated chains (a stick "
                            "time the position data see can contain micro-slips that restart the stick clock; "
                            "docs/analyses-000.md); identify it from one-mass records")
    else:
        warnings.append(f"{len(use)} complete stick episodes: too few for the static law")
    w_max = max(s.w_max for s in summaries)
    if w_max < law.values[LAW.index("w_min")]:
        warnings.append(f"largest |w| seen ({w_max:.3g}) is below w_min: k_rise and w_min are extrapolated")
    mech = runs[0].mech
    k = pts.kept
    res = BeltLawResult(
        method="output error over slip windows (daq.physics.beltndof.simulate) from the equation-error start; "
               "static limit: least squares of the windows' break-away levels against stick time and force rate",
        recordings=summaries,
        mechanics={"mass_kg": mech.mass_kg, "stiffness_N_per_m": mech.stiffness_N_per_m,
                   "normal_force_N": mech.normal_force_N, "d": mech.d, "tau0_s": mech.tau0,
                   "x_unit_m": mech.x_unit, "v_unit_m_per_s": mech.v_unit, "config": mech.config_source},
        law={k_: Estimate(value=float(v), std=float(s)) for k_, v, s in zip(law.names, law.values, law.std)},
        law_rms_noise_units=law.rms,
        equation_error={k_: Estimate(value=float(v), std=float(s) if s > 0 else None)
                        for k_, v, s in zip(ee.names, ee.values, ee.std)},
        equation_error_rms=ee.rms,
        static=({k_: Estimate(value=float(v), std=float(s)) for k_, v, s in zip(static.names, static.values, static.std)}
                if static else None),
        static_rms=static.rms if static else None,
        force_rate_q0_N_per_s=q0,
        episodes=episodes,
        points={"w": pts.w[k].tolist(), "f": pts.f[k].tolist(), "growing": pts.growing[k].tolist(),
                "s": pts.s[k].tolist(), "mass": (pts.mass[k] + 1).tolist(), "recording": pts.run[k].tolist()},
        windows_in_law_fit=len(sub),
        warnings=warnings,
        seconds=time.perf_counter() - t_start)
    return BeltLawAnalysis(res, pts, runs)


def _load_rate(run: BeltRun, w: SlipWindow, state: np.ndarray, t: float) -> float:
    """Rate [N/s] of the force a stuck mass needs, at the simulated break-away: what the static law reads.

    As daq.physics.beltndof._stick_need: D vb' + (K v)_i with the mass at belt speed and
    its neighbours at their simulated velocities (belt jerk neglected).
    """
    n = run.n
    vb = float(np.interp(t, w.rt, w.rv))
    k = int(np.clip(np.searchsorted(w.rt, t) - 1, 0, w.rt.size - 2))
    dvb = float((w.rv[k + 1] - w.rv[k]) / (w.rt[k + 1] - w.rt[k]))
    vel = np.ascontiguousarray(state[n:2 * n], dtype=float).copy()
    vel[w.mass] = vb
    mech = run.mech
    damp = mech.d * math.sqrt(mech.stiffness_N_per_m * mech.mass_kg)
    return float(damp * dvb + beltndof.chain_at(vel, w.mass, n, mech.stiffness_N_per_m))


def _window_rms(runs: list[BeltRun], windows: list[SlipWindow], law: np.ndarray, fs: np.ndarray) -> np.ndarray:
    sims = [WindowSimulator(r, n_sub=N_SUB) for r in runs]
    out = np.empty(len(windows))
    for k, w in enumerate(windows):
        st, _ = sims[w.run].simulate(w, law, fs[k])
        out[k] = float(np.sqrt(np.mean(window_residual(w, st) ** 2)))
    return out


# ----------------------------------------------------------------------------- Poincaré section


class PoincareResult(BaseModel):
    """JSON of ``daq analyse poincare``."""

    analysis: str = "poincare"
    paper: str = "000"
    path: str
    n_masses: int
    mass: int  # 1-based: whose velocity defines the section
    section: str
    level: float  # dimensionless velocity level c of the section
    belt_speed_s: float
    skip_s: float
    points_total: int
    points_steady: int
    classification: str  # "period-k", "irregular", "too few crossings", "no oscillation (steady sliding or rest)"
    period: int | None  # k of period-k
    period_s: float | None  # duration of one period of the section sequence [s]
    distance_by_k: dict[str, float]  # k -> 90th percentile of |P_{n+k} - P_n| (normalised)
    tolerance: float
    distinct_points: int  # clusters of steady section points at the tolerance
    section_points: dict[str, list[float]]  # t [s] and every coordinate (dimensionless) of every crossing
    stick_fraction: float  # share of the steady part the section mass spends stuck


@dataclass
class PoincareAnalysis:
    result: PoincareResult
    t: np.ndarray
    x: np.ndarray  # dimensionless positions (n, N), smoothed
    v: np.ndarray  # dimensionless velocities (n, N)
    cross_t: np.ndarray
    points: np.ndarray  # (m, 2n) section states: x_1..x_n, v_1..v_n
    steady: np.ndarray  # bool per crossing


SKIP_FRACTION = 0.4  # default transient: this share of the record


def poincare(run: BeltRun, mass: int = 0, skip_s: float | None = None, kmax: int = 8,
             half: int = 3) -> PoincareAnalysis:
    """Poincaré section and periodicity of a belt-ndof trajectory (paper 000: periodicity of the vibrations).

    Section (our choice, the paper does not say which it used): the instants the
    velocity of mass ``mass`` crosses the level c = mid-range of its velocity
    *downward* (a Schmitt trigger with hysteresis against noise), each crossing
    giving the point P = (x_1..x_n, x'_1..x'_n) of all masses, dimensionless. In a
    stick-slip cycle this is once per slip, where the mass moves fastest backward
    relative to the belt... at mid-speed, far from the stick (where the state is
    pinned to the belt) and from the turning points (where timing noise is largest).

    Periodicity: d_k = 90th percentile over n of max |P_{n+k} - P_n| with each
    coordinate scaled by its range over the steady part; the motion is period-k for
    the smallest k <= kmax with d_k below the tolerance (8 x the scaled noise of a
    section point, at least 0.01), else irregular (quasi-periodic or chaotic: the
    steady points do not repeat). The first ``skip_s`` seconds (default: 40 % of the
    record; a chain of masses can take seconds to settle on its cycle) are the
    transient and are not classified.
    """
    mech = run.mech
    dtd = 1.0 / run.rate / mech.tau0
    xd = run.x / mech.x_unit
    xs = sg(xd, half, 0)
    vs = sg(xd, half, 1, dtd)
    t = run.t
    skip = SKIP_FRACTION * (t[-1] - t[0]) if skip_s is None else float(skip_s)
    steady_s = t >= t[0] + skip
    v = vs[mass]
    lo, hi = np.quantile(v[steady_s], [0.01, 0.99])
    c = 0.5 * (lo + hi)
    sig_v = run.sigma_x[mass] / mech.x_unit * _sg_gain(half, 1) / dtd
    h = max(4.0 * sig_v, 0.05 * (hi - lo))
    # Schmitt trigger: armed above c + h; a downward crossing of c counts once v then reaches c - h
    # before it returns above c + h (noise around c gives one crossing, not several)
    cross = []
    armed = False
    cand = None
    for j in range(1, v.size):
        if v[j] > c + h:
            armed, cand = True, None
        elif armed and cand is None and v[j - 1] > c >= v[j]:
            cand = j - 1 + (v[j - 1] - c) / (v[j - 1] - v[j])
        if cand is not None and v[j] < c - h:
            cross.append(cand)
            armed, cand = False, None
    cross = np.asarray(cross, dtype=float)
    n = run.n
    if cross.size:
        i0 = np.floor(cross).astype(int)
        fr = cross - i0
        i1 = np.minimum(i0 + 1, t.size - 1)
        pts = np.vstack([xs[:, i0] * (1 - fr) + xs[:, i1] * fr, vs[:, i0] * (1 - fr) + vs[:, i1] * fr]).T
        ct = t[i0] * (1 - fr) + t[i1] * fr
    else:
        pts = np.zeros((0, 2 * n))
        ct = np.zeros(0)
    steady = ct >= t[0] + skip
    P = pts[steady]
    # scale of each coordinate, and the noise of a section point in it
    rng_x = np.ptp(xs[:, steady_s], axis=1)
    rng_v = np.ptp(vs[:, steady_s], axis=1)
    scale = np.concatenate([rng_x, rng_v])
    scale = np.where(scale > 0, scale, 1.0)
    sig_x = run.sigma_x / mech.x_unit * _sg_gain(half, 0)
    sig_vv = run.sigma_x / mech.x_unit * _sg_gain(half, 1) / dtd
    noise = np.concatenate([sig_x, sig_vv]) / scale
    tol = max(0.01, 8.0 * float(np.max(noise)))
    dist: dict[str, float] = {}
    period = None
    for k in range(1, kmax + 1):
        if P.shape[0] < k + 3:
            break
        d = np.max(np.abs(P[k:] - P[:-k]) / scale, axis=1)
        dist[str(k)] = float(np.quantile(d, 0.9))
        if period is None and dist[str(k)] < tol:
            period = k
    if hi - lo < 8.0 * sig_v:
        cls = "no oscillation (steady sliding or rest)"
        period = None
    elif P.shape[0] < 6:
        cls = "too few crossings"
        period = None
    elif period is None:
        cls = "irregular"
    else:
        cls = f"period-{period}"
    # distinct points: greedy clustering at the tolerance
    centres: list[np.ndarray] = []
    for p in P / scale:
        if not any(np.max(np.abs(p - q)) < tol for q in centres):
            centres.append(p)
    period_s = float(np.median(ct[steady][period:] - ct[steady][:-period])) if period and P.shape[0] > period else None
    stuck = np.abs(vs[mass] - run.vb / mech.v_unit) < 4.0 * sig_v + 0.01 * np.abs(run.vb / mech.v_unit)
    names = [f"x{i + 1}" for i in range(n)] + [f"v{i + 1}" for i in range(n)]
    res = PoincareResult(
        path=run.source, n_masses=n, mass=mass + 1,
        section=f"downward crossings of x'{mass + 1} = c (c = mid-range of x'{mass + 1} over the steady part); "
                "coordinates x_i = K X_i / F0, v_i = dx_i/dt in t = tau / sqrt(M/K)",
        level=float(c), belt_speed_s=float(np.median(run.vb) / mech.v_unit), skip_s=skip,
        points_total=int(cross.size), points_steady=int(P.shape[0]), classification=cls, period=period,
        period_s=period_s, distance_by_k=dist, tolerance=tol, distinct_points=len(centres),
        section_points={"t": ct.tolist(), **{nm: pts[:, i].tolist() for i, nm in enumerate(names)}},
        stick_fraction=float(np.mean(stuck[steady_s])))
    return PoincareAnalysis(res, t, xs, vs, ct, pts, steady)
