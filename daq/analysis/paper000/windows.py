"""Slip windows: one slip episode of one mass, cut from a recording and simulated with the rig's own physics.

Why windows and not the whole record: a whole record simulated from its start drifts
in phase, and pointwise error is then swamped by the drift (docs/decisions/
0002-output-error-by-multiple-shooting.md). Each slip episode of a mass is simulated
with the rig's own hybrid integrator (daq.physics.beltndof.simulate; physics in one
place, docs/decisions/0001-physics-in-one-place.md) from before its break-away, where
the mass moves with the belt and its state is known from the stick line, to just
after it sticks again, and every mass's simulated position is compared with the
measured one (see SlipWindow). The fit over these windows is output_error.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from daq.physics import beltndof
from daq.physics.effects import TAIL, E
from daq.signals import savgol
from daq.sim.effectset import environment_vector
from daq.sim.rigs import BeltSim

from .equation_error import chain_force_dimless
from .preparation import BeltRun, Stick

F_BIG = 1e3  # static limit of every mass but the window's (see SlipWindow)
ST_TAU_FAR = 1e6  # [s] stick-time constant of the windows: the limit stays where it starts within a window
CLOCK_FAR = 1e12  # [s] a stick clock this far in the past (future) reads t_s/tau = 1e6 (0)
PRE_BREAK = 8  # window starts at least this many samples (and 0.6 tau0) before the detected end of the stick
POST_STICK = 4  # ... and ends this many samples after the detected start of the next stick
OTHER_BREAK_MARGIN = 8  # a window is cut this many samples before another mass's detected break
MIN_STICK_SAMPLES = 10  # shorter sticks are not used: a mass grazing the belt speed can pass the stick test


@dataclass
class SlipWindow:
    """One slip episode of one mass, simulated from a stuck start to just after it sticks again.

    Start state: the window's mass is stuck, so its velocity is the belt's and its
    position lies on the stick line (x - belt travel = const, averaged over the clean
    part of the stick: far more precise than one sample). Other masses: on their
    stick line if stuck, else Savitzky-Golay position, and a velocity that is a free
    (nuisance) parameter of the window started from the Savitzky-Golay estimate; all
    masses' positions are compared with the data.
    The simulator's static limit is f_s0 (1 + gain (1 - exp(-t_s/tau))) with t_s the
    time since the mass stuck. We set f_s0 = F_BIG, tau = ST_TAU_FAR and gain =
    f_s/F_BIG - 1 (f_s: the episode's break-away level, the nuisance), and put this
    mass's stick clock far in the past and the others' in the future: this mass breaks
    exactly when the force it needs reaches f_s, while every other mass keeps a limit
    of ~F_BIG, never breaks inside the window (the window is cut before another mass
    breaks in the data) and can always stick again (no zero-time stick/slip chatter).
    """

    run: int
    mass: int
    stick: Stick
    j0: int
    j1: int
    s0: np.ndarray  # full state at j0 (SI)
    modes: np.ndarray  # STICK/SLIP per mass at j0
    slip_dir: np.ndarray
    fs_guess: float
    fs_lo: float  # bounds of the break-away level (see slip_windows)
    fs_hi: float
    need_path: np.ndarray  # force [F0] the mass needs to stay stuck, from the data, samples j0..stick end + 2
    valid: bool  # False when the scan puts the break at the window's first sample (the window starts too late)
    x_meas: np.ndarray  # (n, L) measured positions of every mass, samples j0..j1 [m]
    sigma: np.ndarray  # (n,) their noise [m]
    free_v: np.ndarray  # masses slipping at j0 whose start velocity is a nuisance parameter
    v_guess: np.ndarray  # their start velocities [m/s] (updated by the fits)
    rt: np.ndarray
    rv: np.ndarray
    delta_mean: float = float("nan")  # mean load rate over the stick [N/s]


def _stick_line(run: BeltRun, st: Stick, travel: np.ndarray, trim_end: int) -> float:
    """x - belt travel during a stick (constant while stuck): mean over the stick's clean samples."""
    a = st.start + 1
    b = max(a + 1, st.end - trim_end)
    return float(np.mean(run.x[st.mass, a:b] - travel[a:b]))


def _stuck_at(sticks: list[Stick], j: int, trim_end: int) -> Stick | None:
    for st in sticks:
        if st.start + 1 <= j <= st.end - trim_end:
            return st
    return None


def need_dimless(run: BeltRun, xs: np.ndarray, mass: int) -> np.ndarray:
    """Friction [F0] a stuck mass needs: (K x)_i/F0 + d s (+ the belt's acceleration term), along samples."""
    mech = run.mech
    chain = chain_force_dimless(xs / mech.x_unit)[mass]
    s = run.vb / mech.v_unit
    acc = np.gradient(run.vb, 1.0 / run.rate) * mech.mass_kg / mech.normal_force_N
    return chain + mech.d * s + acc


def slip_windows(run: BeltRun, sticks: list[list[Stick]], run_index: int = 0, masses: list[int] | None = None,
                 max_periods: float = 3.0) -> tuple[list[SlipWindow], dict[str, int]]:
    """Cut a recording into slip windows (see SlipWindow); returns them and counts of what was left out."""
    mech = run.mech
    n = run.n
    half = 5
    dt = 1.0 / run.rate
    xs = savgol(run.x, half)
    vs = savgol(run.x, half, 1, dt)
    need = [need_dimless(run, np.where(np.isfinite(xs), xs, 0.0), i) for i in range(n)]
    period = 2 * math.pi * mech.tau0
    max_len = int(max_periods * period * run.rate)
    # the detected end of a stick is late by the time the slip takes to exceed the velocity noise,
    # which scales with tau0 (~0.3 tau0 for alpha_drop = 4): start the window well before it
    pre = max(PRE_BREAK, int(math.ceil(0.6 * mech.tau0 * run.rate)))
    skipped = {"open": 0, "no_next_stick": 0, "other_mass_breaks": 0, "neighbour_just_broke": 0, "too_long": 0}
    out = []
    for i in (masses if masses is not None else range(n)):
        lst = sticks[i]
        for k, st in enumerate(lst):
            if st.open_end or st.end - st.start < MIN_STICK_SAMPLES:
                skipped["open"] += 1
                continue
            if k + 1 >= len(lst):
                skipped["no_next_stick"] += 1
                continue
            j0 = max(st.start + 2, st.end - pre)
            j1 = min(lst[k + 1].start + POST_STICK, run.t.size - 1)
            if j1 - j0 > max_len:
                skipped["too_long"] += 1
                continue
            j1, why = _cut_before_other_breaks(sticks, n, i, st, j0, j1, pre)
            if why:
                skipped[why] += 1
                continue
            s0, modes, sdir = _start_state(run, sticks, i, st, j0, xs, vs)
            free = np.flatnonzero(modes == beltndof.SLIP)
            a, b = max(j0 - 1, 0), min(j1 + 2, run.t.size)
            rt = np.ascontiguousarray(run.t[a:b])
            rv = np.ascontiguousarray(run.vb[a:b])
            fs_guess = float(need[i][st.end - 1])
            # bounds of f_s: the detected stick end is late, so f_s < guess
            fs_lo = max(0.05, 0.75 * fs_guess)
            fs_hi = max(fs_lo + 0.1, 1.1 * fs_guess)
            out.append(SlipWindow(run_index, i, st, j0, j1, s0, modes, sdir, fs_guess, fs_lo, fs_hi,
                                  np.abs(need[i][j0:min(st.end + 3, j1 + 1)]), True,
                                  run.x[:, j0:j1 + 1].copy(), run.sigma_x.copy(), free, s0[n + free].copy(),
                                  rt, rv, _mean_load_rate(run, st, need[i])))
    return out, skipped


def _cut_before_other_breaks(sticks: list[list[Stick]], n: int, i: int, st: Stick, j0: int, j1: int, pre: int
                             ) -> tuple[int, str | None]:
    """The window's end, cut OTHER_BREAK_MARGIN samples before any other mass breaks away inside it;
    or the reason (a key of slip_windows' counts) to leave the window out."""
    cut = j1
    recent = False
    for o in range(n):
        if o == i:
            continue
        for so in sticks[o]:
            if j0 < so.end <= j1 and not so.open_end:
                cut = min(cut, so.end - OTHER_BREAK_MARGIN)
            # a neighbour that broke away just before j0 may still be on its drop branch, which
            # the window cannot start it on: leave such windows out
            if j0 - pre - OTHER_BREAK_MARGIN <= so.end <= j0 and not so.open_end:
                recent = True
    if recent:
        return cut, "neighbour_just_broke"
    if cut < st.end + 10:  # not even the start of the slip left
        return cut, "other_mass_breaks"
    return cut, None


def _start_state(run: BeltRun, sticks: list[list[Stick]], i: int, st: Stick, j0: int, xs: np.ndarray,
                 vs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Full state (SI), STICK/SLIP modes and slip directions of every mass at the window's start j0.

    Stuck masses (the window's own, stuck on ``st``) sit on their stick line at belt speed; the
    others take the Savitzky-Golay position and velocity. The tail starts at ambient temperature
    with the belt's speed and travel.
    """
    n = run.n
    travel = run.belt_travel
    s0 = np.zeros(beltndof.n_state(n))
    modes = np.full(n, beltndof.SLIP)
    sdir = np.ones(n)
    for o in range(n):
        so = st if o == i else _stuck_at(sticks[o], j0, 2)
        if so is not None:
            s0[o] = _stick_line(run, so, travel, 4 if so is st else 2) + travel[j0]
            s0[n + o] = run.vb[j0]
            modes[o] = beltndof.STICK
        else:
            s0[o] = xs[o, j0]
            s0[n + o] = vs[o, j0]
            sdir[o] = 1.0 if run.vb[j0] - vs[o, j0] >= 0 else -1.0
    tail = 2 * n
    s0[tail + TAIL.TEMP] = run.cfg.contact.t_ambient_C
    s0[tail + TAIL.VLAG] = run.vb[j0]
    s0[tail + TAIL.POS] = travel[j0]
    return s0, modes, sdir


def _mean_load_rate(run: BeltRun, st: Stick, need: np.ndarray) -> float:
    """Mean load rate while stuck [N/s]: slope of the needed force over the stick (the rate the static
    law reads is the one at the break-away, from the fitted window: see belt_law._load_rate)."""
    seg = slice(st.start + 1, max(st.start + 3, st.end - 2))
    tt = run.t[seg]
    return float(np.polyfit(tt, need[seg] * run.mech.normal_force_N, 1)[0]) if tt.size >= 3 else float("nan")


class WindowSimulator:
    """Simulates slip windows with given law parameters through daq.physics.beltndof.simulate.

    Why not a daq.sim.rigs.BeltSim (the SimRig daq.models.fit.shooting drives): each window
    needs its own hybrid state (modes, slip directions, stick clocks, the break-away
    level) set at its start, and a SimRig carries one for all calls; output_error.py's
    docstring has the measured difference.
    """

    def __init__(self, run: BeltRun, n_sub: int | None = None) -> None:

        self.run = run
        cfg_n = run.cfg.model_copy(update={"mechanics": run.cfg.mechanics.model_copy(
            update={"n_masses": run.n})})
        e = environment_vector(cfg_n)
        e[E.D_BELT] = run.mech.d
        e[E.ST_TAU] = ST_TAU_FAR
        e[E.FR_GAIN] = 0.0
        e[E.TEMP_COEF] = 0.0
        e[E.VB_TAU] = 0.0
        e[E.VB_RIPPLE] = 0.0
        e[E.VS_D] = 0.0
        self.e = e
        self.p = BeltSim(cfg_n, e).params()
        dt_cfg = run.cfg.integrator.dt_s
        self.n_sub = n_sub or max(1, int(math.ceil((1.0 / run.rate) / dt_cfg - 1e-9)))
        self.h = 1.0 / run.rate / self.n_sub

    def simulate(self, w: SlipWindow, law: np.ndarray, fs: float, fine: int = 1, v: np.ndarray | None = None):
        """States and modes at the window's samples (fine > 1: fine-times finer), law = LAW values.

        ``v``: start velocities of the window's free masses (default: their current guess).
        """

        P = beltndof.P
        H = beltndof.H
        p = self.p.copy()
        p[P.F_S0] = F_BIG
        p[P.ALPHA_DROP], p[P.F_K0], p[P.K_FALL], p[P.W_MIN], p[P.K_RISE] = law[:5]
        e = self.e.copy()
        e[E.AS_AMP] = law[5]
        e[E.ST_GAIN] = fs / F_BIG - 1.0
        n = self.run.n
        hs = beltndof.new_hybrid(n, fs, 1.0)
        t0 = float(self.run.t[w.j0])
        for o in range(n):
            hs[H.MODE, o] = w.modes[o]
            hs[H.SLIP_DIR, o] = w.slip_dir[o]
            hs[H.FS_BREAK, o] = (1.0 + law[5]) * law[1]
            hs[H.STICK_T0, o] = t0 - CLOCK_FAR if o == w.mass else t0 + CLOCK_FAR
        n_out = (w.j1 - w.j0) * fine + 1
        m = max(1, int(math.ceil(self.n_sub / fine)))  # internal steps per output, no longer than the config's
        dt = 1.0 / (self.run.rate * fine * m)
        s0 = w.s0.copy()
        s0[n + w.free_v] = w.v_guess if v is None else v
        states, _, _, modes, _ = beltndof.simulate(s0, t0, dt, m, n_out, p, e, w.rt, w.rv, hs)
        return states, modes
