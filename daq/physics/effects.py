"""The effects' terms, compiled: scalar functions each rig's equations call (numba). The catalog they implement,
its slot names (:class:`E`, :data:`TAIL`) and its specs are data, in :mod:`daq.physics.catalog`, re-exported here.

Decision record: docs/decisions/0001-physics-in-one-place.md.
"""

from __future__ import annotations

import math

import numpy as np

from .catalog import (  # noqa: F401 - re-exported: the rigs' equations read their slots from here
    ALL_RIGS, BEARING_SGN_EPS, CATALOG, DC_MIN, ENVIRONMENT_SLOTS, N_E, N_TAIL, TAIL, E, EffectSpec, FormSpec, ParamSpec,
    VB_TAU_MIN, neutral_vector,
)
from .jit import helper, kernel

# ---------------------------------------------------------------------------
# Terms (compiled): pure scalar functions
#
# Why scalars only: a compiled helper that takes an array and branches pays an
# atomic reference-count pair per call (~20 ns), which dominated the right-hand
# side. Each rig unpacks p, e and s once and passes numbers.
# ---------------------------------------------------------------------------


@helper
def smooth_sign(v: float, eps: float) -> float:
    """tanh(v/eps), the regularised sgn used where the papers write sgn()."""
    if eps <= 0.0:
        return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    return math.tanh(v / eps)


@helper
def bearing(scale: float, v: float, eps: float) -> float:
    """bearing-friction: ``scale`` smooth_sign(v, eps), a pivot's torque (brake-2dof) or its coefficient times load and
    radius (drum-pendulum); 0 without the effect. Why the test: tanh of a moving body's speed went through libm's
    expm1, 14 % of a brake diagnosis's CPU for a term that is 0 times it in every model without the effect
    (perf, 2026-11-28; the same numbers, as 0 x tanh(v) is 0)."""
    if scale == 0.0:
        return 0.0
    return scale * smooth_sign(v, eps)


@helper
def user_mu_factor(v_rel: float, t: float, temp: float, travel: float, stick_clock: float,
                   u0: float, u1: float, u2: float, u3: float) -> float:
    """Hook for a user effect: multiplies the friction coefficient. Built-in: 1 (no user effect).

    A model with a user effect rebinds this name in a copy of the rig's rhs to the
    user's compiled function (daq/models/user_effects.py); the package is not edited.
    """
    return 1.0


@helper
def normal_load(n_inst: float, n_nominal: float, weight: float) -> float:
    """normal-load: blend between the nominal and the instantaneous normal load."""
    return n_nominal + weight * (n_inst - n_nominal)


@helper
def stuck_fraction(v_rel: float, v_stick: float) -> float:
    """Smooth indicator (1 = stuck/creeping, 0 = slipping) used by the stateful static effects."""
    x2 = (v_rel / v_stick) ** 2
    return math.exp(-x2) if x2 < 700.0 else 0.0  # avoid libm's slow underflow path


@helper
def static_factor(ts: float, q: float, st_gain: float, st_tau: float, fr_gain: float, fr_q0: float) -> float:
    """stick-time and force-rate: multiplier on the static (peak) part of a friction law.

    stick-time: 1 + gain (1 - exp(-t_s/tau)) (saturating growth, paper 000 Fig. 11);
    force-rate: + gain ln(1 + |q|/q0) (rate-strengthening of the static limit).
    """
    f = 1.0
    if st_gain != 0.0:
        f += st_gain * (1.0 - math.exp(-max(ts, 0.0) / st_tau))
    if fr_gain != 0.0:
        f += fr_gain * math.log1p(abs(q) / fr_q0)
    return f


@helper
def aging_log(ts: float, gain: float, tau: float) -> float:
    """stick-time, logarithmic form (Dieterich): the term gain ln(1 + t_s/tau) added to the static factor."""
    if gain == 0.0:
        return 0.0
    return gain * math.log1p(max(ts, 0.0) / tau)


@helper
def dieterich_rate(v_rel: float, theta: float, dc: float) -> float:
    """Dieterich's aging law for the contact state: d theta/dt = 1 - |v_rel| theta / Dc (a time in contact that
    grows while the contact barely moves and is wiped out over a slip of a few Dc)."""
    return 1.0 - abs(v_rel) * theta / dc


@helper
def temperature_factor(temp: float, coef: float, ref: float) -> float:
    """temperature: linear sensitivity of the friction coefficient around a reference."""
    return 1.0 + coef * (temp - ref)


