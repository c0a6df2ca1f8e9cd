"""belt-ndof: 1-3 masses in a chain of springs riding a belt (paper 000, eqs. 1-5).

Paper 000's law is discontinuous (a static limit f_s(t_s, delta) and two kinetic
branches), so this rig is integrated as a hybrid system with event detection
instead of a regularised law: each mass is either stuck (moves with the belt,
friction = whatever holds it) or slipping (friction from the law). RK4 steps are
cut at every located event (bisection on the step fraction to 1e-10 of a step):
stick->slip, slip->stick, and the places where the slipping law changes its
smooth piece (its kinks and the accel-sign branch switch), so RK4 keeps its
order between events.

Dimensional form of eq. (1) per mass, chain wall-k-m1-k-m2-k-m3 (free last mass):
    M x_i'' + D x_i' + (K x)_i = F0 f(w_i),  w_i = (v_b - x_i') / v_u,  v_u = F0 / sqrt(K M)
which is eq. (3) after the scaling (2): x = K X / F0, t = tau / sqrt(M/K), d = D / sqrt(K M).
A spring-slider (mechanics.driven = "spring": the chain's far end driven at v_b, the track fixed) is the same
chain in the driver's frame plus the frame's acceleration, + M v_b' on the right (zero at a constant speed).
Static limit: f_s = f_s0 * effects.peak_factor(t_s, Delta) where t_s is the time stuck and
Delta = d(friction needed)/dt while stuck (for one mass on a constant belt, K S: the paper's Delta).

Decision records: docs/decisions/0011-fixed-step-rk4-smooth-laws.md; the drop after adhesion loss only, a driven
spring end and steps on the programme's corners: docs/decisions/0024-chain-drop-driven-end-and-corners.md.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np

from . import effects
from .contact import N_AUX, set_aux
from .effects import TAIL, E, accel_sign_weight
from .friction import f_pwl_piece
from .jit import helper, kernel
from .rsf import AGING, state_rate
from .rsf import SLIP as SLIP_LAW

RIG_ID = "belt-ndof"
SLIP = 0.0
STICK = 1.0
EVENT_TOL = 1e-10
MAX_SOFT_EVENTS = 200  # per output interval; beyond this, kinks are stepped over (chattering guard)
MAX_HARD_EVENTS = 10_000  # per output interval; beyond this the run stops with an error instead of hanging
# ...and on average over a run: a contact that switches a few times every step (a lag far shorter than the step
# made the belt speed flip sign each step: 500 000 switches, 8 s, in one 0.7 s window) stops with the same error.
# A chain of three masses switches ~0.1 times per 250 Hz sample. Counted over the samples so far (plus 100), not
# against the whole run's budget: a fit's trial at absurd values (static level 0.05 under a kinetic 5.0) chattered
# through ~14 600 switches in each 229-sample window before the error; a 16 s slider compare took 44 s, now 4 s.
MAX_EVENTS_PER_OUTPUT = 20


class P(IntEnum):
    M = 0  # each mass [kg]
    K = 1  # each spring [N/m]
    F0 = 2  # friction unit (normal force) [N]
    N = 3  # number of masses
    F_S0 = 4
    ALPHA_DROP = 5
    F_K0 = 6
    K_FALL = 7
    W_MIN = 8
    K_RISE = 9
    SPRING_DRIVEN = 10  # 1: the springs' far end is driven, the track fixed (a spring-slider, in the driver's frame)


N_P = len(P)


class H(IntEnum):
    """Rows of the hybrid (discrete) state, one column per mass."""

    MODE = 0  # SLIP or STICK
    FS_BREAK = 1  # static limit at the last break-away (start of the growing branch)
    SLIP_DIR = 2  # sign of w while slipping (used when w is exactly 0)
    STICK_T0 = 3  # time the current stick began
    REGION = 4  # smooth piece of the law the mass is on (0 = stuck)
    DROP = 5  # 1 while on the break-away drop (from a stick's end or a reversal until the slip leaves it), else 0


N_H = len(H)


def n_state(n: int) -> int:
    return 2 * n + len(TAIL)


def new_hybrid(n: int, f_s0: float, slip_dir: float) -> np.ndarray:
    """All masses slipping in direction slip_dir, break-away limit f_s0."""
    hs = np.zeros((N_H, n))
    hs[H.MODE] = SLIP
    hs[H.FS_BREAK] = f_s0
    hs[H.SLIP_DIR] = slip_dir
    hs[H.DROP] = 1.0
    return hs


@helper
def chain_force(left, mid, right, k, has_right):
    """(K x)_i of the chain wall-k-m1-k-m2-...-mn (free last mass), from neighbour values."""
    f = k * (mid - left)
    if has_right:
        f -= k * (right - mid)
    return f


@kernel
def chain_at(x, i, n, k):
    """(K x)_i for the chain positions (or velocities) in x[0:n]."""
    left = x[i - 1] if i > 0 else 0.0
    right = x[i + 1] if i < n - 1 else 0.0
    return chain_force(left, x[i], right, k, i < n - 1)


@kernel
def drive(t, s, tail, e, rt, rv, left):
    """Commanded and actual belt speed for state s: (v_cmd, v, dv/dt); ``left``: the programme's slope from the
    left at a corner (the last stage of a step that ends there)."""
    return effects.drive_at(t, s[tail + TAIL.VLAG], s[tail + TAIL.POS], e, rt, rv, left)


@helper
def state_term(s, tail, e):
    """rate-and-state: the state's share b psi of the friction (static and sliding), 0 without the effect."""
    b = e[E.RS_B] + e[E.RS_B_SLIP]
    return b * s[tail + TAIL.PSI] if b != 0.0 and e[E.RS_DC] > 0.0 else 0.0


