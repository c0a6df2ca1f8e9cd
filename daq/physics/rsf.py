"""Rate-and-state friction (Dieterich 1979, Ruina 1983) and the quasi-static spring-slider it is measured with.

The law, in the regularised form of Rice & Ben-Zion (1996) and Lapusta et al. (2000):

    mu = a asinh( v / (2 v0) exp((mu0 + b psi) / a) ),   psi = ln(v0 theta / Dc)

which is mu0 + a ln(v/v0) + b ln(v0 theta/Dc) wherever v >> v0 exp(-mu0/a) (every speed a lab measures) and
stays finite and odd through v = 0 (a hold). The state evolves by

    aging law (Dieterich):  d theta/dt = 1 - v theta / Dc        ->  d psi/dt = (v0 exp(-psi) - v) / Dc
    slip law (Ruina):       d theta/dt = -(v theta/Dc) ln(v theta/Dc) -> d psi/dt = -(v / Dc) (ln(v/v0) + psi)

The state is carried as psi (its logarithm): theta spans decades in a hold and psi keeps every step of the
integrator on the same relative accuracy.

Why quasi-static: a velocity step or a slide-hold-slide on a rock press or a tribometer is analysed, in the
field's tools (RSFit3000, rsfmodel), with the machine as a spring of stiffness k between the load point and
the sample, inertia neglected:

    d mu/dt = k' (v_lp(t) - v),   k' = k / N  [1/m]

so v follows from (mu, psi) by inverting the law. Inertia matters only when a step is fast against
sqrt(m/k) (tens of ms on a 30 g slider at 2254 N/m); the reduction's windows are seconds long.

The integrator is Dormand-Prince 5(4) with step control, its steps cut at the corners of the load-point
programme (a piecewise-linear table, as daq.ramps makes), outputs by cubic Hermite interpolation over each
accepted step. Pure functions over arrays: the analysis (daq/analysis/rsf) fits with them.
"""

from __future__ import annotations

import math

import numpy as np

from .jit import helper, kernel

AGING = 0
SLIP = 1
LAWS = {"aging": AGING, "slip": SLIP}

# Dormand-Prince 5(4) tableau
_C2, _C3, _C4, _C5 = 1 / 5, 3 / 10, 4 / 5, 8 / 9
_A21 = 1 / 5
_A31, _A32 = 3 / 40, 9 / 40
_A41, _A42, _A43 = 44 / 45, -56 / 15, 32 / 9
_A51, _A52, _A53, _A54 = 19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729
_A61, _A62, _A63, _A64, _A65 = 9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656
_B1, _B3, _B4, _B5, _B6 = 35 / 384, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84
_E1, _E3, _E4, _E5, _E6, _E7 = 71 / 57600, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525, -1 / 40
MAX_STEPS = 2_000_000


@helper
def rsf_mu(v, psi, mu0, a, b, v0):
    """Friction from slip speed and state (the regularised law); odd in v."""
    return a * np.arcsinh(v / (2.0 * v0) * np.exp((mu0 + b * psi) / a))


@helper
def rsf_speed(mu, psi, mu0, a, b, v0):
    """Slip speed from friction and state: the law inverted, v = 2 v0 exp(-(mu0 + b psi)/a) sinh(mu/a), in
    logarithms (mu/a is ~100 for a lab's a and mu)."""
    x = mu / a
    if x > 0.0:
        return v0 * math.exp(x - (mu0 + b * psi) / a) * -math.expm1(-2.0 * x)
    return -v0 * math.exp(-x - (mu0 + b * psi) / a) * -math.expm1(2.0 * x)


@helper
def state_rate(v, psi, dc, v0, law):
    """d psi/dt by the aging law (law 0) or the slip law (law 1)."""
    av = abs(v)
    if law == AGING:
        return (v0 * math.exp(-psi) - av) / dc
    if av <= 0.0:
        return 0.0
    return -(av / dc) * (math.log(av / v0) + psi)


