"""Paper 001's figures of an analysed brake run: spectrograms, planes, friction, transitions timeline.

Why these four: they are the paper's own views (spectrograms: Figs. 4, 5, 10; phase and configuration
planes: Figs. 6, 7, 11; effective friction of eq. (10) and law (7); the section-5 segments on a
timeline), each with the features that decided our numbers (the transition bias profile, the mismatch,
sub-harmonic and bandwidth traces), so a reader can check a result by eye. Each figure function takes
the result and the :class:`~.analysis.RunContext` and writes one PNG (:func:`daq.io.png.save_png`).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Patch

from daq.io.png import save_png
from daq.physics.friction import mu_brake

from .analysis import BrakeRunResult, RunContext
from .reference import PAPER_160_BOUNDARIES

KIND_COLOURS = {"quasi-steady": "#4daf4a", "period-doubling": "#377eb8", "period-3": "#984ea3",
                "period-4": "#a65628", "irregular": "#e41a1c", "quiet": "#999999", "widening": "#ff7f00"}


def _envelope(t: np.ndarray, y: np.ndarray, buckets: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """A dense trace as a min/max zigzag per bucket: looks the same as every sample, draws 10x faster."""
    if t.size <= 4 * buckets:
        return t, y
    n = t.size // buckets * buckets
    tb = t[:n].reshape(buckets, -1).mean(axis=1)
    yb = y[:n].reshape(buckets, -1)
    return np.repeat(tb, 2), np.column_stack([yb.min(axis=1), yb.max(axis=1)]).ravel()


def _spec_panel(ax, spec, title: str, modes: list[float], fmax: float = 50.0):
    f, tt, pxx = spec
    db = 10 * np.log10(pxx + 1e-30)
    top = np.percentile(db, 99.9)
    im = ax.pcolormesh(tt, f, db, shading="auto", cmap="jet", vmin=top - 90, vmax=top, rasterized=True)
    for m in modes:
        ax.axhline(m, color="white", lw=0.7, ls="--", alpha=0.7)
    ax.set_ylim(0, fmax)
    ax.set_ylabel("f [Hz]")
    ax.set_title(title, fontsize=10)
    return im


def spectrogram_figure(res: BrakeRunResult, ctx: RunContext, path) -> None:
    """Time histories of x1 and x1' over their spectrograms (paper Figs. 4, 5, 10)."""

    fs = ctx.fs
    fig, ax = plt.subplots(4, 1, figsize=(12, 11), sharex=True, constrained_layout=True,
                           gridspec_kw={"height_ratios": [1, 2, 1, 2]})
    ax[0].plot(*_envelope(fs.t, fs.x1 * 1e3), lw=0.3, color="C0")
    ax[0].set_ylabel("x1 [mm]")
    ax[0].set_title("block displacement x1", fontsize=10)
    modes = res.spectrogram.modes_hz
    im = _spec_panel(ax[1], ctx.spec_x, "spectrogram of x1, 10 log10(PSD) [dB re 1 m²/Hz]; dashed: linearised "
                     f"modes {', '.join(f'{m:.2f}' for m in modes)} Hz", modes)
    fig.colorbar(im, ax=ax[1], label="dB", pad=0.01)
    ax[2].plot(*_envelope(fs.t, fs.x1d), lw=0.3, color="C0", label="x1' (estimated from x1)")
    ax[2].plot(fs.t, fs.vb, lw=1.0, color="C3", label="vb (measured)")
    ax[2].set_ylabel("x1' [m/s]")
    ax[2].legend(loc="lower right", fontsize=8)
    ax[2].set_title("block velocity x1' (the sticking phases ride on the belt speed)", fontsize=10)
    im = _spec_panel(ax[3], ctx.spec_v, "spectrogram of x1' [dB re 1 (m/s)²/Hz] (512-sample Hamming window, "
                     "overlap 256, 100 Hz, as the paper)", modes)
    fig.colorbar(im, ax=ax[3], label="dB", pad=0.01)
    ax[3].set_xlabel("t [s]")
    fig.suptitle(f"paper 001 spectrograms: {_name(res.data)} (belt V0 = {res.belt_V0_m_per_s:.3f} m/s, "
                 f"Tmax = {res.belt_Tmax_s:.0f} s)")
    save_png(fig, path, dpi=100)


