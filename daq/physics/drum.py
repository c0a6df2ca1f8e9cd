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

from .contact import AUX
from .effects import (
    DC_MIN,
    TAIL,
    E,
    accel_sign_weight,
    aging_log,
    arrhenius_factor,
    body_accel_factor,
    dieterich_rate,
    drive_speed,
    env_rates,
    normal_load,
    ramp_eval,
    smooth_sign,
    static_factor,
    stick_rates_if_read,
    temperature_factor,
    user_mu_factor,
)
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
    phi, w = s[0], s[1]
    ts, q, temp = s[N_MECH + TAIL.TS], s[N_MECH + TAIL.Q], s[N_MECH + TAIL.TEMP]
    v_lag, pos = s[N_MECH + TAIL.VLAG], s[N_MECH + TAIL.POS]
    R, I0, k, Rs = p[P.R], p[P.I0], p[P.k], p[P.Rs]
    amp = e[E.AS_AMP]

    v_cmd, dv_cmd = ramp_eval(rt, rv, t)
    vd, dvd = drive_speed(v_cmd, dv_cmd, v_lag, pos, e[E.VB_TAU], e[E.VB_RIPPLE], e[E.VB_WAVELEN])
    v_rel = R * w - vd

    n_inst = p[P.P] * (1.0 + p[P.RUNOUT] * math.sin(pos / R))  # drum angle = travel / R
    n = normal_load(n_inst, p[P.P], e[E.NL_WEIGHT])
    spring = k * Rs * math.sin(phi)  # S, what strain gauge A reads

    sf = static_factor(ts, q, e[E.ST_GAIN], e[E.ST_TAU], e[E.FR_GAIN], e[E.FR_Q0])
    sf += aging_log(ts, e[E.ST_LOG_GAIN], e[E.ST_TAU])
    mu = mu_drum(v_rel, p[P.A], p[P.B], p[P.C], p[P.E0], p[P.EPS], sf)
    tf = temperature_factor(temp, e[E.TEMP_COEF], e[E.TEMP_REF]) * arrhenius_factor(temp, e[E.TEMP_ARR], e[E.TEMP_REF])
    mu = mu * tf + e[E.VS_D] * v_rel
    mu = mu * user_mu_factor(v_rel, t, temp, pos, ts, e[E.USER0], e[E.USER1], e[E.USER2], e[E.USER3])
    f = mu * n

    z = n_inst + spring * math.sin(phi) - p[P.m] * p[P.Rc] * w * w  # bearing thrust, eq. (1) row 1
    torque = -spring * Rs * math.cos(phi) - e[E.C_PHI] * w
    torque -= e[E.BF_MU1] * z * p[P.r0] * smooth_sign(w, e[E.BF_EPS])
    if amp != 0.0:
        sg = 1.0 if v_rel > 0.0 else (-1.0 if v_rel < 0.0 else 0.0)
        a_plus = R * (torque - f * (1.0 + amp) * R) / I0
        a_minus = R * (torque - f * (1.0 - amp) * R) / I0
        wsel = accel_sign_weight(sg, a_plus, a_minus, dvd)
        f = f * (1.0 + amp * wsel)
        mu = mu * (1.0 + amp * wsel)
    amp_b = e[E.AS_BODY_AMP]
    if amp_b != 0.0:  # the body form: a smooth switch on the pendulum's acceleration at the contact (R phi'')
        fb = body_accel_factor(torque / R, f, R * R / I0, amp_b, e[E.AS_BODY_A0])
        f = f * fb
        mu = mu * fb
    acc = (torque - f * R) / I0

    load_rate = k * Rs * Rs * math.cos(2.0 * phi) * w / R  # d/dt of spring torque / R
    d_ts, d_q = stick_rates_if_read(v_rel, load_rate, ts, q, abs(e[E.ST_GAIN]) + abs(e[E.ST_LOG_GAIN]), e[E.FR_GAIN],
                                    e[E.V_STICK],
                                    e[E.FR_TAU], e[E.ST_RESET])
    if e[E.ST_DC] > 0.0 and e[E.ST_LOG_GAIN] != 0.0:  # the log form with Dieterich's state for its clock
        d_ts = dieterich_rate(v_rel, ts, max(e[E.ST_DC], DC_MIN))
    d_temp, d_lag, d_pos = env_rates(f * v_rel, v_cmd, vd, t, temp, v_lag, e[E.T_AMB], e[E.TH_DRIFT],
                                     e[E.TH_R], e[E.TH_TAU], e[E.VB_TAU])
    ds[0] = w
    ds[1] = acc
    ds[N_MECH + TAIL.TS] = d_ts
    ds[N_MECH + TAIL.Q] = d_q
    ds[N_MECH + TAIL.TEMP] = d_temp
    ds[N_MECH + TAIL.VLAG] = d_lag
    ds[N_MECH + TAIL.POS] = d_pos
    ds[N_MECH + TAIL.PSI] = 0.0  # rate-and-state is belt-ndof's (one mass)
    aux[AUX.F] = f
    aux[AUX.N] = n
    aux[AUX.MU] = mu
    aux[AUX.V_DRIVE] = vd
    aux[AUX.V_CMD] = v_cmd
    aux[AUX.V_REL] = v_rel
    aux[AUX.N_INST] = n_inst
    aux[AUX.ACC] = R * acc


def energy(states: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Kinetic plus spring energy: conserved with friction, bearing and damping off."""
    phi, w = states[..., 0], states[..., 1]
    # potential of k Rs^2 sin cos: (k Rs^2 / 2) sin^2 phi
    return 0.5 * p[P.I0] * w**2 + 0.5 * p[P.k] * p[P.Rs] ** 2 * np.sin(phi) ** 2


def linear_modes(p: np.ndarray) -> np.ndarray:
    """Small-angle natural frequency [Hz]: sqrt(k Rs^2 / I0) / 2 pi."""
    return np.array([math.sqrt(p[P.k] * p[P.Rs] ** 2 / p[P.I0]) / (2 * math.pi)])
