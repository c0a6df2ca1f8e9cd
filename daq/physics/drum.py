"""drum-pendulum: pendulum pressed against the inside of a rotating drum (paper 002, eqs. 1-3).

State: phi, phi_dot, then the contact tail (travel = drum surface travel [m]).
Equation (SPEC form of eq. 1 with delta = 0, our choice):
    I0 phi'' = -k Rs^2 sin(phi) cos(phi) - F R - mu1 Z r0 sgn(phi') - c phi'
with F = mu(V_rel) N the friction force on the pendulum's contact, V_rel = R phi' - v_drum
(body minus drive, the paper's v_wz with opposite sign), so -F R equals the paper's
+mu N R sgn(v_wz). The bearing thrust follows eq. (1) row 1 with delta = 0:
Z = N + S sin(phi) - m Rc phi'^2. The thrust gauge reads N = P (1 + runout sin(theta))
where theta is the drum angle: a drum out of round by a few percent (chosen) is what
makes the normal load vary, so the normal-load effect has something to follow.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np

from . import effects
from .contact import set_aux
from .effects import TAIL, E, user_mu_factor
from .friction import mu_drum
from .jit import kernel

RIG_ID = "drum-pendulum"
N_MECH = 2
N_STATE = N_MECH + len(TAIL)


class P(IntEnum):
    I0 = 0  # pendulum inertia about the drum axis [kg m^2]
    k = 1  # spring stiffness [N/m]
    Rs = 2  # spring attachment radius [m]
    R = 3  # friction radius (drum inner radius) [m]
    r0 = 4  # bearing radius [m]
    m = 5  # pendulum mass [kg]
    Rc = 6  # radius of the mass centre [m]
    P = 7  # nominal thrust [N]
    RUNOUT = 8  # relative thrust variation per drum revolution [-]
    A = 9
    B = 10  # [s/m]
    C = 11  # [s/m]
    E0 = 12  # law (3) coefficient E
    EPS = 13  # sgn regularisation speed [m/s]


N_P = len(P)


@kernel
def rhs(t, s, p, e, rt, rv, ds, aux):
    """Eq. (1) with the effects of the catalog (effects.py's chain); fills ds and aux."""
    phi, w = s[0], s[1]
    ts, q, temp, v_lag, pos = effects.contact_tail(s, N_MECH)
    R, I0, k, Rs = p[P.R], p[P.I0], p[P.k], p[P.Rs]

    v_cmd, vd, dvd = effects.drive_at(t, v_lag, pos, e, rt, rv, False)
    v_rel = R * w - vd

    n_inst = p[P.P] * (1.0 + p[P.RUNOUT] * math.sin(pos / R))  # drum angle = travel / R
    spring = k * Rs * math.sin(phi)  # S, what strain gauge A reads

    mu = mu_drum(v_rel, p[P.A], p[P.B], p[P.C], p[P.E0], p[P.EPS], effects.peak_factor(ts, q, e))
    user = user_mu_factor(v_rel, t, temp, pos, ts, e[E.USER0], e[E.USER1], e[E.USER2], e[E.USER3])
    f, mu, n = effects.friction_force(mu, effects.mu_factor(temp, e), n_inst, p[P.P], v_rel, user, e)

    z = n_inst + spring * math.sin(phi) - p[P.m] * p[P.Rc] * w * w  # bearing thrust, eq. (1) row 1
    torque = -spring * Rs * math.cos(phi) - e[E.C_PHI] * w
    torque -= effects.bearing(e[E.BF_MU1] * z * p[P.r0], w, e[E.BF_EPS])
    # at the contact (R phi''): every other force torque / R on the inertia I0 / R^2
    f, mu = effects.accel_sign(f, mu, torque / R, R * R / I0, v_rel, dvd, e)
    acc = (torque - f * R) / I0

    load_rate = k * Rs * Rs * math.cos(2.0 * phi) * w / R  # d/dt of spring torque / R
    d_ts, d_q = effects.stick_clock_rates(v_rel, load_rate, ts, q, e)
    env = effects.environment_rates(f * v_rel, v_cmd, vd, t, temp, v_lag, e)
    effects.set_tail(ds, N_MECH, d_ts, d_q, 0.0, env)
    ds[0] = w
    ds[1] = acc
    set_aux(aux, f, n, mu, vd, v_cmd, v_rel, n_inst, R * acc)


def energy(states: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Kinetic plus spring energy: conserved with friction, bearing and damping off."""
    phi, w = states[..., 0], states[..., 1]
    # potential of k Rs^2 sin cos: (k Rs^2 / 2) sin^2 phi
    return 0.5 * p[P.I0] * w**2 + 0.5 * p[P.k] * p[P.Rs] ** 2 * np.sin(phi) ** 2


def linear_modes(p: np.ndarray) -> np.ndarray:
    """Small-angle natural frequency [Hz]: sqrt(k Rs^2 / I0) / 2 pi."""
    return np.array([math.sqrt(p[P.k] * p[P.Rs] ** 2 / p[P.I0]) / (2 * math.pi)])