@helper
def state_speed_rate(s, hs, tail, vb, e):
    """d psi/dt of the one slider's contact: its slip speed (0 while stuck) into the aging law, or the slip law
    when that form is the one in the model (a stuck contact then does not heal: the law's own statement)."""
    if e[E.RS_DC] <= 0.0:
        return 0.0
    v = abs(vb - s[tail // 2]) if hs[H.MODE, 0] == SLIP else 0.0
    law = SLIP_LAW if e[E.RS_B_SLIP] != 0.0 else AGING
    return state_rate(v, s[tail + TAIL.PSI], e[E.RS_DC], e[E.RS_VREF], law)


@kernel
def rhs(t, s, hs, p, e, rt, rv, ds, fric, region, left=False):
    """Right-hand side for the current modes; fric[i] = friction force on mass i along +x [N].

    region[i] codes which smooth piece of the law mass i is on (0 = stuck); the integrator
    cuts its step where the code changes.
    """
    n = int(p[P.N])
    M = p[P.M]
    K = p[P.K]
    F0 = p[P.F0]
    tail = 2 * n
    v_cmd, vb, dvb = drive(t, s, tail, e, rt, rv, left)
    skm = math.sqrt(K * M)
    vu = F0 / skm
    damp = e[E.D_BELT] * skm
    amp = e[E.AS_AMP]
    # seen from a driven spring end, a change of drive speed is a frame acceleration: +M V' on every mass (a mass
    # stuck to the fixed track then needs no friction for it), see docs/examples/spring-slider.md
    frame = p[P.SPRING_DRIVEN]
    tf = effects.mu_factor(s[tail + TAIL.TEMP], e)
    a_d, f_k0, k_f, w_m, k_r = p[P.ALPHA_DROP], p[P.F_K0], p[P.K_FALL], p[P.W_MIN], p[P.K_RISE]
    rs_a, v_ref = (e[E.RS_A], e[E.RS_VREF]) if e[E.RS_DC] > 0.0 else (0.0, 1.0)
    rs_state = state_term(s, tail, e)
    power = 0.0
    for i in range(n):
        vi = s[n + i]
        kx = chain_at(s, i, n, K)
        if hs[H.MODE, i] == STICK:
            ds[i] = vb
            ds[n + i] = dvb
            fric[i] = M * dvb * (1.0 - frame) + damp * vi + kx
            region[i] = 0
        else:
            w = (vb - vi) / vu
            # the mode's own vector field: the law's piece for this slip direction, continued
            # past w = 0 so that a step overshooting the crossing ends on the far side
            sg = hs[H.SLIP_DIR, i]
            u = sg * w
            fsb = hs[H.FS_BREAK, i] if hs[H.DROP, i] != 0.0 else -math.inf
            # rate-and-state (one mass): the direct effect in the slip speed, the state's term along the slip
            rs = sg * rs_state + (rs_a * math.asinh(w * vu / (2.0 * v_ref)) if rs_a != 0.0 else 0.0)
            law_p = sg * f_pwl_piece(u, 1.0, fsb, a_d, f_k0, k_f, w_m, k_r, amp)
            law_m = sg * f_pwl_piece(u, -1.0, fsb, a_d, f_k0, k_f, w_m, k_r, amp)
            fp = effects.with_speed_terms(law_p, tf, w, e) + rs
            fm = effects.with_speed_terms(law_m, tf, w, e) + rs
            ap = (F0 * fp - damp * vi - kx) / M + frame * dvb
            am = (F0 * fm - damp * vi - kx) / M + frame * dvb
            wsel = 1.0 if fp == fm else accel_sign_weight(-sg, ap, am, dvb)
            f = fm + 0.5 * (wsel + 1.0) * (fp - fm)
            fric[i] = F0 * f
            ds[i] = vi
            ds[n + i] = (F0 * f - damp * vi - kx) / M + frame * dvb
            kin = f_k0 - k_f * min(u, w_m) + k_r * max(u - w_m, 0.0)
            on_drop = 1 if wsel != -1.0 and fsb - a_d * u > (1.0 + amp) * kin else 0
            above_min = 1 if u > w_m else 0
            branch = 0 if wsel == 1.0 else (1 if wsel == -1.0 else 2)
            region[i] = 1 + above_min + 2 * on_drop + 4 * branch
        power += fric[i] * (vb - vi)
    # stick clocks are exact event times, kept in hs: no clock or load-rate rates here
    env = effects.environment_rates(power, v_cmd, vb, t, s[tail + TAIL.TEMP], s[tail + TAIL.VLAG], e)
    effects.set_tail(ds, tail, 0.0, 0.0, state_speed_rate(s, hs, tail, vb, e), env)
    return v_cmd, vb, dvb


@kernel
def _rk4_step(t, s, h, k1, hs, p, e, rt, rv, out, wk, fric, region):
    """One RK4 step of size h from (t, s) into out, given k1 = rhs(t, s) (the same for every trial step a
    bisection makes from one state, and the last step's end-point rhs when no event came between); wk holds
    scratch rows."""
    ns = s.size
    k2, k3, k4, tmp = wk[1], wk[2], wk[3], wk[4]
    for j in range(ns):
        tmp[j] = s[j] + 0.5 * h * k1[j]
    rhs(t + 0.5 * h, tmp, hs, p, e, rt, rv, k2, fric, region)
    for j in range(ns):
        tmp[j] = s[j] + 0.5 * h * k2[j]
    rhs(t + 0.5 * h, tmp, hs, p, e, rt, rv, k3, fric, region)
    for j in range(ns):
        tmp[j] = s[j] + h * k3[j]
    rhs(t + h, tmp, hs, p, e, rt, rv, k4, fric, region, True)  # a step never crosses a corner of the programme
    for j in range(ns):
        out[j] = s[j] + h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])