@helper
def arrhenius_factor(temp: float, theta: float, ref: float) -> float:
    """temperature, Arrhenius-like form: exp(theta (1/T - 1/T_ref)) with T = temp + 273.15 K."""
    if theta == 0.0:
        return 1.0
    return math.exp(theta * (1.0 / (temp + 273.15) - 1.0 / (ref + 273.15)))


@kernel
def ramp_eval(rt: np.ndarray, rv: np.ndarray, t: float):
    """Piecewise-linear drive programme: value and slope at t (held constant outside the table)."""
    return ramp_eval_side(rt, rv, t, False)


@kernel
def ramp_eval_side(rt: np.ndarray, rv: np.ndarray, t: float, left: bool):
    """ramp_eval, with the slope from the left at a corner when ``left``: what an integrator step that ends on a
    corner must see (the right-hand slope there is the next step's)."""
    n = rt.size
    if t <= rt[0]:
        return rv[0], 0.0
    if t > rt[n - 1] or (t == rt[n - 1] and not left):
        return rv[n - 1], 0.0
    # lo: the last row before t (at t itself when not ``left``); rt[0] is before t and rt[n-1] is not. Why a guess
    # and a walk, not a bisection: a drive table is the record's own time base, evenly spaced, so the row in
    # proportion is the one (a walk of 0-1 rows, where a bisection of a 15 000-row table takes 14 steps: 11 % of the
    # right-hand side of brake-2dof, measured); an uneven table walks further to the same row.
    lo = int((t - rt[0]) / (rt[n - 1] - rt[0]) * (n - 1))
    lo = min(max(lo, 0), n - 2)
    while lo > 0 and not (rt[lo] < t or (rt[lo] == t and not left)):
        lo -= 1
    while lo < n - 2 and (rt[lo + 1] < t or (rt[lo + 1] == t and not left)):
        lo += 1
    hi = lo + 1
    slope = (rv[hi] - rv[lo]) / (rt[hi] - rt[lo])
    return rv[lo] + slope * (t - rt[lo]), slope


@helper
def drive_speed(v_cmd: float, dv_cmd: float, v_lag: float, pos: float, tau: float, ripple: float,
                wavelen: float):
    """belt-speed: actual drive speed and its derivative given the command.

    Returns (v, dv/dt). Without the effect (tau = 0, ripple = 0) the drive follows the command.
    The ripple is periodic in belt travel (a belt joint or an eccentric pulley).
    """
    if tau > 0.0:
        v_base = v_lag
        dv_base = (v_cmd - v_lag) / tau
    else:
        v_base = v_cmd
        dv_base = dv_cmd
    if ripple == 0.0:
        return v_base, dv_base
    k = 2.0 * math.pi / wavelen
    ph = k * pos
    rip = 1.0 + ripple * math.sin(ph)
    v = v_base * rip
    # d/dt [v_base (1 + a sin(k pos))] with d pos/dt = v
    return v, dv_base * rip + v_base * ripple * math.cos(ph) * k * v


@helper
def accel_sign_weight(sgn_v: float, acc_plus: float, acc_minus: float, drive_acc: float) -> float:
    """accel-sign: which kinetic branch applies, given the accelerations each branch would produce.

    The branch multiplier is (1 + amp*w) with w = +1 while |v_rel| grows and -1 while
    it shrinks. The choice depends on the acceleration it causes, so we pick the
    self-consistent branch; when neither is (the friction jump would reverse the
    trend) the contact slides along d|v_rel|/dt = 0 (Filippov), which fixes w in (-1, 1).
    ``acc_plus``/``acc_minus`` are the body accelerations (same units as the drive's)
    with w = +1/-1; returns w.
    """
    g_plus = sgn_v * (acc_plus - drive_acc)  # d|v_rel|/dt on the growing branch
    g_minus = sgn_v * (acc_minus - drive_acc)
    if g_plus > 0.0:
        return 1.0
    if g_minus < 0.0:
        return -1.0
    if g_minus == g_plus:
        return 0.0
    # linear in w: g(w) = g_minus + (w + 1)/2 (g_plus - g_minus) = 0
    return -1.0 + 2.0 * g_minus / (g_minus - g_plus)