@helper
def _lp_speed(t, rt, rv, j):
    """The load-point programme on its piece j (rt[j] <= t <= rt[j+1])."""
    dt = rt[j + 1] - rt[j]
    if dt <= 0.0:
        return rv[j + 1]
    return rv[j] + (rv[j + 1] - rv[j]) * (t - rt[j]) / dt


@helper
def _rates(t, mu, psi, rt, rv, j, mu0, a, b, dc, kp, v0, law):
    v = rsf_speed(mu, psi, mu0, a, b, v0)
    return kp * (_lp_speed(t, rt, rv, j) - v), state_rate(v, psi, dc, v0, law)


@helper
def _hermite(s, h, y_start, k_start, y_end, k_end):
    """Cubic Hermite interpolation over an accepted step of h, at the fraction s of it."""
    h00 = (1.0 + 2.0 * s) * (1.0 - s) ** 2
    h10 = s * (1.0 - s) ** 2
    h01 = s * s * (3.0 - 2.0 * s)
    h11 = s * s * (s - 1.0)
    return h00 * y_start + h10 * h * k_start + h01 * y_end + h11 * h * k_end


@kernel
def slider_response(t_out, rt, rv, mu_start, psi_start, mu0, a, b, dc, kp, v0, law, rtol):
    """Friction mu(t_out) and state psi(t_out) of the quasi-static spring-slider from (mu_start, psi_start) at
    t_out[0], the load point moving by the piecewise-linear programme (rt, rv). Returns (mu, psi, ok); ok is
    False when the step control gave up (a parameter set far outside the physical range in a fit)."""
    n = t_out.size
    mu_o = np.empty(n)
    psi_o = np.empty(n)
    mu_o[0] = mu_start
    psi_o[0] = psi_start
    t = t_out[0]
    t_end = t_out[n - 1]
    y0, y1 = mu_start, psi_start
    j = 0
    while j < rt.size - 2 and rt[j + 1] <= t:
        j += 1
    k10, k11 = _rates(t, y0, y1, rt, rv, j, mu0, a, b, dc, kp, v0, law)
    atol_mu = rtol * a
    atol_psi = rtol
    h = min(1e-3 * (t_end - t) + 1e-12, 1e-3)
    i_out = 1
    steps = 0
    while t < t_end and steps < MAX_STEPS:
        steps += 1
        t_stop = t_end
        if j < rt.size - 2 and rt[j + 1] < t_stop:
            t_stop = rt[j + 1]  # a corner of the programme: the step ends on it
        last = False
        if t + h >= t_stop:
            h = t_stop - t
            last = True
        k20, k21 = _rates(t + _C2 * h, y0 + h * _A21 * k10, y1 + h * _A21 * k11, rt, rv, j, mu0, a, b, dc, kp, v0, law)
        k30, k31 = _rates(t + _C3 * h, y0 + h * (_A31 * k10 + _A32 * k20), y1 + h * (_A31 * k11 + _A32 * k21),
                          rt, rv, j, mu0, a, b, dc, kp, v0, law)
        k40, k41 = _rates(t + _C4 * h, y0 + h * (_A41 * k10 + _A42 * k20 + _A43 * k30),
                          y1 + h * (_A41 * k11 + _A42 * k21 + _A43 * k31), rt, rv, j, mu0, a, b, dc, kp, v0, law)
        k50, k51 = _rates(t + _C5 * h, y0 + h * (_A51 * k10 + _A52 * k20 + _A53 * k30 + _A54 * k40),
                          y1 + h * (_A51 * k11 + _A52 * k21 + _A53 * k31 + _A54 * k41),
                          rt, rv, j, mu0, a, b, dc, kp, v0, law)
        k60, k61 = _rates(t + h, y0 + h * (_A61 * k10 + _A62 * k20 + _A63 * k30 + _A64 * k40 + _A65 * k50),
                          y1 + h * (_A61 * k11 + _A62 * k21 + _A63 * k31 + _A64 * k41 + _A65 * k51),
                          rt, rv, j, mu0, a, b, dc, kp, v0, law)
        z0 = y0 + h * (_B1 * k10 + _B3 * k30 + _B4 * k40 + _B5 * k50 + _B6 * k60)
        z1 = y1 + h * (_B1 * k11 + _B3 * k31 + _B4 * k41 + _B5 * k51 + _B6 * k61)
        k70, k71 = _rates(t + h, z0, z1, rt, rv, j, mu0, a, b, dc, kp, v0, law)
        e0 = h * (_E1 * k10 + _E3 * k30 + _E4 * k40 + _E5 * k50 + _E6 * k60 + _E7 * k70)
        e1 = h * (_E1 * k11 + _E3 * k31 + _E4 * k41 + _E5 * k51 + _E6 * k61 + _E7 * k71)
        err = max(abs(e0) / (atol_mu + rtol * abs(z0)), abs(e1) / (atol_psi + rtol * abs(z1)))
        if not (err == err) or not (z0 == z0) or not (z1 == z1):  # nan: a trial far outside the physics
            h *= 0.1
            if h < 1e-14 * (1.0 + abs(t)):
                return mu_o, psi_o, False
            continue
        if err <= 1.0:
            t_new = t_stop if last else t + h
            while i_out < n and t_out[i_out] <= t_new:  # cubic Hermite over the accepted step
                s = (t_out[i_out] - t) / h
                mu_o[i_out] = _hermite(s, h, y0, k10, z0, k70)
                psi_o[i_out] = _hermite(s, h, y1, k11, z1, k71)
                i_out += 1
            t = t_new
            y0, y1 = z0, z1
            if last and j < rt.size - 2 and t >= rt[j + 1]:
                j += 1
                k10, k11 = _rates(t, y0, y1, rt, rv, j, mu0, a, b, dc, kp, v0, law)
            else:
                k10, k11 = k70, k71
            fac = 0.9 * err ** -0.2 if err > 1e-10 else 5.0
            h = h * min(5.0, max(0.2, fac))
        else:
            h = h * max(0.1, 0.9 * err ** -0.2)
        if h < 1e-14 * (1.0 + abs(t)):
            return mu_o, psi_o, False
    while i_out < n:
        mu_o[i_out] = y0
        psi_o[i_out] = y1
        i_out += 1
    return mu_o, psi_o, t >= t_end