def _name(p: str) -> str:
    return Path(p).name


def planes_figure(res: BrakeRunResult, ctx: RunContext, path) -> None:
    """Phase planes (x1, x1') and configuration planes (x1, y1) in time windows (paper Figs. 6, 7, 11)."""

    fs = ctx.fs
    n = len(res.planes)
    fig, ax = plt.subplots(2, n, figsize=(3.2 * n + 1, 7), constrained_layout=True, squeeze=False)
    for j, w in enumerate(res.planes):
        m = (fs.t >= w.start_s) & (fs.t <= w.end_s)
        a = ax[0, j]
        a.plot(fs.x1[m] * 1e3, fs.x1d[m], lw=0.5, color="C0")
        a.axhline(w.vb_mean_m_per_s, color="C3", lw=0.8, ls="--", label=f"mean vb {w.vb_mean_m_per_s:.3f}")
        a.set_title(f"phase plane {w.start_s:g} < t < {w.end_s:g} s", fontsize=9)
        a.set_xlabel("x1 [mm]")
        a.set_ylabel("x1' [m/s]")
        a.legend(loc="lower right", fontsize=7)
        b = ax[1, j]
        b.plot(fs.x1[m] * 1e3, fs.y1[m] * 1e3, lw=0.5, color="C2")
        b.set_title(f"configuration {w.start_s:g} < t < {w.end_s:g} s", fontsize=9)
        b.set_xlabel("x1 [mm]")
        b.set_ylabel("y1 = r phi [mm]")
    fig.suptitle(f"paper 001 phase and configuration planes: {_name(res.data)}")
    save_png(fig, path, dpi=100)


