"""Figures of ``daq analyse rsf`` as a rock-friction lab draws them: friction against load-point displacement
with each event's fit overlaid and the residuals beneath; the healing of static friction against log hold time.

Written with the one figure writer ``daq.io.png.save_png``.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from daq.io.png import save_png

from .analysis import Curves, RsfFile

MAX_FILES_DRAWN = 12  # a batch of thousands of records draws its first dozen (the table holds every event)


def record_figure(f: RsfFile, c: Curves, path: Path) -> Path:
    """mu against load-point travel, the favoured law's fit over each event, residuals below."""
    fig, (ax, ar) = plt.subplots(2, 1, figsize=(11, 7), sharex=True, height_ratios=(3, 1), constrained_layout=True)
    x_um = 1e6 * c.travel
    ax.plot(x_um, c.mu, color="0.6", lw=0.6, label="record")
    for (sl, curve), ev in zip(c.fitted, f.events):
        fit = ev.fits.get(ev.law) or min(ev.fits.values(), key=lambda q: q.rss)
        ax.plot(x_um[sl], curve, lw=1.4, label=None)
        ar.plot(x_um[sl], c.mu[sl] - curve, lw=0.5)
        label = ((f"hold {ev.hold_s:.3g} s" if ev.kind == "hold"
                  else f"{1e6 * ev.v1_m_per_s:.3g}->{1e6 * ev.v2_m_per_s:.3g} um/s")
                 + f"\na={fit.a.value:.4f} b={fit.b.value:.4f}\nDc={1e6 * fit.Dc_m.value:.3g} um ({ev.law})")
        up = not (ev.kind == "step" and ev.v2_m_per_s < ev.v1_m_per_s)
        i = int(np.argmax(curve) if up else np.argmin(curve))  # at the event's peak (a step down: its trough)
        ax.annotate(label, (x_um[sl][i], curve[i]), xytext=(4, 4 if up else -4), textcoords="offset points",
                    fontsize=6.5, ha="left", va="bottom" if up else "top")
    ax.margins(y=0.18)
    ax.set_ylabel("friction mu")
    ax.set_title(f"{Path(f.data).name}: friction against load-point displacement, each event's fit "
                 "(the law it favours)")
    ax.legend(loc="lower left", fontsize=8)
    ar.axhline(0.0, color="k", lw=0.5)
    ar.set_ylabel("residual")
    ar.set_xlabel("load-point displacement [um]")
    return save_png(fig, path)


def healing_figure(files: list[RsfFile], path: Path) -> Path | None:
    """Peak friction change after each hold against log10 of the hold, with beta's line, per recording."""
    drawn = [f for f in files if f.healing is not None]
    if not drawn:
        return None
    fig, ax = plt.subplots(figsize=(7, 5), constrained_layout=True)
    for f in drawn[:MAX_FILES_DRAWN]:
        h = f.healing
        x = np.log10(h.holds_s)
        pts = ax.plot(x, h.peak_changes, "o", label=f"{Path(f.data).name}: beta = {h.beta.value:.4g} "
                                                     f"+- {h.beta.se:.2g} per decade")
        xs = np.linspace(x.min(), x.max(), 20)
        ax.plot(xs, h.intercept + h.beta.value * xs, "-", color=pts[0].get_color(), lw=1)
    ax.set_xlabel("log10 hold time [s]")
    ax.set_ylabel("peak friction change on re-sliding, Delta mu_peak")
    ax.set_title("healing: static friction against hold time")
    ax.legend(fontsize=8)
    return save_png(fig, path)


def figures(files: list[RsfFile], curves: list[Curves], outdir: Path) -> list[Path]:
    outdir.mkdir(parents=True, exist_ok=True)
    paths = [record_figure(f, c, outdir / f"rsf-{k:03d}-{Path(f.data).stem}.png")
             for k, (f, c) in enumerate(zip(files[:MAX_FILES_DRAWN], curves))]
    heal = healing_figure(files, outdir / "rsf-healing.png")
    return paths + ([heal] if heal else [])
