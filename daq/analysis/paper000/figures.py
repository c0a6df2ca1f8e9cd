"""Figures of paper 000's identification (its Figs. 8-11 and 19), from the analyses' results.

Why a module of its own: the numerical core (the other modules of this package) stays
free of plotting; each figure reads only the pydantic result (and, for the phase plane,
the smoothed trajectory the analysis returns), so a figure can be redrawn from the JSON.
Every PNG goes through daq.io.png.save_png at 110 dpi.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # before pyplot: figures are files, no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LogNorm, Normalize  # noqa: E402

from daq.io.png import save_png  # noqa: E402

from .belt_law import BeltLawResult  # noqa: E402
from .equation_error import LAW, pwl_law  # noqa: E402
from .poincare import PoincareAnalysis  # noqa: E402
from .static_law import static_law  # noqa: E402

DPI = 110


def _law(res: BeltLawResult) -> np.ndarray:
    return np.array([res.law[k].value for k in LAW])


def belt_law_figure(res: BeltLawResult, path: str | Path) -> None:
    """Figs. 9-10: friction against relative velocity on both branches, points and the fitted law."""
    law = _law(res)
    pts = res.points
    w = np.asarray(pts["w"])
    f = np.asarray(pts["f"])
    g = np.asarray(pts["growing"])
    s = np.asarray(pts["s"])
    u, fu = np.abs(w), f * np.sign(w)
    speeds = sorted({round(r.belt_speed_s, 4) for r in res.recordings})
    norm = Normalize(min(speeds) * 0.9, max(speeds) * 1.05 if len(speeds) > 1 else min(speeds) * 1.1)
    cmap = plt.get_cmap("viridis")
    fig, axes = plt.subplots(1, 2, figsize=(14, 5.6), constrained_layout=True)
    ax = axes[0]
    for branch, marker, lab in ((1, "^", "accelerating relative motion (|w| grows)"),
                                (-1, "v", "decelerating relative motion (|w| shrinks)")):
        m = g == branch
        ax.scatter(u[m], fu[m], c=s[m], cmap=cmap, norm=norm, s=7, marker=marker, alpha=0.6, lw=0, label=lab)
    umax = max(float(u.max()) if u.size else 1.0, law[3] * 1.2)
    uu = np.linspace(0.0, umax * 1.05, 400)
    ee = np.array([res.equation_error[k].value for k in LAW])
    for lab, th, ls, col in (("fitted law (output error)", law, "-", "k"),
                             ("equation-error fit (paper's least squares)", ee, ":", "0.45")):
        ax.plot(uu, pwl_law(uu, np.ones_like(uu), np.zeros_like(uu), *th), ls, color=col, lw=1.6 if col == "k" else 1.2,
                label=f"{lab}: growing branch (1 + amp) f_k")
        ax.plot(uu, pwl_law(uu, -np.ones_like(uu), np.zeros_like(uu), *th), ls, color=col, lw=1.0,
                label=f"{lab}: shrinking branch (1 - amp) f_k")
    ax.axvline(law[3], color="0.6", lw=0.8, ls="--")
    ax.text(law[3], 0.02, f" w_min = {law[3]:.3f}", transform=ax.get_xaxis_transform(),
            fontsize=8, color="0.4")
    fs_med = np.median([e.f_s for e in res.episodes]) if res.episodes else None
    if fs_med is not None:
        kin_up = pwl_law(uu, np.ones_like(uu), np.zeros_like(uu), *law)
        drop = fs_med - law[0] * uu
        m = drop >= kin_up
        ax.plot(uu[m], drop[m], "-", color="C3", lw=1.2,
                label=f"break-away drop from the median f_s = {fs_med:.3f} (alpha_drop = {law[0]:.2f})")
    ax.set_xlim(0, umax * 1.05)
    ax.set_xlabel("relative velocity |w| = |s - x'| [-]  (unit F0 / sqrt(K M))")
    ax.set_ylabel("friction f [-]  (unit F0)")
    ax.set_title("f(w) points from the equation of motion (kept samples) and the identified law (cf. Fig. 9)",
                 fontsize=10)
    ax.legend(fontsize=7, loc="upper right")
    sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, ax=ax, label="belt speed s [-]")
    ax.grid(alpha=0.3)
    # Fig. 10: at each belt speed the points binned in w on each branch, against the one identified law
    ax = axes[1]
    rec_idx = np.asarray(pts["recording"])
    for k, rec in enumerate(res.recordings):
        col = cmap(norm(rec.belt_speed_s))
        for branch, marker, ls in ((1, "^", "-"), (-1, "v", "--")):
            m = (rec_idx == k) & (g == branch)
            if m.sum() < 5:
                continue
            edges = np.linspace(0.0, u[m].max() + 1e-9, 13)
            idx = np.digitize(u[m], edges) - 1
            cu = [u[m][idx == b].mean() for b in range(12) if (idx == b).sum() >= 3]
            cf = [fu[m][idx == b].mean() for b in range(12) if (idx == b).sum() >= 3]
            ax.plot(cu, cf, marker + ls, color=col, ms=5, lw=0.9,
                    label=f"s = {rec.belt_speed_s:.3f} ({Path(rec.path).name})" if branch == 1 else None)
    ax.plot(uu, pwl_law(uu, np.ones_like(uu), np.zeros_like(uu), *law), "-", color="k", lw=1.0, alpha=0.6,
            label="identified law, growing branch")
    ax.plot(uu, pwl_law(uu, -np.ones_like(uu), np.zeros_like(uu), *law), "--", color="k", lw=1.0, alpha=0.6,
            label="identified law, shrinking branch")
    ax.set_xlim(0, umax * 1.05)
    ax.set_xlabel("relative velocity |w| [-]")
    ax.set_ylabel("friction f [-]")
    ax.set_title("f(w, sgn w') at each belt speed (cf. Fig. 10): kept points averaged in w bins,\n"
                 "^ |w| growing, v |w| shrinking; one law for every s", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    a = res.law
    fig.suptitle("paper 000 friction law: " + ", ".join(f"{k} = {a[k].value:.4g} ± {a[k].std:.2g}" for k in LAW),
                 fontsize=10)
    save_png(fig, path, dpi=DPI)


def _static_panel(fig, ax, x, fs, f_corr, sd, c, cmap: str, norm, corr_label: str, cbar_label: str, law,
                  law_label: str, xlabel: str, ylabel: str, title: str) -> None:
    """One panel of Fig. 11: raw levels faint, corrected levels coloured by the other variable, the law."""
    ax.plot(x, fs, "o", ms=4, color="0.8", label="raw break-away levels", zorder=1)
    sc = ax.scatter(x, f_corr, c=c, cmap=cmap, norm=norm, s=22, zorder=3, label=corr_label)
    ax.errorbar(x, f_corr, yerr=sd, fmt="none", ecolor="0.4", lw=0.6, zorder=2)
    fig.colorbar(sc, ax=ax, label=cbar_label)
    if law is not None:
        xx = np.geomspace(x.min() * 0.7, x.max() * 1.4, 200)
        ax.plot(xx, law(xx), "k-", lw=1.2, label=law_label)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_xscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, which="both")


def belt_static_figure(res: BeltLawResult, path: str | Path) -> None:
    """Fig. 11: static friction (break-away level) against stick time and force rate, with the fitted law.

    With both effects the raw levels hardly move (longer sticks come with lower force
    rates at low belt speed), so each panel shows the levels corrected to the other
    variable's median through the fitted law (partial-residual plot), raw levels faint.
    """
    eps = [e for e in res.episodes if e.t_s_s is not None and e.t_s_s > 0 and np.isfinite(e.delta_N_per_s)]
    fig, axes = plt.subplots(1, 2, figsize=(14, 5.6), constrained_layout=True)
    if not eps:
        for ax in axes:
            ax.text(0.5, 0.5, "no complete stick episode", ha="center", transform=ax.transAxes)
        save_png(fig, path, dpi=DPI)
        return
    ts = np.array([e.t_s_s for e in eps])
    dl = np.maximum(np.abs([e.delta_N_per_s for e in eps]), 1e-3)
    fs = np.array([e.f_s for e in eps])
    sd = np.array([e.f_s_std for e in eps])
    q0 = res.force_rate_q0_N_per_s
    st = res.static
    d_ref, t_ref = float(np.median(dl)), float(np.median(ts))
    if st:
        th = [st[k].value for k in ("f_s0", "stick_time_gain", "stick_time_tau_s", "force_rate_gain")]
        at = static_law(ts, dl, *th, q0)
        f_t = fs - at + static_law(ts, np.full_like(ts, d_ref), *th, q0)  # corrected to Delta = d_ref
        f_d = fs - at + static_law(np.full_like(dl, t_ref), dl, *th, q0)  # corrected to t_s = t_ref
    else:
        f_t = f_d = fs
    dnorm = LogNorm(dl.min(), max(dl.max(), dl.min() * 1.01))
    tnorm = LogNorm(ts.min(), max(ts.max(), ts.min() * 1.01))
    _static_panel(fig, axes[0], ts, fs, f_t, sd, dl, "plasma", dnorm,
                  f"corrected to Delta = {d_ref:.3g} N/s by the fitted law", "force rate Delta at break-away [N/s]",
                  (lambda tt: static_law(tt, np.full_like(tt, d_ref), *th, q0)) if st else None,
                  f"fitted f_s(t_s, Delta = {d_ref:.3g} N/s)", "stick time t_s [s]",
                  "static friction (break-away level) f_s [-]  (unit F0)", "f_s against adhesion time (cf. Fig. 11)")
    _static_panel(fig, axes[1], dl, fs, f_d, sd, ts, "viridis", tnorm,
                  f"corrected to t_s = {t_ref:.3g} s by the fitted law", "stick time t_s [s]",
                  (lambda dd: static_law(np.full_like(dd, t_ref), dd, *th, q0)) if st else None,
                  f"fitted f_s(t_s = {t_ref:.3g} s, Delta)", "force rate Delta at break-away [N/s]",
                  "static friction f_s [-]", "f_s against force rate (cf. Fig. 11)")
    if st:
        fig.suptitle("f_s = f_s0 (1 + g_t (1 - exp(-t_s/tau)) + g_d ln(1 + Delta/q0)), q0 = "
                     f"{q0:g} N/s fixed; {len(eps)} break-aways, rms {res.static_rms:.2g}\n" + ", ".join(
                         f"{k} = {v.value:.4g} ± {v.std:.2g}" for k, v in st.items()), fontsize=10)
    save_png(fig, path, dpi=DPI)


def poincare_figure(a: PoincareAnalysis, path: str | Path) -> None:
    """Limit cycle in the phase plane with the section points (cf. Figs. 8, 19), return map, section sequence."""
    r = a.result
    k = r.mass - 1
    n = r.n_masses
    steady_t = a.t >= a.t[0] + r.skip_s
    fig, axes = plt.subplots(2, 2, figsize=(13, 9.5), constrained_layout=True)
    ax = axes[0, 0]
    ax.plot(a.x[k][~steady_t], a.v[k][~steady_t], color="0.75", lw=0.5, label="transient")
    ax.plot(a.x[k][steady_t], a.v[k][steady_t], color="C0", lw=0.6, label="steady part")
    P = a.points
    st = a.steady
    ax.axhline(r.level, color="0.4", ls="--", lw=0.8, label=f"section x'{r.mass} = {r.level:.3f}, downward")
    ax.plot(P[st, k], P[st, n + k], "o", ms=5, mfc="none", mec="C3", label="section points (steady)")
    ax.axhline(r.belt_speed_s, color="C2", lw=0.8, ls=":", label=f"belt speed s = {r.belt_speed_s:.3f} (stick)")
    ax.set_xlabel(f"x{r.mass} = K X{r.mass} / F0 [-]")
    ax.set_ylabel(f"x'{r.mass} [-]  (t in units of sqrt(M/K))")
    ax.set_title(f"phase plane of mass {r.mass}", fontsize=10)
    ax.legend(fontsize=8, loc="lower left")
    ax.grid(alpha=0.3)
    ax = axes[0, 1]
    xs = P[st, k]
    # the tolerance in this coordinate's units: scatter inside it is noise, so never zoom below it
    tol_x = r.tolerance * float(np.ptp(a.x[k][steady_t])) if steady_t.any() else 0.0
    if xs.size >= 2:
        ax.plot(xs[:-1], xs[1:], "o", ms=4, color="C3")
        lo, hi = float(xs.min()), float(xs.max())
        pad = max(0.05 * (hi - lo), 3.0 * tol_x, 1e-3)
        ax.plot([lo - pad, hi + pad], [lo - pad, hi + pad], color="0.6", lw=0.8, label="x_{n+1} = x_n")
        ax.set_xlim(lo - pad, hi + pad)
        ax.set_ylim(lo - pad, hi + pad)
        ax.legend(fontsize=8)
    ax.set_xlabel(f"x{r.mass} at crossing n [-]")
    ax.set_ylabel(f"x{r.mass} at crossing n+1 [-]")
    ax.set_title("first-return map of the section", fontsize=10)
    ax.grid(alpha=0.3)
    ax = axes[1, 0]
    for i in range(n):
        ax.plot(a.cross_t, P[:, i], "o-", ms=3, lw=0.6, label=f"x{i + 1} at the section")
    ax.axvline(a.t[0] + r.skip_s, color="0.5", ls="--", lw=0.8, label="end of transient (skip)")
    if xs.size:
        m0 = float(np.mean(xs))
        ax.axhspan(m0 - tol_x, m0 + tol_x, color="C3", alpha=0.12,
                   label=f"x{r.mass}: +- tolerance around its steady mean")
        y0, y1 = ax.get_ylim()
        ax.set_ylim(min(y0, m0 - 4 * tol_x), max(y1, m0 + 4 * tol_x))
    ax.set_xlabel("t [s]")
    ax.set_ylabel("position at the section [-]")
    ax.set_title("section sequence", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax = axes[1, 1]
    t_end = a.t[-1]
    span = min(t_end - a.t[0], max(6 * (r.period_s or 0.5), 2.0))
    m = a.t >= t_end - span
    for i in range(n):
        ax.plot(a.t[m], a.v[i][m], lw=0.8, label=f"x'{i + 1}")
    ct = a.cross_t[a.cross_t >= t_end - span]
    ax.plot(ct, np.full(ct.size, r.level), "v", color="C3", ms=6, label="section crossings")
    ax.axhline(r.belt_speed_s, color="C2", lw=0.8, ls=":", label="belt speed s")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("velocity [-]")
    ax.set_title(f"last {span:.1f} s", fontsize=10)
    ax.legend(fontsize=8, loc="lower left")
    ax.grid(alpha=0.3)
    per = f", period {r.period_s:.3f} s" if r.period_s else ""
    fig.suptitle(f"{Path(r.path).name}: {n} mass(es), s = {r.belt_speed_s:.3f}: {r.classification}{per} "
                 f"({r.points_steady} steady section points, {r.distinct_points} distinct at tolerance "
                 f"{r.tolerance:.3g})", fontsize=11)
    save_png(fig, path, dpi=DPI)
