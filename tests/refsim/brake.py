"""brake-2dof reference model (paper 001), derived here from the paper's Lagrangian.

Coordinates q = (x1, y1), y1 = r phi (paper 001 section 2.2). Spring elongations
(1a)-(1c): dl1 = x1, dl2 = -(x1 + y1), dl3 = y1 + x1^2/(2r). Lagrangian (2):

    L = 1/2 (m x1'^2 + J phi'^2) - V,
    V = 1/2 k1 dl1^2 + 1/2 k2 dl2^2 + 1/2 k3 dl3^2 + P(phi),
    P(phi) = M g l [1 - cos(pi/4 + phi)],  l = (3 sqrt 2 / 4) r.

We keep P(phi) exact (the paper expands dP/dy1 into the cubic lambda_r of eq. 5b; the
two differ by O(phi^4), ~1e-8 m here) and differentiate V by hand:

    dV/dx1 = k1 x1 + k2 (x1 + y1) + k3 dl3 x1 / r
    dV/dy1 = k2 (x1 + y1) + k3 dl3 + M g (l/r) sin(pi/4 + y1/r)

Kinetic energy with phi = y1/r gives the mass matrix diag(m, J/r^2). Non-conservative
forces from the virtual work (3): the friction F on x1, the pivot torque Q on phi
(-Q/r on y1), and the dampers c1 (on z1 = x1 + y1) and c2 (on y1). Euler-Lagrange (4):

    m x1''       = -c1 z1' - dV/dx1 - F
    J/r^2 y1''   = -c1 z1' - c2 y1' - dV/dy1 - Q/r

which is eq. (5a)/(5b) with lambda_r = (l/r) sin(pi/4 + phi). Normal load, eq. (6):
N = m g + M g lambda_r - k3 dl3 - c2 y1'. Friction F = mu(V_rel) N with law (7) as
printed, V_rel = x1' - v_b:

    mu = mu0 / (1 + gamma |V|) * (1 + beta / cosh(alpha V)) * tanh(alpha V)

where the hidden effects of :mod:`.effects` enter (static peak = the beta term).
Integrated by scipy's adaptive ``solve_ivp`` (RK45 by default) with dense output
sampled at the sensor instants; the command's slope kinks (lead-in end, belt stop)
restart the integrator.

State: x1, x1', y1, y1', T [K], theta_s (Dieterich) [s], q (load rate) [N/s],
a_f (filtered body acceleration) [m/s^2], v_lag, v_lag' (drive), s (belt travel) [m].
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy import optimize
from scipy.integrate import solve_ivp
from scipy.linalg import eigh

from . import effects as fx

RIG = "brake-2dof"
STATE = ("x1", "x1_dot", "y1", "y1_dot", "temp_K", "theta_s", "q", "acc_f", "v_lag", "v_lag_dot", "travel")
N_STATE = len(STATE)
# absolute tolerances per state (the error norm's scale): 1e-9 m on positions, i.e. 1/5000 of
# the laser's noise; the effect states have their own scales
ATOL = np.array([1e-9, 1e-7, 1e-9, 1e-7, 1e-6, 1e-6, 1e-3, 1e-4, 1e-8, 1e-6, 1e-8])


@dataclass
class BrakeParams:
    M: float
    m: float
    J: float
    r: float
    k1: float
    k2: float
    k3: float
    g: float
    mu0: float
    gamma: float
    alpha: float
    beta: float
    c1: float
    c2: float
    T_amb_K: float
    r_thermal: float
    tau_thermal: float
    v_stick: float
    eta: float = 0.5  # share of the frictional power that heats the block's contact (Blok partition)
    exact_gravity: bool = True  # P(phi) exact; False: the paper's cubic lambda_r of eq. (5b)

    @property
    def l(self) -> float:
        return 3.0 * math.sqrt(2.0) / 4.0 * self.r


def params_from_config(cfg: dict) -> BrakeParams:
    mech, fr, ct = cfg["mechanics"], cfg["friction"], cfg["contact"]
    vd = cfg.get("seed_effects", {}).get("viscous-damping", {})
    return BrakeParams(
        M=mech["M_kg"], m=mech["m_kg"], J=mech["J_kg_m2"], r=mech["r_m"],
        k1=mech["k1_N_per_m"], k2=mech["k2_N_per_m"], k3=mech["k3_N_per_m"], g=mech["g_m_per_s2"],
        mu0=fr["mu0"], gamma=fr["gamma_s_per_m"], alpha=fr["alpha_s_per_m"], beta=fr["beta"],
        c1=float(vd.get("c1", 0.0)), c2=float(vd.get("c2", 0.0)),
        T_amb_K=ct["t_ambient_C"] + fx.KELVIN, r_thermal=ct["r_thermal_K_per_W"], tau_thermal=ct["tau_thermal_s"],
        v_stick=ct["v_stick_m_per_s"],
    )


def mu_law7(v: float, mu0: float, gamma: float, alpha: float, beta: float) -> float:
    """Paper 001 eq. (7) as printed."""
    av = alpha * v
    sech = 1.0 / math.cosh(av) if abs(av) < 700.0 else 0.0
    return mu0 / (1.0 + gamma * abs(v)) * (1.0 + beta * sech) * math.tanh(av)


@dataclass
class Trajectory:
    t: np.ndarray
    y: np.ndarray  # (n, N_STATE)
    aux: dict[str, np.ndarray]
    nfev: int
    wall_s: float = 0.0


def integrate(rhs, y0, t_eval, kinks, atol, *, rtol: float = 1e-7, method: str = "RK45",
              max_step: float = 1e-3) -> tuple[np.ndarray, int, float]:
    """solve_ivp from t = 0 over the sorted instants t_eval, restarted at the drive's kinks.

    Returns (states (n, n_state), right-hand-side evaluations, wall seconds). Dense output
    (solve_ivp's own interpolant) gives the states at the sensor instants.
    """
    t_eval = np.asarray(t_eval, dtype=float)
    t_end = float(t_eval[-1])
    y = np.array(y0, dtype=float)
    bounds = [0.0, *[k for k in kinks if 0.0 < k < t_end], t_end]
    out = np.empty((t_eval.size, y.size))
    nfev = 0
    w0 = time.perf_counter()
    for a, b in itertools.pairwise(bounds):
        last = b == t_end
        sel = (t_eval >= a) & ((t_eval <= b) if last else (t_eval < b))
        te = t_eval[sel]
        if not last:  # also the piece's end: the next piece starts from its exact state
            te = np.append(te, b)
        sol = solve_ivp(rhs, (a, b), y, method=method, t_eval=te, rtol=rtol, atol=atol, max_step=max_step)
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed at t={sol.t[-1] if sol.t.size else a}: {sol.message}")
        out[sel] = sol.y.T[: int(sel.sum())]
        y = sol.y[:, -1].copy()
        nfev += sol.nfev
    return out, nfev, time.perf_counter() - w0


class ReferenceRig:
    """What both reference rigs share: integration over the sample instants, the contact quantities along it.
    A rig defines ``atol`` (per state), ``drive``, ``initial_state()``, ``rhs(t, y)`` and ``_eval(t, y, full)``."""

    atol: np.ndarray
    rig: str

    def __init__(self, cfg: dict | None = None, effects=(), drive: fx.Drive | None = None, params=None) -> None:
        self.cfg = cfg if cfg is not None else fx.load_config(self.rig)
        self.fx = effects if isinstance(effects, fx.EffectSet) else fx.EffectSet.parse(effects, self.rig)
        self.drive = drive or fx.default_drive(self.cfg)
        self.p = params or self.params_from_config(self.cfg)
        self._bind_shared()
        self._bind()

    @staticmethod
    def params_from_config(cfg: dict):
        raise NotImplementedError

    def _bind(self) -> None:
        """The rig's own parameters the right-hand side reads (plain floats)."""

    def _bind_shared(self) -> None:
        """The effects' parameters both rigs read alike (plain floats)."""
        p, e = self.p, self.fx
        self.sl = e.get("stick-log")
        self.sc = e.get("stick-creep")
        self.ab = e.get("accel-body")
        ar = e.get("arrhenius")
        self.ar_E = ar["E"]
        self.ar_Tref = (ar["T_ref_C"] + fx.KELVIN) if math.isfinite(ar["T_ref_C"]) else p.T_amb_K
        self.bd = e.get("belt-drive")
        self.fr = e.get("force-rate-pow")
        self.vs_D = e.get("vel-strength")["D"]
        self.wv = e.get("waviness")
        self.br_eps = e.get("bearing")["eps"]
        self.C_th = p.tau_thermal / p.r_thermal  # heat capacity [J/K]

    def aging(self, th: float) -> float:
        """The static peak's aging factor on the stick-time clock th (stick-log on Dieterich's state, or
        stick-creep on the creep clock: one at a time, they share the slot)."""
        if self.sc["b"] != 0.0:
            return fx.dieterich_factor(th, self.sc["b"], self.sc["theta"])
        return fx.dieterich_factor(th, self.sl["b"], self.sl["theta"])

    def clock_rate(self, th: float, v_rel: float) -> float:
        """d/dt of the stick-time clock: the creep clock with stick-creep on, Dieterich's aging law otherwise."""
        if self.sc["b"] != 0.0:
            return fx.creep_clock_rate(th, v_rel, self.sc["v_c"], self.sc["L_r"])
        return fx.dieterich_rate(th, v_rel, self.sl["Dc"])

    def clock_start(self, v0: float) -> float:
        """The clock at t = 0: steady sliding on a running belt, or 1 s of contact age at rest."""
        if v0 == 0.0:
            return 1.0
        if self.sc["b"] != 0.0:
            return fx.creep_clock_steady(v0, self.sc["v_c"], self.sc["L_r"])
        return self.sl["Dc"] / abs(v0)

    def _drive_base(self, t: float, vl: float, vld: float):
        """The drive before its ripple: (commanded speed, lagged or commanded speed, rates of the lag's states)."""
        v_cmd = self.drive.command(t)
        bd = self.bd
        if bd["tau"] > 0.0:
            return v_cmd, vl, *fx.drive_rates(v_cmd, vl, vld, bd["tau"], bd["zeta"])
        return v_cmd, v_cmd, 0.0, 0.0

    def simulate(self, t_eval: np.ndarray, *, rtol: float = 1e-7, atol_scale: float = 1.0,
                 method: str = "RK45", max_step: float = 1e-3, y0: np.ndarray | None = None) -> Trajectory:
        """Integrate from t = 0 and return the states (and contact quantities) at the sorted instants t_eval."""
        y0 = self.initial_state() if y0 is None else y0
        y, nfev, wall = integrate(self.rhs, y0, t_eval, self.drive.kinks(float(t_eval[-1])), self.atol * atol_scale,
                                  rtol=rtol, method=method, max_step=max_step)
        return Trajectory(np.asarray(t_eval, dtype=float), y, self.aux(t_eval, y), nfev, wall)

    def aux(self, t: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
        rows = [self._eval(float(ti), yi, full=True)[1] for ti, yi in zip(t, y)]
        return {k: np.array([r[k] for r in rows]) for k in rows[0]}


class BrakeRig(ReferenceRig):
    """The brake-2dof rig with hidden effects, driven by a :class:`effects.Drive`."""

    atol, rig, params_from_config = ATOL, RIG, staticmethod(params_from_config)

    def _bind(self) -> None:
        p, e = self.p, self.fx
        st = e.get("stiffness")
        self.k1 = p.k1 * (1.0 + st["k1"])
        self.k2 = p.k2 * (1.0 + st["k2"])
        self.k3 = p.k3 * (1.0 + st["k3"])
        self.br_T = e.get("bearing")["torque"]

    # -- conservative part: V and its derivatives (hand-derived, checked by the tests) ----
    def lam(self, y1: float) -> float:
        """lambda_r: the angular body's gravity lever (eq. 5b), exact or the paper's cubic."""
        p = self.p
        u = y1 / p.r
        if p.exact_gravity:
            return p.l / p.r * math.sin(math.pi / 4 + u)
        return math.sqrt(2.0) * p.l / (2 * p.r) * (1.0 + u - u * u / 2.0 - u ** 3 / 6.0)

    def potential(self, x1, y1):
        p = self.p
        d3 = y1 + x1 * x1 / (2 * p.r)
        if p.exact_gravity:
            grav = p.M * p.g * p.l * (1.0 - np.cos(np.pi / 4 + y1 / p.r))
        else:
            u = y1 / p.r
            grav = p.M * p.g * math.sqrt(2) * p.l / 2 * (u + u ** 2 / 2 - u ** 3 / 6 - u ** 4 / 24)
        return 0.5 * self.k1 * x1 ** 2 + 0.5 * self.k2 * (x1 + y1) ** 2 + 0.5 * self.k3 * d3 ** 2 + grav

    def grad_potential(self, x1: float, y1: float) -> tuple[float, float]:
        p = self.p
        d3 = y1 + x1 * x1 / (2 * p.r)
        z1 = x1 + y1
        gx = self.k1 * x1 + self.k2 * z1 + self.k3 * d3 * x1 / p.r
        gy = self.k2 * z1 + self.k3 * d3 + p.M * p.g * self.lam(y1)
        return gx, gy

    def hessian(self, x1: float, y1: float) -> np.ndarray:
        p = self.p
        d3 = y1 + x1 * x1 / (2 * p.r)
        if p.exact_gravity:
            dlam = p.l / p.r ** 2 * math.cos(math.pi / 4 + y1 / p.r)
        else:
            u = y1 / p.r
            dlam = math.sqrt(2) * p.l / (2 * p.r ** 2) * (1 - u - u * u / 2)
        hxx = self.k1 + self.k2 + self.k3 * (x1 * x1 / p.r ** 2 + d3 / p.r)
        hxy = self.k2 + self.k3 * x1 / p.r
        hyy = self.k2 + self.k3 + p.M * p.g * dlam
        return np.array([[hxx, hxy], [hxy, hyy]])

    def mass_matrix(self) -> np.ndarray:
        return np.diag([self.p.m, self.p.J / self.p.r ** 2])

    def energy(self, y: np.ndarray) -> np.ndarray:
        """Mechanical energy T + V along states y (..., N_STATE)."""
        x1, v1, y1, w1 = y[..., 0], y[..., 1], y[..., 2], y[..., 3]
        return 0.5 * self.p.m * v1 ** 2 + 0.5 * self.p.J / self.p.r ** 2 * w1 ** 2 + self.potential(x1, y1)

    def equilibrium(self) -> tuple[float, float]:
        """Friction-free static equilibrium: grad V = 0 (Newton with the analytic Hessian)."""
        sol = optimize.root(lambda q: self.grad_potential(q[0], q[1]), x0=[0.0, 0.0],
                            jac=lambda q: self.hessian(q[0], q[1]), method="hybr", tol=1e-15)
        return float(sol.x[0]), float(sol.x[1])

    def linear_modes(self, about: str = "equilibrium") -> np.ndarray:
        """Eigenfrequencies [Hz] of the linearised conservative system, K v = w^2 M v."""
        q = self.equilibrium() if about == "equilibrium" else (0.0, 0.0)
        w2 = eigh(self.hessian(*q), self.mass_matrix(), eigvals_only=True)
        return np.sqrt(w2) / (2 * math.pi)

    def normal_load(self, x1: float, y1: float, y1d: float) -> float:
        """Eq. (6) divided by mu."""
        p = self.p
        d3 = y1 + x1 * x1 / (2 * p.r)
        return p.m * p.g + p.M * p.g * self.lam(y1) - self.k3 * d3 - p.c2 * y1d

    # -- the right-hand side ------------------------------------------------------------
    def _eval(self, t: float, s, full: bool = False):
        p = self.p
        x1, v1, y1, w1, T, th, q, af, vl, vld, trav = s
        v_cmd, v_base, d_vl, d_vld = self._drive_base(t, vl, vld)
        bd = self.bd
        vb = v_base * fx.belt_ripple(trav, bd["ripple"], bd["wavelength"], bd["h2"])
        v_rel = v1 - vb

        n = self.normal_load(x1, y1, w1)
        peak = p.beta * self.aging(th) \
            * fx.power_rate_factor(q, self.fr["g"], self.fr["q0"], self.fr["n"])
        mu = mu_law7(v_rel, p.mu0, p.gamma, p.alpha, peak)
        mu = mu * fx.arrhenius_factor(T, self.ar_E, self.ar_Tref)
        mu = mu * (1.0 + self.wv["w"] * math.sin(2.0 * math.pi * trav / self.wv["wavelength"]))
        mu = mu + self.vs_D * v_rel
        mu = mu * (1.0 + self.ab["amp"] * math.tanh(af / self.ab["a0"]))
        f = mu * n

        gx, gy = self.grad_potential(x1, y1)
        zd = v1 + w1
        ax = (-p.c1 * zd - gx - f) / p.m
        q_piv = self.br_T * fx.smooth_sgn_atan(w1 / p.r, self.br_eps)
        ay = (-p.c1 * zd - p.c2 * w1 - gy - q_piv / p.r) * p.r ** 2 / p.J

        power = abs(f * v_rel)
        d_T = (p.eta * power - (T - p.T_amb_K) / p.r_thermal) / self.C_th
        d_th = self.clock_rate(th, v_rel)
        # d/dt of the spring load the contact holds: (d2V/dx1^2) x1' + (d2V/dx1 dy1) y1'
        d3 = y1 + x1 * x1 / (2 * p.r)
        load_rate = (self.k1 + self.k2 + self.k3 * (x1 * x1 / p.r ** 2 + d3 / p.r)) * v1 \
            + (self.k2 + self.k3 * x1 / p.r) * w1
        d_q = fx.lorentz_stuck(v_rel, p.v_stick) * (load_rate - q) / self.fr["tau_q"]
        d_af = (ax - af) / self.ab["tau_a"]
        ds = (v1, ax, w1, ay, d_T, d_th, d_q, d_af, d_vl, d_vld, vb)
        if not full:
            return ds
        return ds, {"friction_force": f, "normal_load": n, "mu": mu, "v_rel": v_rel, "vb": vb, "vb_set": v_cmd,
                    "acc": ax, "acc_y": ay}

    def rhs(self, t: float, s) -> tuple:
        return self._eval(t, s)

    # -- integration ----------------------------------------------------------------------
    def initial_state(self) -> np.ndarray:
        """Block and angular body at rest at the friction-free equilibrium; belt at its command."""
        x1, y1 = self.equilibrium()
        v0 = self.drive.command(0.0)
        s = np.zeros(N_STATE)
        s[0], s[2] = x1, y1
        s[4] = self.p.T_amb_K
        s[5] = self.clock_start(v0)
        s[8] = v0
        return s

    def true_channels(self, tr: Trajectory) -> dict[str, np.ndarray]:
        """What the interchange channels read, without instrument errors."""
        return {"x1": tr.y[:, 0], "phi": tr.y[:, 2] / self.p.r, "vb": tr.aux["vb"], "vb_set": tr.aux["vb_set"],
                "temp": tr.y[:, 4] - fx.KELVIN}

    def truth(self, tr: Trajectory) -> dict[str, np.ndarray]:
        return {"x1_dot": tr.y[:, 1], "y1": tr.y[:, 2], "y1_dot": tr.y[:, 3], "friction_force": tr.aux["friction_force"],
                "normal_load": tr.aux["normal_load"], "mu": tr.aux["mu"], "v_rel": tr.aux["v_rel"],
                "theta_s": tr.y[:, 5], "belt_travel": tr.y[:, 10]}