ROS2_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


@kernel
def _ros2_step(t, s, h, k1, hs, p, e, rt, rv, out, wk, fric, region):
    """One step of ROS2 (Verwer et al. 1999: a two-stage Rosenbrock-W method, second order for any W, L-stable),
    W holding each mass's own (x_i, v_i) block of the Jacobian and the contact state's own rate, found by
    differences. Why: rate-and-state makes a slider stiff. Its direct effect at creep speeds (F0 a / (M |v|):
    1e5 /s for 10 g at 10 um/s, against RK4's 5.6e3 /s at 0.5 ms), its state in a fast slip (|v| / Dc: 7900 /s
    at 0.79 m/s over Dc = 0.1 mm made RK4 diverge). With those implicit the step is stable at any slip speed
    and, where the slider's inertia does not matter, lands on the quasi-static motion. Same contract as
    _rk4_step."""
    n = int(p[P.N])
    ns = s.size
    tmp, f, z1, jac = wk[1], wk[2], wk[3], wk[4]
    g = ROS2_GAMMA * h
    for i in range(n):  # jac[i] = d(v_i')/d(x_i), jac[n + i] = d(v_i')/d(v_i)
        for j in range(ns):
            tmp[j] = s[j]
        dx = 1e-7 * (abs(s[i]) + 1e-6)
        tmp[i] += dx
        rhs(t, tmp, hs, p, e, rt, rv, f, fric, region)
        jac[i] = (f[n + i] - k1[n + i]) / dx
        tmp[i] = s[i]
        dv = 1e-6 * (abs(s[n + i]) + e[E.RS_VREF]) + 1e-12
        tmp[n + i] += dv
        rhs(t, tmp, hs, p, e, rt, rv, f, fric, region)
        jac[n + i] = (f[n + i] - k1[n + i]) / dv
        tmp[n + i] = s[n + i]
    k = 2 * n + TAIL.PSI  # d(psi')/d(psi)
    tmp[k] += 1e-6
    rhs(t, tmp, hs, p, e, rt, rv, f, fric, region)
    jac[2 * n] = (f[k] - k1[k]) / 1e-6
    for j in range(ns):
        z1[j] = k1[j]
    _w_solve(z1, jac, g, n)
    for j in range(ns):
        tmp[j] = s[j] + h * z1[j]
    rhs(t + h, tmp, hs, p, e, rt, rv, f, fric, region, True)
    for j in range(ns):
        f[j] -= 2.0 * z1[j]
    _w_solve(f, jac, g, n)
    for j in range(ns):
        out[j] = s[j] + h * (1.5 * z1[j] + 0.5 * f[j])