def friction_figure(res: BrakeRunResult, ctx: RunContext, path) -> None:
    """mu_eff(t), mu against V_rel with the fitted law (7), F/(m g) against eq. (10), and the bias profile."""

    fs = ctx.fs
    fr = res.friction
    mu0, gam = fr.fit.params["mu0"].value, fr.fit.params["gamma"].value
    used = (fs.slip == 1) & (np.abs(fs.v_rel) >= fr.v_min_m_per_s) & (fs.dist_s >= fr.exclusion_s)
    fig, ax = plt.subplots(2, 2, figsize=(13, 9), constrained_layout=True)
    # (a) a one-second zoom of mu_eff(t)
    T = fs.t[-1] - fs.t[0]
    a0 = fs.t[0] + 0.25 * T
    m = (fs.t >= a0) & (fs.t <= a0 + 1.0)
    a = ax[0, 0]
    a.plot(fs.t[m], fs.mu_eff[m], lw=0.8, color="0.4", label="F/(m g), all samples")
    a.plot(fs.t[m], np.where(used[m], fs.mu_eff[m], np.nan), lw=1.2, color="C0", label="samples fitted")
    a.plot(fs.t[m], np.where(fs.slip[m] == 0, fs.mu_eff[m], np.nan), lw=1.2, color="C1",
           label="stick/creep (|V_rel| < v_stick)")
    a.set_xlabel("t [s]")
    a.set_ylabel("mu_eff = F/(m g)")
    a.set_title("effective friction coefficient (eq. 10's left side), 1 s of the run", fontsize=10)
    a.legend(fontsize=8, loc="lower right")
    # (b) mu against V_rel
    vv = np.linspace(min(-0.05, np.nanpercentile(fs.v_rel, 0.5)), max(0.05, np.nanpercentile(fs.v_rel, 99.5)), 800)
    b = ax[0, 1]
    stride = max(1, fs.t.size // 40000)
    b.plot(fs.v_rel[::stride], fs.mu[::stride], ".", ms=1, color="0.75", label="all samples (mu = F/N)")
    b.plot(fs.v_rel[used][::stride], fs.mu[used][::stride], ".", ms=1, color="C0", alpha=0.5,
           label="fitted samples")
    b.plot(vv, mu_brake(vv, mu0, gam, ctx.alpha, ctx.beta), color="C3", lw=1.5,
           label=f"fit: mu0 = {mu0:.4f} ± {fr.fit.params['mu0'].std:.4f}, gamma = {gam:.3f} ± "
                 f"{fr.fit.params['gamma'].std:.3f} s/m")
    b.plot(vv, mu_brake(vv, ctx.mu0_cfg, ctx.gamma_cfg, ctx.alpha, ctx.beta), color="k", lw=0.8, ls="--",
           label=f"rig config law (mu0 = {ctx.mu0_cfg:g}, gamma = {ctx.gamma_cfg:g})")
    b.set_ylim(-1.0, 1.0)
    b.set_xlabel("V_rel = x1' - vb [m/s]")
    b.set_ylabel("mu = F/N")
    b.set_title(f"law (7) fitted (alpha = {ctx.alpha:g}, beta = {ctx.beta:g} held)", fontsize=10)
    b.legend(fontsize=7, loc="upper left", markerscale=8)
    # (c) F/(m g) against V_rel and eq. (10)
    c = ax[1, 0]
    c.plot(fs.v_rel[::stride], fs.mu_eff[::stride], ".", ms=1, color="0.75", label="F/(m g), all samples")
    p_m10 = fr.fit_eq10.params
    c.plot(vv, (1 + fr.kappa1) * mu_brake(vv, mu0, gam, ctx.alpha, ctx.beta)
           / (1 + fr.kappa2 * mu_brake(vv, mu0, gam, ctx.alpha, ctx.beta)), color="C3", lw=1.5,
           label="eq. (10) of the fitted law (7)")
    c.plot(vv, mu_brake(vv, mu0, gam, ctx.alpha, ctx.beta), color="C3", lw=0.8, ls=":", label="law (7) itself")
    c.set_ylim(-2.0, 2.0)
    c.set_xlabel("V_rel [m/s]")
    c.set_ylabel("mu_eff = F/(m g)")
    c.set_title(f"eq. (10), quasi-static: kappa1 = {fr.kappa1:.3f}, kappa2 = {fr.kappa2:.4f}; law (7) fitted\n"
                f"through it: mu0 = {p_m10['mu0'].value:.3f}, gamma = {p_m10['gamma'].value:.2f} (biased: in slip "
                "N of eq. (6) swings)", fontsize=9)
    c.legend(fontsize=8, loc="upper left", markerscale=8)
    # (d) bias profile
    d = ax[1, 1]
    prof = [bb for bb in fr.bias_profile if bb.n > 0]
    lo = np.array([bb.d_from_s for bb in prof]) * 1e3
    hi = np.array([bb.d_to_s if np.isfinite(bb.d_to_s) else bb.d_from_s + (lo[1] - lo[0]) / 1e3 for bb in prof]) * 1e3
    mid = 0.5 * (lo + hi)
    d.plot(mid, [bb.median for bb in prof], "o-", color="C0", label="median residual")
    d.plot(mid, [bb.rms for bb in prof], "s-", color="C1", label="rms residual")
    d.axhspan(-fr.bias_tolerance, fr.bias_tolerance, color="C0", alpha=0.15, label=f"|bias| <= {fr.bias_tolerance}")
    d.axvline(fr.exclusion_s * 1e3, color="k", ls="--", label=f"chosen exclusion {fr.exclusion_s * 1e3:.1f} ms")
    d.set_xlabel("distance to the nearest stick-slip transition [ms] (last bin: and beyond)")
    d.set_ylabel("mu residual vs preliminary fit")
    d.set_title("bias of friction from twice-differentiated x1, by distance to a transition", fontsize=10)
    d.text(0.98, 0.5, fr.differentiator.replace(", centred", "").replace(" (", "\n("), transform=d.transAxes,
           ha="right", fontsize=8, color="0.3")
    d.legend(fontsize=8)
    fig.suptitle(f"paper 001 effective friction and law (7): {_name(res.data)} "
                 f"({fr.fit.n_points} samples fitted, residual rms {fr.fit.rms:.4f})")
    save_png(fig, path, dpi=100)


def timeline_figure(res: BrakeRunResult, ctx: RunContext, path) -> None:
    """The segments on a timeline under the x1 spectrogram, with the features that decided them."""

    tr = ctx.trace
    trans = res.transitions
    cfg = trans.cfg
    fig, ax = plt.subplots(5, 1, figsize=(13, 12), sharex=True, constrained_layout=True,
                           gridspec_kw={"height_ratios": [2.2, 0.8, 1.2, 1.2, 1.0]})
    im = _spec_panel(ax[0], ctx.spec_x, "spectrogram of x1 [dB] with the detected segment boundaries",
                     res.spectrogram.modes_hz, fmax=40.0)
    fig.colorbar(im, ax=ax[0], label="dB", pad=0.01)
    for s in trans.segments:
        if s.track == "regime":
            ax[0].axvline(s.start_s, color="white", lw=0.8)
    # timeline tracks
    tl = ax[1]
    for s in trans.segments:
        y = 1.0 if s.track == "regime" else 0.0
        tl.broken_barh([(s.start_s, s.end_s - s.start_s)], (y - 0.4, 0.8), color=KIND_COLOURS.get(s.kind, "k"))
    tl.set_yticks([1.0, 0.0], ["regime\n(cycles)", "spectrum"])
    tl.set_ylim(-0.6, 1.6)
    kinds = sorted({s.kind for s in trans.segments}, key=list(KIND_COLOURS).index)
    tl.legend(handles=[Patch(color=KIND_COLOURS[k], label=k) for k in kinds], ncol=len(kinds), fontsize=8,
              loc="lower left", bbox_to_anchor=(0, 1.0), frameon=False)
    # cycle mismatch
    c = ax[2]
    for n in range(1, min(2, cfg.max_period) + 1):
        c.semilogy(tr.cycle_t, np.clip(tr.mismatch[n - 1], 1e-5, None), lw=0.9,
                   label=f"period-{n} mismatch" + (" (alternation)" if n == 1 else ""))
    c.axhline(cfg.mismatch_tol, color="k", ls="--", lw=0.8, label=f"tau = {cfg.mismatch_tol}")
    c.set_ylabel("relative mismatch")
    c.legend(fontsize=8, loc="upper center", ncol=3)
    c.set_title("cycle-to-cycle: n-step second difference of peak rise / interval", fontsize=9, loc="right")
    # subharmonic line
    s_ = ax[3]
    s_.plot(tr.col_t, tr.sub_db, "o-", ms=3, color="C4", label="f/2 or 3f/2 line re f line [dB]")
    s_.axhline(cfg.subharmonic_db, color="C4", ls="--", lw=0.8, label=f"{cfg.subharmonic_db:g} dB")
    s_.set_ylabel("sub-harmonic [dB]")
    s_.legend(fontsize=8, loc="upper left")
    b = ax[4]
    b.plot(tr.col_t, tr.bandwidth_hz / trans.reference_bandwidth_hz, "o-", ms=3, color="C1",
           label=f"entropy bandwidth of x1' / reference ({trans.reference_bandwidth_hz:.2f} Hz)")
    b.axhline(cfg.widening_factor, color="C1", ls="--", lw=0.8, label=f"widening: x {cfg.widening_factor:g}")
    b.set_yscale("log")
    b.set_ylabel("bandwidth ratio")
    b.set_xlabel("t [s]")
    b.legend(fontsize=8, loc="upper left")
    if ctx.paper_marks:
        for a_ in ax:
            for x in PAPER_160_BOUNDARIES:
                a_.axvline(x, color="m", ls=":", lw=1.0)
    marks = ("\ndotted magenta: the paper's Fig. 8 segment boundaries (98, 110, 130, 135, 140, 150 s)"
             if ctx.paper_marks else "")
    fig.suptitle(f"paper 001 transitions: {_name(res.data)} ({trans.n_cycles} cycles); detected segments below the "
                 f"spectrogram{marks}")
    save_png(fig, path, dpi=100)


FIGURES = {"spectrogram.png": spectrogram_figure, "planes.png": planes_figure, "friction.png": friction_figure,
           "transitions.png": timeline_figure}
