"""Paper 002's figures for ``daq analyse drum-mu --report``: mu(t), mu against v with law (3), residuals.

Written with the one figure writer ``daq.io.png.save_png`` (atomic, 110 dpi as before).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D
from matplotlib.ticker import FixedLocator, NullFormatter, ScalarFormatter

from daq.io.png import save_png

from .analysis import DrumMuResult
from .kinematics import MuSeries
from .law import law


def figures(res: DrumMuResult, s: MuSeries, outdir: Path) -> list[Path]:
    """mu(t) with the used samples marked; mu vs v with the fit; residuals vs v and t."""

    matplotlib.use("Agg")

    outdir.mkdir(parents=True, exist_ok=True)
    name = Path(res.data).name
    bins = _SpeedBins.of(np.abs(s.v)[s.used])
    return [_mu_t_figure(res, s, name, outdir), _mu_v_figure(res, s, name, bins, outdir),
            _residuals_figure(res, s, name, bins, outdir)]


@dataclass
class _SpeedBins:
    """Log-spaced bins of the used sliding speeds |v_wz| (those with >= 20 samples) for bin medians."""

    vv: np.ndarray  # 400 speeds over the used range, for the law's curve
    idx: np.ndarray  # bin of every used sample
    full: list[int]  # bins with >= 20 samples
    mids: np.ndarray  # median speed of each full bin

    @classmethod
    def of(cls, av_u: np.ndarray) -> _SpeedBins:
        vv = np.geomspace(max(av_u.min(), 1e-5), av_u.max(), 400)
        edges = np.geomspace(vv[0], vv[-1] * 1.0001, 40)
        idx = np.digitize(av_u, edges)
        full = [i for i in range(1, edges.size) if np.sum(idx == i) >= 20]
        return cls(vv, idx, full, np.array([np.median(av_u[idx == i]) for i in full]))

    def medians(self, y: np.ndarray) -> np.ndarray:
        return np.array([np.median(y[self.idx == i]) for i in self.full])


def _mu_t_figure(res: DrumMuResult, s: MuSeries, name: str, outdir: Path) -> Path:
    """1: mu(t) (used samples marked), v_wz with +-v_min, and the thrust N, against time."""
    u = s.used
    fig, axs = plt.subplots(3, 1, figsize=(12, 8.5), sharex=True, constrained_layout=True)
    ax = axs[0]
    ax.plot(s.t, s.mu, lw=0.3, color="0.7", label="not used (|v_wz| < v_min, guard, record edges)")
    ax.plot(s.t, np.where(u, s.mu, np.nan), lw=0.4, color="C0", label="μ(t) by eq. (2), used for law (3)")
    lo, hi = np.nanpercentile(s.mu[u], [0.5, 99.5])
    pad = 0.3 * (hi - lo) + 1e-3
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_ylabel("μ [-]")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"{name}: friction coefficient μ(t) by paper 002 eq. (2) "
                 "from φ, φ̇ (gauge D), φ̈ (accelerometer C)")
    vmin = float(res.selection["v_min_m_per_s"])
    axs[1].plot(s.t, s.v * 1e3, lw=0.4, color="C1", label="v_wz")
    axs[1].axhline(vmin * 1e3, color="k", lw=0.7, ls=":", label=f"±v_min = {vmin * 1e3:g} mm/s")
    axs[1].axhline(-vmin * 1e3, color="k", lw=0.7, ls=":")
    axs[1].set_ylabel("v_wz = R(ω − φ̇) [mm/s]")
    axs[1].legend(loc="upper right", fontsize=8)
    axs[2].plot(s.t, s.N, lw=0.4, color="C2")
    axs[2].set_ylabel("N (thrust gauge B) [N]")
    axs[2].set_xlabel("t [s]")
    for a in axs:
        a.grid(alpha=0.3)
    return save_png(fig, outdir / "mu_t.png", dpi=110)


def _mu_v_figure(res: DrumMuResult, s: MuSeries, name: str, bins: _SpeedBins, outdir: Path) -> Path:
    """2: mu against |v_wz| (linear and log) with bin medians and the fitted law (3)."""
    u = s.used
    av = np.abs(s.v)
    c = res.fit.coefficients
    coef_txt = (f"A={c['A'].value:.4g}  B={c['B'].value:.4g} s/m  C={c['C'].value:.4g} s/m  "
                f"D={c['D'].value:.4g} s/m  E={c['E'].value:.4g}  R²={res.fit.R2:.4f}")
    meds = bins.medians(s.mu[u])
    step = max(1, int(u.sum()) // 8000)
    fig, ax = plt.subplots(1, 2, figsize=(13, 5.5), constrained_layout=True)
    for k, axk in enumerate(ax):
        axk.plot(av[u][::step] * 1e3, s.mu[u][::step], ".", ms=1.2, alpha=0.3, color="C0")
        axk.plot(bins.mids * 1e3, meds, "o", ms=4, color="C1")
        axk.plot(bins.vv * 1e3, law(bins.vv, res.fit.theta(), res.sgn_eps_m_per_s), color="k", lw=1.5)
        axk.set_xlabel("sliding speed v_wz [mm/s]" + (" (log scale)" if k else ""))
        axk.set_ylabel("μ [-]")
        if k:
            _log_mm(axk)
        lo, hi = np.nanpercentile(s.mu[u], [0.2, 99.8])
        axk.set_ylim(lo - 0.15 * (hi - lo), hi + 0.15 * (hi - lo))
        axk.grid(alpha=0.3)
    ax[0].legend([Line2D([], [], ls="", marker=".", color="C0"), Line2D([], [], ls="", marker="o", ms=4, color="C1"),
                  Line2D([], [], color="k", lw=1.5)], ["μ(t) samples used", "bin medians", "law (3) fitted"],
                 fontsize=8, loc="upper center")
    fig.suptitle(f"{name}: law (3) fitted, P ≈ {res.thrust_N['mean']:.1f} N\n{coef_txt}", fontsize=10)
    return save_png(fig, outdir / "mu_v.png", dpi=110)


def _residuals_figure(res: DrumMuResult, s: MuSeries, name: str, bins: _SpeedBins, outdir: Path) -> Path:
    """3: residuals of law (3) against |v_wz| (with bin medians) and against time."""
    u = s.used
    av = np.abs(s.v)
    step = max(1, int(u.sum()) // 8000)
    r = s.mu[u] - law(av[u], res.fit.theta(), res.sgn_eps_m_per_s)
    rmed = bins.medians(r)
    fig, ax = plt.subplots(1, 2, figsize=(13, 4.8), constrained_layout=True)
    ax[0].plot(av[u][::step] * 1e3, r[::step], ".", ms=1.2, alpha=0.3, label="samples")
    ax[0].plot(bins.mids * 1e3, rmed, "o-", ms=3, lw=1, color="C3", label="bin medians")
    _log_mm(ax[0])
    ax[0].axhline(0, color="k", lw=0.8)
    ax[0].set_xlabel("sliding speed v_wz [mm/s] (log scale)")
    ax[0].set_ylabel("μ − law (3) [-]")
    ax[0].set_title(f"residuals vs v (rms {res.fit.rms:.2g}, R² = {res.fit.R2:.4f})", fontsize=10)
    ax[0].legend([Line2D([], [], ls="", marker=".", color="C0"), Line2D([], [], marker="o", ms=3, color="C3")],
                 ["samples", "bin medians"], fontsize=8, loc="upper right")
    ax[1].plot(s.t[u][::step], r[::step], ".", ms=1.2, alpha=0.3, color="C2")
    ax[1].axhline(0, color="k", lw=0.8)
    ax[1].set_xlabel("t [s]")
    ax[1].set_ylabel("μ − law (3) [-]")
    ax[1].set_title(f"residuals vs time (n = {res.fit.n}, effective {res.fit.n_eff:.0f})", fontsize=10)
    q = np.nanpercentile(np.abs(r), 99.8)
    for a in ax:
        a.grid(alpha=0.3)
        a.set_ylim(-1.3 * q, 1.3 * q)
    fig.suptitle(f"{name}: residuals of law (3)", fontsize=11)
    return save_png(fig, outdir / "residuals.png", dpi=110)


def _log_mm(ax) -> None:
    """Log x axis in mm/s with plain tick labels (1, 2, 5, 10, ...)."""

    ax.set_xscale("log")
    lo, hi = ax.get_xlim()
    ticks = [x for x in (0.1, 0.2, 0.5, 1, 2, 3, 5, 10, 20, 30, 50, 100, 200) if lo <= x <= hi]
    ax.xaxis.set_major_locator(FixedLocator(ticks))
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())