@helper
def _w_solve(r, jac, g, n):
    """r <- (I - g W)^-1 r, W block-diagonal: [[0, 1], [jac[i], jac[n + i]]] on each mass's (x_i, v_i), jac[2 n]
    on the contact state psi, 0 elsewhere."""
    k = 2 * n + TAIL.PSI
    r[k] /= 1.0 - g * jac[2 * n]
    for i in range(n):
        jx, jv = jac[i], jac[n + i]
        det = 1.0 - g * jv - g * g * jx
        rx, rv_ = r[i], r[n + i]
        r[i] = (rx * (1.0 - g * jv) + g * rv_) / det
        r[n + i] = (rv_ + g * jx * rx) / det


@kernel
def _step(t, s, h, k1, hs, p, e, rt, rv, out, wk, fric, region):
    """RK4, or ROS2 where the model carries rate-and-state's contact state (Dc > 0, whatever a and b: the
    integrator does not change as a fit moves them from 0). Without the effect (Dc = 0) bit for bit RK4."""
    if e[E.RS_DC] > 0.0:
        _ros2_step(t, s, h, k1, hs, p, e, rt, rv, out, wk, fric, region)
    else:
        _rk4_step(t, s, h, k1, hs, p, e, rt, rv, out, wk, fric, region)


@kernel
def _static_limit(ts, q, p, e):
    return p[P.F_S0] * effects.peak_factor(ts, q, e)


