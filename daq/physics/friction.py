"""Friction laws of the three seed papers, as pure functions of relative velocity.

Written with ``np.*`` and without branches so that one definition serves the
compiled rig equations (scalars) and the analysis code (arrays). Every law is
odd in the relative velocity; the tests check it.

Decision record: docs/decisions/0011-fixed-step-rk4-smooth-laws.md.
"""

from __future__ import annotations

import numpy as np

from .jit import helper


@helper
def mu_brake(v_rel, mu0, gamma, alpha, beta):
    """Paper 001 eq. (7): mu0/(1+gamma|v|) (1 + beta/cosh(alpha v)) tanh(alpha v).

    ``beta`` carries the static peak; the stick-time and force-rate effects scale it.
    tanh and 1/cosh come from one exp(-|alpha v|), clipped at 300 where both are
    exact to double precision, which keeps the hot loop off libm's underflow paths.
    """
    av = np.minimum(np.abs(alpha * v_rel), 300.0)
    q = np.exp(-av)
    q2 = q * q
    tanh = np.sign(v_rel) * (1.0 - q2) / (1.0 + q2)
    sech = 2.0 * q / (1.0 + q2)
    return mu0 / (1.0 + gamma * np.abs(v_rel)) * (1.0 + beta * sech) * tanh


def brake_peak(mu0: float, beta: float, alpha: float) -> tuple[float, float]:
    """Paper 001 eqs. (8)-(9) for gamma = 0: location V* and height mu* of the peak."""
    b0 = np.sqrt(1.0 + 8.0 * beta**2)
    v_star = np.arccosh(4.0 * beta / (b0 - 1.0)) / alpha  # arcsech(x) = arccosh(1/x)
    mu_star = mu0 / (16.0 * beta) * np.sqrt((b0 - 3.0 * beta) / (1.0 - beta)) * (3.0 + b0) * (b0 - 1.0 + 4.0 * beta)
    return float(v_star), float(mu_star)


@helper
def mu_drum(v_rel, a, b, c, e0, eps, peak_scale):
    """Paper 002 eq. (3) applied as mu(|v|) sgn(v): A[1-exp(-B|v|)]exp(-C|v|) + E.

    The paper's D v term is the velocity-strengthening effect and is added by the
    caller. sgn is regularised as tanh(v/eps) because mu(0+) = E != 0 (a static
    jump); the convergence test shrinks eps. ``peak_scale`` multiplies the hump
    (the static/peak part) for the stick-time and force-rate effects.
    """
    av = np.abs(v_rel)
    hump = a * peak_scale * (1.0 - np.exp(-b * av)) * np.exp(-c * av)
    return np.tanh(v_rel / eps) * (hump + e0)


@helper
def f_pwl_kinetic(w, f_k0, k_fall, w_min, k_rise):
    """Paper 000 kinetic characteristic (dimensionless), odd and piecewise linear in w.

    For |w| <= w_min it falls from f_k0 with slope k_fall (negative damping, the
    source of self-excitation); beyond w_min it rises with slope k_rise. This is
    our parametrisation of the shape described in paper 000 (its breakpoints
    live in figures we do not have): a falling then rising line pair.
    """
    aw = np.abs(w)
    fall = f_k0 - k_fall * np.minimum(aw, w_min)
    rise = k_rise * np.maximum(aw - w_min, 0.0)
    return np.sign(w) * (fall + rise)


@helper
def f_pwl_piece(u, growing, f_s, alpha_drop, f_k0, k_fall, w_min, k_rise, amp):
    """Magnitude of the paper 000 law for slip in one direction, u = |w| (continued linearly below 0).

    growing = +1 while |w| increases (after break-away), -1 while it decreases.
    Growing branch: starts at the static limit f_s and drops with slope alpha_drop
    until it meets the kinetic line scaled by (1+amp). Shrinking branch: the kinetic
    line scaled by (1-amp). amp is the accel-sign effect (0 = branches coincide
    apart from the break-away drop). For u < 0 (just past a zero crossing) the pieces
    continue linearly, which is what a hybrid integrator needs to see the crossing.
    """
    kin = f_k0 - k_fall * np.minimum(u, w_min) + k_rise * np.maximum(u - w_min, 0.0)
    up = np.maximum(f_s - alpha_drop * u, (1.0 + amp) * kin)
    down = (1.0 - amp) * kin
    g = (growing + 1.0) * 0.5
    return g * up + (1.0 - g) * down


@helper
def f_pwl(w, growing, f_s, alpha_drop, f_k0, k_fall, w_min, k_rise, amp):
    """Paper 000 law with its two branches for slipping contact (w != 0): odd in w."""
    return np.sign(w) * f_pwl_piece(np.abs(w), growing, f_s, alpha_drop, f_k0, k_fall, w_min, k_rise, amp)
