"""A spring-slider in the lab frame (tests only): a slider on a fixed track pulled through a spring by a driver.

Why a second form of the same physics: issue 14's acceptance puts a lab's spring-slider record through the
belt-ndof model loop. The model integrates paper 000's chain in the frame of the belt (daq/physics/beltndof.py,
an event-detecting RK4 on the mass position); this writes the record in the lab frame instead, with scipy's
adaptive ``solve_ivp`` and its event location, in the spring's extension e = X_d - X and the slider's speed
s = X' over the track, and with static friction that ages as Dieterich's logarithm of the time at rest
(f_s = f_s0 + b ln(1 + t_stick / tau)), a published form the user's model does not have. Nothing is
imported from ``daq``; a mistake in the frame change, the law's branches or the event logic on either side
shows up as a model that cannot reach the noise floor.

    stick:  s = 0,          e' = V(t)                    until k e > F0 f_s(t_stick)
    slip:   m s' = k e - F0 f(s),  e' = V(t) - s          until s = 0 (then stick; no reversal here)
    speeding up (s' > 0):   f = max(f_b - alpha w, f_k(w))   (paper 000's growing branch: the drop from the
                                                            static level f_b at break-away, then the kinetic line)
    slowing down (s' < 0):  f = f_k(w)                        (its shrinking branch)
    f_k(w) = f_k0 - k_fall min(w, w_min) + k_rise max(w - w_min, 0),  w = s / v_u,  v_u = F0 / sqrt(k m).
The switch from one branch to the other is located as the event s' = 0. Where the speed peaks while the drop is
still above the kinetic line, neither branch is consistent (the drop decelerates the slider, which would put it on
the kinetic line, which accelerates it): the slider slides on at the peak speed (a Filippov sliding mode, what the
model's branch choice does too), friction = k e / F0 between the branches, until the spring's pull falls to the
kinetic line (then the shrinking branch) or rises back to the drop (the growing one):
    plateau:   s' = 0,  e' = V(t) - s,   while F0 f_k(s) < k e < F0 (f_b - alpha w).
Seen where the drive slows or stops during a slip (slide-hold-slide, velocity steps down).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp


@dataclass
class Slider:
    m: float  # slider mass [kg]
    k: float  # spring stiffness [N/m]
    f0: float  # normal load [N] (m g on a horizontal track)
    f_s0: float = 1.33  # static level of a fresh contact [units of f0]
    b: float = 0.05  # Dieterich aging: f_s = f_s0 + b ln(1 + t_stick / tau)
    tau: float = 0.5  # [s]
    alpha: float = 4.0
    f_k0: float = 1.0
    k_fall: float = 0.3
    w_min: float = 0.8
    k_rise: float = 0.05

    @property
    def v_u(self) -> float:
        return self.f0 / math.sqrt(self.k * self.m)

    def static(self, t_stick: float) -> float:
        return self.f_s0 + self.b * math.log1p(max(t_stick, 0.0) / self.tau)

    def kinetic(self, s: float) -> float:
        w = s / self.v_u
        return self.f_k0 - self.k_fall * min(w, self.w_min) + self.k_rise * max(w - self.w_min, 0.0)

    def friction(self, s: float, f_b: float, growing: bool) -> float:
        return max(f_b - self.alpha * s / self.v_u, self.kinetic(s)) if growing else self.kinetic(s)


def simulate(sl: Slider, drive: Callable[[float], float], t: np.ndarray, e0: float = 0.0,
             phases: list[tuple[float, str]] | None = None) -> np.ndarray:
    """Spring extension e [m] at the times ``t`` (from rest, stuck, at t[0]): the force gauge reads k e. ``phases``,
    if given, receives each phase entered and when."""
    out = np.empty(t.size)
    t_now, e, s, phase, t_stick0, f_b = float(t[0]), e0, 0.0, "stick", float(t[0]), sl.f_s0
    i = 0
    while t_now < t[-1] and i < t.size:
        if phase == "stick":
            def ends(tt, y):  # break-away
                return sl.k * y[0] - sl.f0 * sl.static(tt - t_stick0)
            ends.terminal, ends.direction = True, 1
            sol = solve_ivp(lambda tt, y: [drive(tt)], (t_now, t[-1]), [e], events=ends, dense_output=True,
                            rtol=1e-10, atol=1e-13, max_step=0.01)
        elif phase == "plateau":
            s_hold, f_hi = s, f_b - sl.alpha * s / sl.v_u

            def ends(tt, y):  # the spring's pull leaves the band between the branches
                return min(sl.k * y[0] - sl.f0 * sl.kinetic(s_hold), sl.f0 * f_hi - sl.k * y[0])
            ends.terminal, ends.direction = True, -1
            sol = solve_ivp(lambda tt, y: [drive(tt) - s_hold], (t_now, t[-1]), [e], events=ends, dense_output=True,
                            rtol=1e-10, atol=1e-13, max_step=0.002)
        else:
            growing = phase == "growing"

            def rhs(tt, y, growing=growing):
                return [drive(tt) - y[1], (sl.k * y[0] - sl.f0 * sl.friction(y[1], f_b, growing)) / sl.m]

            def ends(tt, y, growing=growing):  # growing: the slider's speed peaks; shrinking: it comes to rest
                return rhs(tt, y)[1] if growing else y[1]
            ends.terminal, ends.direction = True, -1
            sol = solve_ivp(rhs, (t_now, t[-1]), [e, s], events=ends, dense_output=True, rtol=1e-10, atol=1e-13,
                            max_step=0.002)
        t_end = float(sol.t_events[0][0]) if sol.t_events[0].size else float(t[-1])
        j = i + int(np.searchsorted(t[i:], t_end, side="right"))
        if j > i:
            out[i:j] = sol.sol(t[i:j])[0]
        i = j
        if not sol.t_events[0].size:  # the grid ended within the phase (no switch to judge: before 2026-11-27 the
            break  # end of a growing phase was read as a peak on the drop and raised)
        y = sol.sol(t_end)
        if phase == "stick":
            e, s, phase, f_b = float(y[0]), 1e-12, "growing", sl.static(t_end - t_stick0)
        elif phase == "growing":
            e, s = float(y[0]), float(y[1])
            phase = "plateau" if f_b - sl.alpha * s / sl.v_u > sl.kinetic(s) else "shrinking"
        elif phase == "plateau":
            e = float(y[0])
            phase = "shrinking" if sl.k * e <= sl.f0 * sl.kinetic(s) * (1 + 1e-9) else "growing"
        else:
            e, s, phase, t_stick0 = float(y[0]), 0.0, "stick", t_end
            if sl.k * e > sl.f0 * sl.static(0.0):
                raise RuntimeError(f"slip reversal at t = {t_end:.4f} s: not modelled here")
        t_now = t_end
        if phases is not None:
            phases.append((t_now, phase))
    return out