@kernel
def _stick_need(t, s, i, hs, p, e, rt, rv, ds, fric, region):
    """Friction [N] needed to keep mass i stuck at state s, and its rate Delta [N/s]."""
    n = int(p[P.N])
    saved = hs[H.MODE, i]
    hs[H.MODE, i] = STICK
    _, vb, dvb = rhs(t, s, hs, p, e, rt, rv, ds, fric, region)
    need = fric[i]
    hs[H.MODE, i] = saved
    K = p[P.K]
    damp = e[E.D_BELT] * math.sqrt(K * p[P.M])
    # Delta = d/dt (M vb' + D vb + (K x)_i) with x_i' = vb; vb'' neglected (piecewise-linear ramps)
    vel = s[n:2 * n].copy()
    vel[i] = vb
    rate = damp * dvb + chain_at(vel, i, n, K)
    return need, rate


@kernel
def _events(t, s, hs, p, e, rt, rv, ds, fric, region, flags, soft, k_at, region_at):
    """Flag masses whose event fired at state s (1 = mode change, 2 = law piece change); any fired?
    With ``soft`` the rhs at (t, s) and its law pieces are left in k_at and region_at (the next step's k1
    when nothing fired)."""
    n = int(p[P.N])
    tail = 2 * n
    any_ev = False
    _, vb, _ = drive(t, s, tail, e, rt, rv, False)
    if soft:
        rhs(t, s, hs, p, e, rt, rv, k_at, fric, region_at)
        for i in range(n):
            flags[i] = 2 if region_at[i] != hs[H.REGION, i] else 0
            any_ev = any_ev or flags[i] != 0
    else:
        for i in range(n):
            flags[i] = 0
    for i in range(n):
        if hs[H.MODE, i] == SLIP:
            if (vb - s[n + i]) * hs[H.SLIP_DIR, i] < 0.0:  # relative velocity crossed zero
                flags[i] = 1
                any_ev = True
        else:
            need, rate = _stick_need(t, s, i, hs, p, e, rt, rv, ds, fric, region)
            if abs(need) > p[P.F0] * (_static_limit(t - hs[H.STICK_T0, i], rate, p, e) + state_term(s, tail, e)):
                flags[i] = 1
                any_ev = True
    return any_ev


@kernel
def _end_drops(hs, region, n):
    """A slipping mass whose law piece is off the break-away drop has left it for good (until it sticks or
    reverses): paper 000's drop is "the decrease of the friction force at the moment of adhesion loss", not a
    branch to return to when the slip speed dips and grows again within one slip, as it does in a chain. Any
    drop ended (the caller then recomputes the rhs: the branch choice read the drop)?"""
    ended = False
    for i in range(n):
        if hs[H.MODE, i] == SLIP and hs[H.DROP, i] != 0.0 and ((region[i] - 1) >> 1) & 1 == 0:
            hs[H.DROP, i] = 0.0
            ended = True
    return ended


@kernel
def _switch(t, s, hs, flags, p, e, rt, rv, ds, fric, region):
    """Apply the mode changes flagged at an event."""
    n = int(p[P.N])
    tail = 2 * n
    _, vb, _ = drive(t, s, tail, e, rt, rv, False)
    for i in range(n):
        if flags[i] != 1:
            continue
        if hs[H.MODE, i] == SLIP:
            # w reached zero: stick if the static limit (fresh contact, t_s = 0) can hold the mass
            s[n + i] = vb
            need, rate = _stick_need(t, s, i, hs, p, e, rt, rv, ds, fric, region)
            fresh = _static_limit(0.0, rate, p, e)
            limit = p[P.F0] * (fresh + state_term(s, tail, e))
            if abs(need) <= limit:
                hs[H.MODE, i] = STICK
                hs[H.STICK_T0, i] = t
            else:  # passes through zero relative velocity: reversal of slip
                hs[H.SLIP_DIR, i] = 1.0 if need > 0.0 else -1.0
                hs[H.FS_BREAK, i] = fresh
                hs[H.DROP, i] = 1.0
        else:
            need, rate = _stick_need(t, s, i, hs, p, e, rt, rv, ds, fric, region)
            hs[H.FS_BREAK, i] = _static_limit(t - hs[H.STICK_T0, i], rate, p, e)  # the state's term rides the slip
            hs[H.DROP, i] = 1.0
            hs[H.MODE, i] = SLIP
            # a stuck mass rides the belt; rounding (a belt that changed speed) can leave its velocity
            # 1e-13 m/s on the wrong side, read at once as a zero crossing of w: a spurious fresh contact
            s[n + i] = vb
            # friction needed > 0 means the springs pull back: the mass lags the belt, w > 0
            hs[H.SLIP_DIR, i] = 1.0 if need > 0.0 else -1.0


