"""brake-2dof: block on a decelerating belt coupled to an angular body (paper 001, eqs. 5-7, 10).

State: x1, x1_dot, y1, y1_dot (y1 = r phi), then the contact tail (effects.TAIL).
The printed equations are used as they are; effects scale their terms:
``geometric`` scales the x1^2/2r terms and the angular body's gravity M g lambda_r
(0 gives the linear model of the paper's ref. [21]); ``normal-load`` blends the
friction's normal load between its nominal static value and eq. (6).
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np
from scipy import optimize
from scipy.linalg import eigh

from . import effects
from .contact import N_AUX, set_aux
from .effects import N_E, TAIL, E, user_mu_factor
from .friction import mu_brake
from .jit import helper, kernel

RIG_ID = "brake-2dof"
N_MECH = 4
N_STATE = N_MECH + len(TAIL)


class P(IntEnum):
    """Mechanics/law parameter vector of brake-2dof."""

    M = 0  # angular body mass [kg]
    m = 1  # block mass [kg]
    J = 2  # angular body moment of inertia about S [kg m^2]
    r = 3  # arm radius [m]
    k1 = 4
    k2 = 5
    k3 = 6  # [N/m]
    g = 7  # [m/s^2]
    lam0 = 8  # sqrt(2) l / (2 r), with l = 3 sqrt(2)/4 r -> 3/4
    mu0 = 9
    gamma = 10  # [s/m]
    alpha = 11  # [s/m]
    beta = 12
    N_NOM = 13  # nominal normal load (static equilibrium without friction) [N]
    INV_m = 14  # derived: 1/m, r^2/J, 1/r (the hot loop multiplies instead of dividing)
    R2_J = 15
    INV_r = 16


N_P = len(P)


@helper
def lambda_r(y1, r, lam0):
    """lambda_r of eq. (5b): gravity lever of the angular body, a cubic in y1/r."""
    u = y1 / r
    return lam0 * (1.0 + u - 0.5 * u * u - u * u * u / 6.0)


@kernel
def rhs(t, s, p, e, rt, rv, ds, aux):
    """Eqs. (5a), (5b), (6), (7) with the effects of the catalog (effects.py's chain); fills ds and aux."""
    m, r, k1, k2, k3, g = p[P.m], p[P.r], p[P.k1], p[P.k2], p[P.k3], p[P.g]
    x1, x2, y1, y2 = s[0], s[1], s[2], s[3]
    ts, q, temp, v_lag, pos = effects.contact_tail(s, N_MECH)
    gw, c1, c2 = e[E.GEO_WEIGHT], e[E.C1], e[E.C2]

    v_cmd, vb, dvb = effects.drive_at(t, v_lag, pos, e, rt, rv, False)
    v_rel = x2 - vb

    inv_m, inv_r = p[P.INV_m], p[P.INV_r]
    d3 = y1 + gw * x1 * x1 * 0.5 * inv_r  # elongation of k3, eq. (1c)
    grav = gw * p[P.M] * g * lambda_r(y1, r, p[P.lam0])
    n_inst = m * g + grav - k3 * d3 - c2 * y2  # eq. (6) divided by mu

    mu = mu_brake(v_rel, p[P.mu0], p[P.gamma], p[P.alpha], p[P.beta] * effects.peak_factor(ts, q, e))
    user = user_mu_factor(v_rel, t, temp, pos, ts, e[E.USER0], e[E.USER1], e[E.USER2], e[E.USER3])
    f, mu, n = effects.friction_force(mu, effects.mu_factor(temp, e), n_inst, p[P.N_NOM], v_rel, user, e)

    z2 = x2 + y2
    g_block = -c1 * z2 - (k1 + k2) * x1 - k2 * y1 - gw * k3 * x1 * inv_r * d3  # eq. (5a) without F
    f, mu = effects.accel_sign(f, mu, g_block, inv_m, v_rel, dvb, e)
    ax = (g_block - f) * inv_m

    q_pivot = effects.bearing(e[E.BF_TORQUE], y2 * inv_r, e[E.BF_EPS])  # Q of eq. (5b)
    ay = (-c1 * z2 - c2 * y2 - k2 * (x1 + y1) - k3 * d3 - grav - q_pivot * inv_r) * p[P.R2_J]

    load_rate = (k1 + k2) * x2 + k2 * y2  # rate of the spring load the contact must hold
    d_ts, d_q = effects.stick_clock_rates(v_rel, load_rate, ts, q, e)
    env = effects.environment_rates(f * v_rel, v_cmd, vb, t, temp, v_lag, e)
    effects.set_tail(ds, N_MECH, d_ts, d_q, 0.0, env)
    ds[0] = x2
    ds[1] = ax
    ds[2] = y2
    ds[3] = ay
    set_aux(aux, f, n, mu, vb, v_cmd, v_rel, n_inst, ax)


def derive(p: np.ndarray) -> np.ndarray:
    """Fill the derived slots (reciprocals) from the physical ones; call after changing m, J or r."""
    p[P.INV_m] = 1.0 / p[P.m]
    p[P.R2_J] = p[P.r] ** 2 / p[P.J]
    p[P.INV_r] = 1.0 / p[P.r]
    return p


def potential(x1, y1, p: np.ndarray, geo_weight: float):
    """Potential energy whose gradient gives the conservative part of eqs. (5a)-(5b)."""
    r = p[P.r]
    d3 = y1 + geo_weight * x1 * x1 / (2.0 * r)
    grav = geo_weight * p[P.M] * p[P.g] * p[P.lam0] * (
        y1 + y1**2 / (2 * r) - y1**3 / (6 * r**2) - y1**4 / (24 * r**3)
    )
    return 0.5 * p[P.k1] * x1**2 + 0.5 * p[P.k2] * (x1 + y1) ** 2 + 0.5 * p[P.k3] * d3**2 + grav


def energy(states: np.ndarray, p: np.ndarray, geo_weight: float) -> np.ndarray:
    """Total mechanical energy (kinetic with masses m and J/r^2, plus potential)."""
    x1, x2, y1, y2 = states[..., 0], states[..., 1], states[..., 2], states[..., 3]
    kin = 0.5 * p[P.m] * x2**2 + 0.5 * p[P.J] / p[P.r] ** 2 * y2**2
    return kin + potential(x1, y1, p, geo_weight)


def equilibrium(p: np.ndarray, geo_weight: float) -> tuple[float, float]:
    """Static equilibrium (x1, y1) without friction: where eqs. (5a)/(5b) give zero acceleration."""

    pp = p.copy()
    pp[P.mu0] = 0.0
    derive(pp)
    e = np.zeros(N_E)
    e[E.GEO_WEIGHT] = geo_weight
    e[E.V_STICK] = e[E.TH_TAU] = e[E.FR_TAU] = e[E.ST_RESET] = 1.0
    rt = np.array([0.0, 1.0])
    rv = np.zeros(2)
    s = np.zeros(N_STATE)
    ds = np.empty(N_STATE)
    aux = np.empty(N_AUX)

    def acc(q):
        s[0], s[2] = q
        rhs(0.0, s, pp, e, rt, rv, ds, aux)
        return [ds[1], ds[3]]

    sol = optimize.root(acc, x0=[0.0, 0.0], method="hybr", tol=1e-14)
    return float(sol.x[0]), float(sol.x[1])


def nominal_normal_load(p: np.ndarray, geo_weight: float) -> float:
    """Eq. (6) times 1/mu at the friction-free static equilibrium: the 'constant' normal load."""
    x1, y1 = equilibrium(p, geo_weight)
    r = p[P.r]
    d3 = y1 + geo_weight * x1 * x1 / (2 * r)
    grav = geo_weight * p[P.M] * p[P.g] * lambda_r(y1, r, p[P.lam0])
    return float(p[P.m] * p[P.g] + grav - p[P.k3] * d3)


def linear_modes(p: np.ndarray, geo_weight: float, about: str = "equilibrium") -> np.ndarray:
    """Eigenfrequencies [Hz] of the conservative system linearised with masses m and J/r^2.

    ``about`` = "equilibrium" (gravity-loaded) or "origin" (y1 = 0, as the paper seems to).
    The stiffness is the Hessian of :func:`potential`, taken by central differences.
    """
    x0, y0 = equilibrium(p, geo_weight) if about == "equilibrium" else (0.0, 0.0)
    h = 1e-6
    q0 = np.array([x0, y0])
    kmat = np.zeros((2, 2))
    for i in range(2):
        for j in range(2):
            def v(di, dj):
                q = q0.copy()
                q[i] += di
                q[j] += dj
                return potential(q[0], q[1], p, geo_weight)
            kmat[i, j] = (v(h, h) - v(h, -h) - v(-h, h) + v(-h, -h)) / (4 * h * h)
    mmat = np.diag([p[P.m], p[P.J] / p[P.r] ** 2])

    w2 = eigh(kmat, mmat, eigvals_only=True)
    return np.sqrt(np.abs(w2)) / (2 * math.pi)


def mu_effective(mu, p: np.ndarray):
    """Paper 001 eq. (10): steady-state effective coefficient F/(m g) including the angular body."""
    M, m, r, g = p[P.M], p[P.m], p[P.r], p[P.g]
    k1, k2, k3 = p[P.k1], p[P.k2], p[P.k3]
    kap3 = 3 * M * g * (k1 + k2) + 4 * r * (k2 * k3 + k1 * (k2 + k3))
    kap1 = 3 * M * r * (k1 * k2 + 2 * (k1 + k2) * k3) / (m * kap3)
    kap2 = (4 * r * k2 * k3 - 3 * M * g * k2) / kap3
    return (1 + kap1) * mu / (1 + kap2 * mu)
