"""Stick–slip cycles, live: each stick phase and the slip that ends it, measured as the estimates arrive.

Why in the estimator: a friction researcher looks first at the cycles (break-away force,
how long the contact stuck, how far and how fast it slipped), and the estimator already
knows friction force and relative velocity sample by sample. A cycle is one **stick phase**
(|v_rel| inside the stick band, by the estimator's own regime classification with
hysteresis) followed by one **slip phase**; it is complete, and published, when the next
stick phase begins. Per cycle:

- ``breakaway_N``: the largest |F| over the stick phase up to the sample where slip is
  declared (the static friction the contact held before it let go), and ``mu_breakaway``
  the same over the normal force there;
- ``stick_s``: the stick phase's length; ``slip_s`` the slip phase's;
- ``slip_m``: the relative distance slipped, the integral of |v_rel| over the slip phase;
- ``peak_slip_m_per_s``: the largest |v_rel| in the slip phase.

A stick phase shorter than ``min_stick_s`` is not a stick (a noisy v_rel brushing the
band), so it does not split a slip; the first phase after a start or a gap is incomplete
and never counted. Work per block: a few numpy reductions per regime switch (a switch
every ~50 ms on the brake rig), so it stays off the estimator's latency.

The same detector on the simulator's true v_rel and friction force gives the truth that
tests/test_cycles.py compares with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CYCLE_STREAM = "cycles"
CYCLE_UNITS = {"breakaway_N": "N", "mu_breakaway": "-", "stick_s": "s", "slip_s": "s", "slip_m": "m",
               "peak_slip_m_per_s": "m/s"}
MIN_STICK_S = 0.01
TIME_EPS = 1e-6  # [s] time differences are compared with this slack: a run's absolute times differ in the last bits


@dataclass
class Cycle:
    """One stick–slip cycle; ``t`` is the break-away (stick -> slip) time [s]."""

    t: float
    breakaway_N: float
    mu_breakaway: float
    stick_s: float
    slip_s: float
    slip_m: float
    peak_slip_m_per_s: float

    def row(self) -> list[float]:
        return [getattr(self, k) for k in CYCLE_UNITS]


class CycleDetector:
    """Incremental: feed (t, F, N, v_rel, slip) per block; get the cycles completed in it.

    A cycle opens at a break-away that ends a real stick phase, and is published once the
    next stick phase has lasted ``min_stick_s`` (then it is a real stick, and the slip ended
    where it began): about 10 ms after the slip ends.
    """

    def __init__(self, min_stick_s: float = MIN_STICK_S) -> None:
        self.min_stick_s = min_stick_s
        self.reset()

    def reset(self) -> None:
        """Forget the phase in progress (after an input gap: what happened in it is unknown)."""
        self._state = -1  # 0 stick, 1 slip, -1 not yet known
        self._stick_t0: float | None = None  # start of the stick phase in progress (None: began before our data)
        self._f_max = 0.0
        self._n_at_max = float("nan")
        self._open: Cycle | None = None  # broke away; its slip is being measured
        self._t_prev: float | None = None

    def feed(self, t: np.ndarray, F: np.ndarray, N: np.ndarray, v_rel: np.ndarray, slip: np.ndarray) -> list[Cycle]:
        """The cycles completed in this block."""
        if t.size == 0:
            return []
        s = slip.astype(np.int8)
        if self._state < 0:
            self._state = int(s[0])
        cuts = np.flatnonzero(np.diff(np.concatenate(([self._state], s))) != 0)
        bounds = [0, *cuts.tolist(), t.size]
        out: list[Cycle] = []
        for a, b in zip(bounds[:-1], bounds[1:]):
            if a in cuts:
                self._switch(int(s[a]), float(t[a]))
            if b > a:
                self._accumulate(t[a:b], F[a:b], N[a:b], v_rel[a:b], out)
        return out

    def _switch(self, new: int, t: float) -> None:
        """A regime switch at time ``t`` to ``new`` (0 stick, 1 slip)."""
        if new == 1:  # break-away
            real = self._stick_t0 is not None and t - self._stick_t0 >= self.min_stick_s - TIME_EPS
            if real:
                self._open = Cycle(t=t, breakaway_N=self._f_max, stick_s=t - self._stick_t0, slip_s=0.0, slip_m=0.0,
                                   mu_breakaway=self._f_max / self._n_at_max if self._n_at_max else float("nan"),
                                   peak_slip_m_per_s=0.0)
            # else: a flicker inside a slip (the open cycle's slip goes on), or the first stick after a start
        else:
            self._stick_t0, self._f_max, self._n_at_max = t, 0.0, float("nan")
        self._state = new

    def _accumulate(self, t: np.ndarray, F: np.ndarray, N: np.ndarray, v: np.ndarray, out: list[Cycle]) -> None:
        """Fold a piece of one phase into its running figures; close the open cycle once a stick is real."""
        if self._state == 0:
            i = int(np.argmax(np.abs(F)))
            if abs(F[i]) >= self._f_max:
                self._f_max, self._n_at_max = float(abs(F[i])), float(N[i])
            c = self._open
            if c is not None and self._stick_t0 is not None and t[-1] - self._stick_t0 >= self.min_stick_s - TIME_EPS:
                c.slip_s = self._stick_t0 - c.t
                out.append(c)
                self._open = None
        elif self._open is not None:
            av = np.abs(v)
            dt = np.diff(np.concatenate(([self._t_prev if self._t_prev is not None else t[0]], t)))
            self._open.slip_m += float(np.dot(av, dt))
            self._open.peak_slip_m_per_s = max(self._open.peak_slip_m_per_s, float(av.max()))
        self._t_prev = float(t[-1])