@helper
def _locate_event(t, s, h, k1, hs, p, e, rt, rv, trial, wk, ds, fric, region, flags, soft, k_end, region_end):
    """An event fired within the step h from (t, s): bisect the step's fraction down to EVENT_TOL and step to the
    bracket's far end. Returns the step taken; trial holds the state there and flags its events."""
    lo = 0.0
    hi = 1.0
    while (hi - lo) > EVENT_TOL:
        mid = 0.5 * (lo + hi)
        _step(t, s, mid * h, k1, hs, p, e, rt, rv, trial, wk, fric, region)
        if _events(t + mid * h, trial, hs, p, e, rt, rv, ds, fric, region, flags, soft, k_end, region_end):
            hi = mid
        else:
            lo = mid
    h = hi * h
    _step(t, s, h, k1, hs, p, e, rt, rv, trial, wk, fric, region)
    _events(t + h, trial, hs, p, e, rt, rv, ds, fric, region, flags, soft, k_end, region_end)
    return h


@helper
def _check_chatter(n_hard, n_events, k):
    """Stop a contact that switches without end (see MAX_HARD_EVENTS, MAX_EVENTS_PER_OUTPUT)."""
    if n_hard > MAX_HARD_EVENTS:  # a contact flipping without time advancing
        raise RuntimeError("belt-ndof: contact chatters (over 10000 stick/slip switches in one output interval)")
    if n_events > MAX_EVENTS_PER_OUTPUT * (k + 1) + 100:  # so far, not by the window's end
        raise RuntimeError("belt-ndof: contact chatters (over 20 stick/slip switches per output sample)")


@helper
def _record(k, t, s, hs, p, e, rt, rv, ds, fric, region, states, auxs, frics, modes_out):
    """Output sample k at (t, s): the state, the friction on each mass, the modes, and aux of mass 1."""
    n = int(p[P.N])
    rhs(t, s, hs, p, e, rt, rv, ds, fric, region)
    states[k] = s
    frics[k] = fric
    modes_out[k] = hs[H.MODE]
    v_cmd, vb, _ = drive(t, s, 2 * n, e, rt, rv, False)
    # aux in the common convention: F = mu(V_rel) N with V_rel = body - drive, force on body = -F
    set_aux(auxs[k], -fric[0], p[P.F0], -fric[0] / p[P.F0], vb, v_cmd, s[n] - vb, p[P.F0], ds[n])