@helper
def body_accel_factor(g_other: float, f: float, inv_mass: float, amp: float, a0: float) -> float:
    """accel-sign, body form: the factor 1 + amp tanh(a/a0) on the friction, with a the body's acceleration
    that this very friction causes, a = (g_other - f (1 + amp tanh(a/a0))) inv_mass (an implicit equation:
    four Newton steps from the acceleration without the effect; |amp| <= 0.5 keeps it monotone for the
    loads and scales of these rigs). ``g_other`` is every other force on the body (in the units of f)."""
    a = (g_other - f) * inv_mass
    for _ in range(4):
        th = math.tanh(a / a0)
        h = a - (g_other - f * (1.0 + amp * th)) * inv_mass
        dh = 1.0 + f * amp * (1.0 - th * th) / a0 * inv_mass
        if dh < 0.1:
            dh = 0.1
        a -= h / dh
    return 1.0 + amp * math.tanh(a / a0)


@helper
def env_rates(friction_power: float, v_cmd: float, v_drive: float, t: float, temp: float, v_lag: float,
              t_amb: float, drift: float, r_th: float, tau_th: float, vb_tau: float):
    """Rates of temperature, drive lag and drive travel: (dT/dt, dv_lag/dt, dpos/dt)."""
    d_temp = (t_amb + drift * t + r_th * abs(friction_power) - temp) / tau_th
    d_lag = (v_cmd - v_lag) / max(vb_tau, VB_TAU_MIN) if vb_tau > 0.0 else 0.0
    return d_temp, d_lag, v_drive


@helper
def stick_rates(v_rel: float, load_rate: float, ts: float, q: float, v_stick: float, fr_tau: float,
                st_reset: float):
    """Rates of the stick clock and of the load rate remembered from the last stick.

    While stuck the clock runs and q tracks the tangential load rate; while slipping the
    clock decays (time constant st_reset) and q is held.
    """
    st = stuck_fraction(v_rel, v_stick)
    return st - (1.0 - st) * ts / st_reset, st * (load_rate - q) / fr_tau


@helper
def stick_rates_if_read(v_rel: float, load_rate: float, ts: float, q: float, e_st_gain: float, e_fr_gain: float,
                        v_stick: float, fr_tau: float, st_reset: float):
    """stick_rates, but frozen at zero when neither stick-time nor force-rate reads the clock (saves an exp)."""
    if e_st_gain == 0.0 and e_fr_gain == 0.0:
        return 0.0, 0.0
    return stick_rates(v_rel, load_rate, ts, q, v_stick, fr_tau, st_reset)



# ---------------------------------------------------------------------------
# The chain (compiled): the effects of one contact, in the one order every rig applies them
#
# Why one chain: each rig's rhs calls these steps instead of the terms, so an effect is wired
# once, here, and reaches brake-2dof, drum-pendulum and belt-ndof alike (record 40). A step
# takes the effect vector ``e`` and reads its own slots, so a new effect adds no argument to
# any rig; the rig passes only its mechanics (its law's value, loads, masses) as scalars.
# Inlined, the steps compile to the code the rigs had written out, in the same floating-point
# order. Why each step reads its slots before anything else: an inlined helper that still holds
# an array past a branch or a call pays an atomic reference-count pair per call (see "Terms"),
# which doubled the smooth rigs' rhs time; so a step that takes an array (e, ds, aux) uses it
# only in its first lines, and where two steps with branches meet, the rig calls them in turn.
# The user factor is the rig's own call (daq/models/user_effects.py rebinds it in a copy of
# the rig's rhs), passed in as ``user``.
# ---------------------------------------------------------------------------


@helper
def contact_tail(s, off):
    """The contact's state from the tail at ``off`` of a state vector: (t_s, q, temperature, v_lag, travel)."""
    return s[off + TAIL.TS], s[off + TAIL.Q], s[off + TAIL.TEMP], s[off + TAIL.VLAG], s[off + TAIL.POS]


@helper
def drive_at(t, v_lag, pos, e, rt, rv, left):
    """The drive at t: (commanded speed, actual speed, its rate) after belt-speed; ``left`` as in ramp_eval_side."""
    tau, ripple, wavelen = e[E.VB_TAU], e[E.VB_RIPPLE], e[E.VB_WAVELEN]
    v_cmd, dv_cmd = ramp_eval_side(rt, rv, t, left)
    v, dv = drive_speed(v_cmd, dv_cmd, v_lag, pos, tau, ripple, wavelen)
    return v_cmd, v, dv


