"""Stage 2 of the law identification: output error over slip windows (what the reported law comes from).

Why output error: the equation error (equation_error.py) is biased exactly at the
stick-slip transitions; here the law is judged by what the simulated windows
(windows.py) predict for the measured positions (docs/decisions/
0002-output-error-by-multiple-shooting.md). Shared: alpha_drop, f_k0, k_fall, w_min,
k_rise, amp; per window: the break-away level f_s at which the simulated stick ends
and the start velocities of neighbours that slip at the window's start. scipy
least_squares, block-sparse Jacobian, soft-L1 loss. The order of the steps (f_s by a
scan of the levels the data pass through, alpha_drop from a grid, then the kinetic
part, then everything, then refits) is belt_law.py's.

Why not daq/models/fit/shooting.py (multiple shooting, the models' fitter): it answers another
question. Since 2026-11-25 belt-ndof is in the model loop (models/data.py BeltData, decision
21: a window's hybrid start from the data, the static level from the model's law and
effects); this fitter identifies the law itself with a free break-away level per slip
window, which the models' fitter does not have. Measured 2026-11-24 (before BeltData) on the set of
tests/test_paper000.py (six one-mass records, 6 s at 250 Hz, seeds 0-5), with
scripts that call this package, daq.models.fit.data and daq.sim.rigs.BeltSim directly:

- (then) No belt-ndof data layer: ``daq.models.fit.data.rig_data`` on the belt-ndof config
  raised "model fitting is implemented for brake-2dof, drum-pendulum, not belt-ndof".
- A window's start is a hybrid state, not only a state vector: Problem.shoot calls
  ``SimRig.advance(s0, ...)`` with one ``BeltSim.hybrid`` for all windows (built
  slipping, stick clock at t = 0, carried from call to call); Problem's start values
  are entries of the continuous state (RigData.start_slots). With the same law, f_s,
  start state and step, and only the hybrid state as BeltSim keeps it instead of
  the window's (mass stuck, stick clock long past), the simulated positions of the
  53 windows are off by at least 3.8e3 noise units (median 6.3e3).
- The break-away level is a per-window nuisance outside the state (it sits in the
  effect vector, E.ST_GAIN): the 53 windows' f_s span 1.874-1.927, each determined
  to 8e-5 (median std); with one shared f_s (their mean) the windows fit at 17 noise units
  (median; worst 814) instead of 0.98. Its cost is flat above the largest force the
  mass needs in the window (mean-square residual 5062999.59 at f_s = 5, 10 and 20),
  hence the scan and the bounds (scan_break_levels); Problem.fit bounds only the
  shared parameters.
- Windows are one slip episode each, 61-119 samples (median 69); shooting.Windows
  has one length for all windows.
Not a reason: the loss. With ``LOSS = "linear"`` (shooting's plain least squares)
belt_law gives the same law within 0.13 of its std on these records (soft-L1 is
for the segmentation errors of other records); and the step: the config's 0.5 ms
(8 steps per sample, Problem's choice) moves the positions by 6e-3 noise units
against N_SUB = 2 and costs 2x (53 windows once: 24 ms against 12 ms). What this
fitter costs: belt_law on that set 4.0 s in all; its final joint fit, 30 windows
(6 shared parameters and 30 break-away levels), 22 evaluations in 1.2 s, rms 1.004
noise units.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from .equation_error import LAW, LsqFit, std_from_jac
from .preparation import BeltRun
from .windows import SlipWindow, WindowSimulator

LOSS = "soft_l1"  # robust loss of the output-error fits
N_SUB = 2  # internal steps per output sample in the windows: the law is piecewise linear, RK4 between
# located events is exact to ~1e-8 of the amplitude at 2 ms steps (same fits as with the config's 0.5 ms)
LAW_LO = np.array([0.2, 0.05, 0.0, 0.02, 0.0, -0.5])
LAW_HI = np.array([50.0, 5.0, 5.0, 20.0, 5.0, 0.5])


def window_residual(w: SlipWindow, states: np.ndarray) -> np.ndarray:
    """Simulated minus measured positions of every mass after the start sample, in units of their noise."""
    n = w.x_meas.shape[0]
    return ((states[1:, :n] - w.x_meas[:, 1:].T) / w.sigma).ravel()


def scan_break_levels(runs: list[BeltRun], windows: list[SlipWindow], law: np.ndarray) -> None:
    """Start value and bounds of each window's f_s: the best of the levels the data's stick passes through.

    Why a scan: above the largest force the mass needs inside the window the simulated
    mass never breaks and the cost is flat in f_s; a gradient method started there stays
    there (a late-detected stick end in a chain, where the neighbour sticks and the need
    stops growing, puts the naive guess exactly there). Each candidate is the force the
    data says the mass needs at one sample; the bounds bracket the best by four samples.
    """
    sims = [WindowSimulator(r, n_sub=N_SUB) for r in runs]
    for w in windows:
        cand = np.asarray(w.need_path, dtype=float)
        if cand.size < 2:
            continue
        step = 1 if cand.size <= 12 else 2
        idx = np.arange(0, cand.size, step)
        costs = []
        for fs in cand[idx]:
            st, _ = sims[w.run].simulate(w, law, float(fs))
            costs.append(float(np.mean(window_residual(w, st) ** 2)))
        j = int(idx[int(np.argmin(costs))])
        w.valid = j != 0
        lo_j, hi_j = max(0, j - 4), min(cand.size - 1, j + 4)
        w.fs_guess = float(cand[j])
        w.fs_lo = float(max(0.05, min(cand[lo_j:hi_j + 1].min(), w.fs_guess) - 1e-3))
        w.fs_hi = float(max(cand[lo_j:hi_j + 1].max(), w.fs_guess) + 1e-3)


def fit_output_error(runs: list[BeltRun], windows: list[SlipWindow], law0: np.ndarray,
                     free: tuple[str, ...] = LAW, fs0: np.ndarray | None = None, progress=None,
                     max_nfev: int = 40, f_scale: float = 3.0) -> tuple[LsqFit, np.ndarray, np.ndarray]:
    """Least squares of the measured positions over slip windows: shared law, one f_s per window.

    ``free`` names the law parameters fitted (the rest stay at law0). Per window the
    break-away level f_s and the start velocities of the masses slipping at its start
    are nuisance parameters (the velocities are kept in the windows for the next fit).
    Returns the law fit (std 0 for fixed parameters), the fitted break-away levels and
    their standard deviations. Residuals: every mass's position in units of its noise,
    with a soft-L1 loss beyond ``f_scale`` noise units (a window the detection got
    wrong must not drag the law). The Jacobian is block-sparse (a window's residuals
    depend on the law and its own nuisances), so scipy differences all windows' own
    columns in 1 + (free velocities per window) passes. Why this and not
    daq.models.fit.shooting.Problem.fit: see the module docstring (measured).
    """

    sims = [WindowSimulator(r, n_sub=N_SUB) for r in runs]
    nw = len(windows)
    idx = [LAW.index(k) for k in free]
    nl = len(idx)
    law0 = np.asarray(law0, dtype=float)
    sizes = [(w.j1 - w.j0) * w.x_meas.shape[0] for w in windows]
    offs = np.concatenate([[0], np.cumsum(sizes)])
    npw = [1 + w.free_v.size for w in windows]  # parameters per window: f_s, then free start velocities
    poff = nl + np.concatenate([[0], np.cumsum(npw)])
    calls = [0]

    def law_of(th):
        law = law0.copy()
        law[idx] = th[:nl]
        return law

    def resid(th):
        law = law_of(th)
        out = np.empty(offs[-1])
        for k, w in enumerate(windows):
            a = poff[k]
            st, _ = sims[w.run].simulate(w, law, th[a], v=th[a + 1:poff[k + 1]])
            out[offs[k]:offs[k + 1]] = window_residual(w, st)
        calls[0] += 1
        if progress and calls[0] % 25 == 0:
            progress(f"output error: {calls[0]} evaluations of {nw} windows, rms {np.sqrt(np.mean(out**2)):.3g} "
                     "noise units")
        return out

    sp = lil_matrix((offs[-1], poff[-1]), dtype=int)
    if nl:
        sp[:, :nl] = 1
    lo, hi, th0 = list(LAW_LO[idx]), list(LAW_HI[idx]), list(law0[idx])
    for k, w in enumerate(windows):
        sp[offs[k]:offs[k + 1], poff[k]:poff[k + 1]] = 1
        lo.append(w.fs_lo)
        hi.append(w.fs_hi)
        th0.append(w.fs_guess if fs0 is None else float(fs0[k]))
        span = 0.2 * np.abs(w.v_guess) + 0.2 * float(np.max(np.abs(w.rv))) + 0.01
        lo += list(w.v_guess - span)
        hi += list(w.v_guess + span)
        th0 += list(w.v_guess)
    lo, hi, th0 = np.array(lo), np.array(hi), np.array(th0)
    th0 = np.clip(th0, lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo))
    r = least_squares(resid, th0, bounds=(lo, hi), jac_sparsity=sp, x_scale="jac", max_nfev=max_nfev,
                      diff_step=1e-5, loss=LOSS, f_scale=f_scale)
    res = r.fun
    std_all = std_from_jac(r.jac, res, poff[-1])
    std = np.zeros(len(LAW))
    std[idx] = std_all[:nl]
    fit = LsqFit(LAW, law_of(r.x), std, float(np.sqrt(np.mean(res**2))), int(res.size),
                 {"evaluations": int(r.nfev), "status": int(r.status), "windows": nw})
    for k, w in enumerate(windows):
        w.v_guess = r.x[poff[k] + 1:poff[k + 1]].copy()
    return fit, r.x[poff[:-1]], std_all[poff[:-1]]


def window_rms(runs: list[BeltRun], windows: list[SlipWindow], law: np.ndarray, fs: np.ndarray) -> np.ndarray:
    """Rms of each window's residual [noise units] at the given law and break-away levels."""
    sims = [WindowSimulator(r, n_sub=N_SUB) for r in runs]
    out = np.empty(len(windows))
    for k, w in enumerate(windows):
        st, _ = sims[w.run].simulate(w, law, fs[k])
        out[k] = float(np.sqrt(np.mean(window_residual(w, st) ** 2)))
    return out