@kernel
def simulate(s0, t0, dt, n_sub, n_out, p, e, rt, rv, hs):
    """Hybrid integration from s0 at t0; returns states, aux (mass 1), friction per mass, modes, n_events.

    The discrete state ``hs`` (rows H, one column per mass) belongs to the caller and is
    updated in place, so a long run can be integrated in chunks.
    """
    n = int(p[P.N])
    ns = s0.size
    states = np.empty((n_out, ns))
    auxs = np.zeros((n_out, N_AUX))
    frics = np.empty((n_out, n))
    modes_out = np.empty((n_out, n))
    s = s0.copy()
    flags = np.zeros(n, dtype=np.int64)
    region = np.zeros(n, dtype=np.int64)
    wk = np.empty((5, ns))
    trial = np.empty(ns)
    ds = np.empty(ns)
    fric = np.empty(n)
    k1 = np.empty(ns)  # rhs at (t, s) and its law pieces: computed once per state, not once per trial step
    region1 = np.zeros(n, dtype=np.int64)
    k_end = np.empty(ns)  # the same at a trial step's end (from _events)
    region_end = np.zeros(n, dtype=np.int64)
    have_k1 = False
    n_events = 0
    t = t0
    # the drive programme's next corner (a step ends there: across it RK4 drops to first order); a window starts
    # anywhere in a long record's table, so found by bisection, not walked to
    kink = np.searchsorted(rt, t0, side="right")
    for k in range(n_out):
        t_target = t0 + k * n_sub * dt
        n_soft = 0
        n_hard = 0
        while t_target - t > 1e-9 * dt:
            soft = n_soft < MAX_SOFT_EVENTS
            if not have_k1:
                rhs(t, s, hs, p, e, rt, rv, k1, fric, region1)
            have_k1 = False
            if _end_drops(hs, region1, n):
                rhs(t, s, hs, p, e, rt, rv, k1, fric, region1)
            for i in range(n):
                hs[H.REGION, i] = region1[i]
            h = min(dt, t_target - t)
            while kink < rt.size and rt[kink] <= t:
                kink += 1
            if kink < rt.size and rt[kink] - t <= h + 1e-9 * dt:
                h = rt[kink] - t  # ends on the corner exactly (rounding must not leave it a hair to either side)
            _step(t, s, h, k1, hs, p, e, rt, rv, trial, wk, fric, region)
            if _events(t + h, trial, hs, p, e, rt, rv, ds, fric, region, flags, soft, k_end, region_end):
                t += _locate_event(t, s, h, k1, hs, p, e, rt, rv, trial, wk, ds, fric, region, flags, soft, k_end,
                                   region_end)
                s[:] = trial
                hard = False
                for i in range(n):
                    hard = hard or flags[i] == 1
                if hard:
                    _switch(t, s, hs, flags, p, e, rt, rv, ds, fric, region)
                    n_events += 1
                    n_hard += 1
                    _check_chatter(n_hard, n_events, k)
                else:
                    n_soft += 1
            else:
                t += h
                s[:] = trial
                if soft:  # the end point's rhs, with the modes unchanged: the next step's k1
                    k1[:] = k_end
                    region1[:] = region_end
                    have_k1 = True
        _record(k, t, s, hs, p, e, rt, rv, ds, fric, region, states, auxs, frics, modes_out)
    return states, auxs, frics, modes_out, n_events


def energy(states: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Kinetic plus spring energy of the chain (conserved with friction and damping off)."""
    n = int(p[P.N])
    x = states[..., :n]
    v = states[..., n:2 * n]
    kin = 0.5 * p[P.M] * np.sum(v**2, axis=-1)
    ext = x[..., :1] ** 2
    if n > 1:
        ext = np.concatenate([ext, np.diff(x, axis=-1) ** 2], axis=-1)
    return kin + 0.5 * p[P.K] * np.sum(ext, axis=-1)


def linear_modes(p: np.ndarray) -> np.ndarray:
    """Natural frequencies [Hz] of the chain without friction."""
    return chain_modes(p[P.M], p[P.K], int(p[P.N]))


def chain_modes(mass: float, stiffness: float, n: int) -> np.ndarray:
    """Natural frequencies [Hz] of the chain wall-k-m1-...-mn (free last mass) of equal masses and springs."""
    kmat = np.zeros((n, n))
    for i in range(n):
        kmat[i, i] = 2.0 if i < n - 1 else 1.0
        if i > 0:
            kmat[i, i - 1] = kmat[i - 1, i] = -1.0
    w2 = np.linalg.eigvalsh(kmat * stiffness / mass)
    return np.sqrt(w2) / (2 * math.pi)