@helper
def peak_factor(ts, q, e):
    """Multiplier on the static (peak) part of a rig's law: stick-time (both forms) and force-rate."""
    st_gain, st_tau, fr_gain, fr_q0, log_gain = e[E.ST_GAIN], e[E.ST_TAU], e[E.FR_GAIN], e[E.FR_Q0], e[E.ST_LOG_GAIN]
    return static_factor(ts, q, st_gain, st_tau, fr_gain, fr_q0) + aging_log(ts, log_gain, st_tau)


@helper
def mu_factor(temp, e):
    """Multiplier on a rig's whole law: temperature (both forms)."""
    coef, ref, theta = e[E.TEMP_COEF], e[E.TEMP_REF], e[E.TEMP_ARR]
    return temperature_factor(temp, coef, ref) * arrhenius_factor(temp, theta, ref)


@helper
def with_speed_terms(mu_law, factor, speed, e):
    """The law after its multiplier ``factor`` (mu_factor) and the terms added in the slip speed:
    velocity-strengthening (belt-ndof passes its dimensionless w as the speed)."""
    return mu_law * factor + e[E.VS_D] * speed


@helper
def friction_force(mu_law, factor, n_inst, n_nominal, v_rel, user, e):
    """The smooth-law rigs' contact (brake-2dof, drum-pendulum): the law's mu through the chain (``factor`` =
    mu_factor), times the normal load after normal-load. Returns (F, mu, N) before accel-sign."""
    mu = with_speed_terms(mu_law, factor, v_rel, e) * user
    n = normal_load(n_inst, n_nominal, e[E.NL_WEIGHT])
    return mu * n, mu, n


@helper
def accel_sign(f, mu, g_other, inv_mass, v_rel, drive_acc, e):
    """accel-sign, both forms, on (F, mu). The body's acceleration at the contact is (g_other - F) inv_mass
    (g_other: every other force, in F's units); ``drive_acc``: the drive's, in the same units."""
    amp, amp_b, a0 = e[E.AS_AMP], e[E.AS_BODY_AMP], e[E.AS_BODY_A0]
    if amp != 0.0:
        sg = 1.0 if v_rel > 0.0 else (-1.0 if v_rel < 0.0 else 0.0)
        w = accel_sign_weight(sg, (g_other - f * (1.0 + amp)) * inv_mass, (g_other - f * (1.0 - amp)) * inv_mass,
                              drive_acc)
        f = f * (1.0 + amp * w)
        mu = mu * (1.0 + amp * w)
    if amp_b != 0.0:  # the body form: a smooth switch on the body's own acceleration
        fb = body_accel_factor(g_other, f, inv_mass, amp_b, a0)
        f = f * fb
        mu = mu * fb
    return f, mu


@helper
def stick_clock_rates(v_rel, load_rate, ts, q, e):
    """Rates of the stick clock and the remembered load rate (stick-time, force-rate); Dieterich's state
    for the clock where the log form has a Dc."""
    st_gain, log_gain, fr_gain, dc = e[E.ST_GAIN], e[E.ST_LOG_GAIN], e[E.FR_GAIN], e[E.ST_DC]
    v_stick, fr_tau, st_reset = e[E.V_STICK], e[E.FR_TAU], e[E.ST_RESET]
    d_ts, d_q = stick_rates_if_read(v_rel, load_rate, ts, q, abs(st_gain) + abs(log_gain), fr_gain, v_stick, fr_tau,
                                    st_reset)
    if dc > 0.0 and log_gain != 0.0:  # the log form with Dieterich's state for its clock
        d_ts = dieterich_rate(v_rel, ts, max(dc, DC_MIN))
    return d_ts, d_q


@helper
def environment_rates(power, v_cmd, v_drive, t, temp, v_lag, e):
    """Rates of temperature, drive lag and travel (env_rates) from the friction power and the drive."""
    t_amb, drift, r_th, tau_th, vb_tau = e[E.T_AMB], e[E.TH_DRIFT], e[E.TH_R], e[E.TH_TAU], e[E.VB_TAU]
    return env_rates(power, v_cmd, v_drive, t, temp, v_lag, t_amb, drift, r_th, tau_th, vb_tau)


@helper
def set_tail(ds, off, d_ts, d_q, d_psi, env):
    """Fill the contact tail's rates at ``off``: stick clock, load rate, rate-and-state's state, and the three
    of environment_rates (``env``)."""
    ds[off + TAIL.TS] = d_ts
    ds[off + TAIL.Q] = d_q
    ds[off + TAIL.TEMP] = env[0]
    ds[off + TAIL.VLAG] = env[1]
    ds[off + TAIL.POS] = env[2]
    ds[off + TAIL.PSI] = d_psi