def steady_mu(v: float, mu0: float, a: float, b: float, v0: float) -> float:
    """Steady-state friction at slip speed v (theta = Dc/v under either law): mu0 + (a - b) ln(v/v0) for v >> v0's
    regularisation scale."""
    psi = math.log(v0 / v)
    return float(a * np.arcsinh(v / (2.0 * v0) * np.exp((mu0 + b * psi) / a)))


def simulate(t: np.ndarray, rt: np.ndarray, rv: np.ndarray, *, mu0: float, a: float, b: float, dc: float,
             kp: float, v0: float, law: str = "aging", rtol: float = 1e-8,
             start: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """mu(t), psi(t) of the quasi-static slider, from steady state at the programme's speed at t[0] unless
    ``start`` = (mu, psi) is given. Raises ValueError if the integrator cannot follow the parameters."""
    t = np.ascontiguousarray(t, dtype=float)
    rt = np.ascontiguousarray(rt, dtype=float)
    rv = np.ascontiguousarray(rv, dtype=float)
    if start is None:
        v_start = float(np.interp(t[0], rt, rv))
        if v_start <= 0.0:
            raise ValueError("the programme is at rest at the start: give start=(mu, psi)")
        psi_start = math.log(v0 / v_start)
        start = (steady_mu(v_start, mu0, a, b, v0), psi_start)
    mu, psi, ok = slider_response(t, rt, rv, float(start[0]), float(start[1]), mu0, a, b, dc, kp, v0,
                                  LAWS[law], rtol)
    if not ok:
        raise ValueError("the integrator could not follow these parameters")
    return mu, psi
