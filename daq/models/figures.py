"""Figures of compare, diagnose and history (PNG): what a researcher looks at before reading numbers."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from daq.io.png import save_png  # noqa: E402
from daq.physics.contact import AUX  # noqa: E402
from daq.signals import RING_PERIODS, paper_spectrogram, sg  # noqa: E402

from .diagnosis.compare import OUTLIER_SIGMAS, Drawn  # noqa: E402
from .diagnosis.scoring import MIN_STEP, MIN_T  # noqa: E402
from .fit import robust  # noqa: E402
from .fit.session import Fitted, Session  # noqa: E402


def _pick_windows(session: Session, n: int = 3) -> np.ndarray:
    w = session.win.starts.size
    return np.unique(np.linspace(0, w - 1, n).round().astype(int))


def compare_figure(session: Session, fitted: Fitted, result: dict, path: Path, title: str = "") -> None:
    """compare.png: three windows (early, middle, late), the phase plane, friction against relative velocity, the
    error by regime and over time, the spectral line of the free run, and the numbers (``result``: compare's JSON)."""
    pr = fitted.problem
    wins = _pick_windows(session)
    vel_all = fitted.start_values()
    shot = pr.shoot(fitted.values, wins, vel_all[wins])
    sh_all = pr.shoot(fitted.values, session.win.select(None), vel_all)
    fig = plt.figure(figsize=(15, 10), constrained_layout=True)
    gs = fig.add_gridspec(3, 3)
    _window_panels(fig, gs[0, :2], session, fitted, shot, wins)
    _phase_plane(fig.add_subplot(gs[0, 2]), session, shot, len(wins))
    _friction_panel(fig.add_subplot(gs[1, 0]), sh_all)
    _regime_panel(fig.add_subplot(gs[1, 1]), session, result)
    _time_panel(fig.add_subplot(gs[1, 2]), session, sh_all, result)
    _spectral_panel(fig.add_subplot(gs[2, :2]), result)
    _numbers_panel(fig.add_subplot(gs[2, 2]), session, result)
    fig.suptitle(title or f"{result['model']} vs {Path(result['data']).name}")
    save_png(fig, path, dpi=90)


def _window_panels(fig, cell, session: Session, fitted: Fitted, shot, wins: np.ndarray) -> None:
    """Time histories: one panel per window (early, middle, late), outliers and repaired spikes marked."""
    m, primary = session.m, session.primary
    sub = cell.subgridspec(1, len(wins), wspace=0.08)
    for j, w in enumerate(wins):
        ax = fig.add_subplot(sub[0, j])
        t = m.t[shot.index[j]]
        ax.plot(t, shot.meas[primary][j], "k.", ms=2, label="measured")
        ax.plot(t, shot.pred[primary][j], "C1-", lw=1.2, label="model from the data's state")
        # the samples the loss counts linearly: beyond 3x the window's own scale (where the model misses the whole
        # window, that scale is the misfit's and hardly a sample is: marking every sample > 5 noise levels off hid
        # the data of a seed model behind crosses)
        z = (shot.pred[primary][j] - shot.meas[primary][j]) / m.sigma[primary]
        far = robust.counted_linearly(z[None, None, :], fitted.problem.loss)[0, 0]
        fixed = np.isin(shot.index[j], m.outliers.get(primary, np.zeros(0, int)) // m.averaged)  # (file's samples)
        if far.any():
            ax.plot(t[far], shot.meas[primary][j][far], "x", color="C3", ms=6, label="outlier (counted linearly)")
        if fixed.any():
            ax.plot(t[fixed], shot.meas[primary][j][fixed], "o", mfc="none", color="C2", ms=6, label="spike repaired")
        ax.set_xlabel("t [s]")
        if j == 0:
            ax.set_ylabel(f"{primary} [{m.units[primary]}]")
            ax.legend(loc="best", fontsize=7)
        ax.set_title(("early", "middle", "late")[j] if len(wins) == 3 else f"window {w}", fontsize=9)


def _phase_plane(ax, session: Session, shot, n_wins: int) -> None:
    m, primary = session.m, session.primary
    unit = m.units[primary]
    xs = m.outputs[primary]
    vd = sg(xs, m.rate, 0.006 if m.rate >= 500 else 1.5 / m.rate, 1)
    for j in range(n_wins):
        ii = shot.index[j]
        ax.plot(xs[ii], vd[ii], "k-", lw=0.6, alpha=0.7, label="measured" if j == 0 else None)
        pv = np.gradient(shot.pred[primary][j], 1.0 / m.rate)
        ax.plot(shot.pred[primary][j], pv, "C1-", lw=0.9, label="model" if j == 0 else None)
    ax.set_xlabel(f"{primary} [{unit}]")
    ax.set_ylabel(f"d{primary}/dt [{unit}/s]")
    ax.set_title("phase plane")
    ax.legend(fontsize=8)


def _friction_panel(ax, sh_all) -> None:
    """Friction against relative velocity along every window, both branches."""
    v = sh_all.aux[..., AUX.V_REL].ravel()
    F = sh_all.aux[..., AUX.F].ravel()
    dv = np.gradient(np.abs(sh_all.aux[..., AUX.V_REL]), axis=1).ravel()
    ax.plot(v[dv > 0], F[dv > 0], ".", ms=1, color="C3", label="model, |v_rel| growing")
    ax.plot(v[dv <= 0], F[dv <= 0], ".", ms=1, color="C0", label="model, |v_rel| shrinking")
    ax.set_xlabel("v_rel [m/s]")
    ax.set_ylabel("friction force [N]")
    ax.set_title("friction vs relative velocity (model, along the windows)")
    ax.legend(fontsize=7, markerscale=6)


def _regime_panel(ax, session: Session, result: dict) -> None:
    names = list(result["by_regime"])
    vals = [result["by_regime"][k]["error"] for k in names]
    ax.barh(names, vals, color=["C3" if k == result["worst_regime"] else "C0" for k in names])
    ax.axvline(result["noise_floor"], color="k", ls="--", label="noise floor")
    ax.set_xlabel(f"rms error [{session.m.units[session.primary]}]")
    ax.ticklabel_format(axis="x", style="sci", scilimits=(-2, 3))  # (plain metres overlapped: 0.0000250000)
    ax.set_title("error by regime")
    ax.legend(fontsize=8)
    ax.tick_params(axis="y", labelsize=8)


def _time_panel(ax, session: Session, sh_all, result: dict) -> None:
    """Each window's rms error over time: fit, held-out and flagged windows."""
    m, primary = session.m, session.primary
    ms = np.sqrt(np.mean((sh_all.pred[primary][:, 1:] - sh_all.meas[primary][:, 1:]) ** 2, axis=1))
    tw = m.t[session.win.starts]
    fitw, heldw = session.win.select(False), session.win.select(True)
    flagged = np.setdiff1d(np.arange(tw.size), session.win.scored())
    ax.plot(tw[fitw], ms[fitw], "o", ms=3, label="fit windows")
    ax.plot(tw[heldw], ms[heldw], "s", ms=3, label="held-out windows (the error)")
    if flagged.size:
        ax.plot(tw[flagged], ms[flagged], "x", color="0.5", ms=5, label="flagged transient (not scored)")
    ax.set_yscale("log")
    ax.axhline(result["noise_floor"], color="k", ls="--", label="noise floor")
    ax.set_xlabel("t [s]")
    ax.set_ylabel(f"rms error [{m.units[primary]}]")
    ax.set_title("error over time")
    ax.legend(fontsize=8)


def _spectral_panel(ax, result: dict) -> None:
    """The free run's strongest spectral line over time against the record's."""
    sl = result.get("spectral_line")
    if sl:
        ax.plot(sl["t"], sl["measured_Hz"], "k.-", label="measured")
        ax.plot(sl["t"], sl["model_Hz"], "C1.-", label="model (free run)")
        ax.set_ylabel("strongest line [Hz]")
        ax.set_xlabel("t [s]")
        ax.legend(fontsize=8)
    ax.set_title("spectrogram line (window 512, overlap 256, 100 Hz, as paper 001)")


def _numbers_panel(ax, session: Session, result: dict) -> None:
    unit = session.m.units[session.primary]
    ax.axis("off")
    lines = [f"error {result['error']:.3g} {unit} (noise floor {result['noise_floor']:.3g})",
             f"(on held-out windows; all windows {result['error_all_windows']:.3g})",
             f"loss {result['loss']}; samples counted linearly {sum(result['loss_capped'].values())}",
             (f"spikes repaired {sum(result['outliers'].values())}; "
              f"> {OUTLIER_SIGMAS:g} noise levels off {sum(result['residual_outliers'].values())}"), ""]
    for k, d in result["invariants"].items():
        lines.append(f"{k}: measured {d['measured']:.4g}, model {d['model']:.4g}")
    lines.append("")
    for k, d in result["by_signal"].items():
        lines.append(f"{k}: {d['error']:.3g} {d['unit']} (floor {d['noise_floor']:.3g})")
    ax.text(0, 1, "\n".join(lines), va="top", family="monospace", fontsize=8)


def spectrogram_figure(session: Session, drawn: Drawn, path: Path) -> None:
    m = session.m
    primary = session.primary
    tt = m.t[drawn.fidx]
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5), constrained_layout=True, sharey=True)
    for ax, x, label in ((axes[0], m.outputs[primary][drawn.fidx], "measured"), (axes[1], drawn.pred[primary], "model")):
        f, t, pxx = paper_spectrogram(tt, x - x.mean())
        ax.pcolormesh(t, f, 10 * np.log10(pxx + 1e-30), shading="auto")
        ax.set_title(f"{primary}: {label}")
        ax.set_xlabel("t [s]")
    axes[0].set_ylabel("f [Hz]")
    save_png(fig, path, dpi=90)


def cycles_figure(session: Session, result: dict, drawn: Drawn, path: Path) -> None:
    """The cycles' distributions, record against the model's free run (compare's "cycles")."""
    rec, mod = drawn.cycles
    unit = result["cycles"]["unit"]
    drive = result["cycles"]["loading"]["drive_speed"]
    if drive > 0.0:  # the loading rates over the drive's speed: 1 where a stuck slider is loaded, less where it creeps
        rec, mod = ({**c, "early": c["load_rate_early"] / drive, "late": c["load_rate_late"] / drive} for c in (rec, mod))
    panels = (("stick_s", "stick time [s]"), ("creep_s", "of it at the peak load [s]"), ("drop", f"load drop [{unit}]"),
              ("slip_s", "slip duration [s]"), ("period_s", "period [s]"))
    if drive > 0.0:
        panels += (("early", "loading, stick's 1st third / drive"), ("late", "loading, stick's last third / drive"))
    fig, axes = plt.subplots(1, len(panels), figsize=(3.6 * len(panels), 3.8), constrained_layout=True)
    for ax, (key, label) in zip(axes, panels):
        both = np.concatenate([rec[key], mod[key]])
        both = both[np.isfinite(both)]
        if both.size:
            bins = np.linspace(np.min(both), np.max(both) + 1e-300, 30)
            for x, c, who in ((rec[key], "C0", "record"), (mod[key], "C1", "model free run")):
                x = x[np.isfinite(x)]
                ax.hist(x, bins=bins, alpha=0.6, color=c, label=f"{who} ({x.size})")
                if x.size:
                    ax.axvline(np.median(x), color=c, ls="--", lw=1)
        ax.set_xlabel(label)
    axes[0].set_ylabel("cycles")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"stick-slip cycles of {result['cycles']['signal']} (dashed: medians)")
    save_png(fig, path, dpi=90)


def ringing_figure(session: Session, result: dict, drawn: Drawn, path: Path) -> bool:
    """A record ringing off the rig's natural frequency, read window by window (compare's motion.by_amplitude):
    each window's frequency against its amplitude, the rig file's natural frequency, the medians of the smallest and
    largest quarters (``drawn.ringing``: compare's windows, not read again). Drawn only where compare read it
    (returns whether it drew)."""
    mo, amp = result["motion"], result["motion"].get("by_amplitude")
    if drawn.ringing is None or not amp["windows"]:
        return False
    a, f = drawn.ringing
    primary = session.primary
    unit = result["cycles"]["unit"]
    fig, ax = plt.subplots(figsize=(6.4, 4.2), constrained_layout=True)
    ax.plot(a, f, ".", ms=4, alpha=0.6, label=f"record, {a.size} windows of {RING_PERIODS:g} periods")
    ax.axhline(mo["natural_Hz"], color="k", ls=":", label=f"rig file's mechanics {mo['natural_Hz']:.3g} Hz")
    for key, edge, c in (("smallest", amp["amplitude_q25"], "C2"), ("largest", amp["amplitude_q75"], "C3")):
        line = amp["line_Hz_small" if key == "smallest" else "line_Hz_large"]
        ax.axvline(edge, color=c, lw=0.8, alpha=0.7)
        ax.axhline(line, color=c, ls="--", label=f"median, {key} quarter of amplitudes: {line:.3g} Hz")
    ax.set_xlabel(f"amplitude [{unit}]")
    ax.set_ylabel("frequency [Hz]")
    ax.set_ylim(0.8 * min(mo["natural_Hz"], float(np.min(f))), 1.05 * float(np.max(f)))
    ax.legend(fontsize=8, loc="lower left")
    ax.set_title(f"ringing of {primary} by amplitude (Spearman {amp['rho']:+.2f}, p {amp['p']:.2g})", fontsize=10)
    save_png(fig, path, dpi=90)
    return True


def diagnose_figure(session: Session, diag, path: Path) -> None:
    m = session.m
    primary = session.primary
    unit = m.units[primary]
    fig = plt.figure(figsize=(19, 5), constrained_layout=True)
    gs = fig.add_gridspec(1, 4)
    ax = fig.add_subplot(gs[0, 0])
    added = {c.label for step in diag.sequence for c in step.cands} if diag.found else set()
    # a candidate whose gain the model without it reaches too (at the candidate fit's values) is not the effect's
    # a candidate whose fit failed numerically: an empty hatched bar at 0, said in its name (decision 50)
    shown = diag.candidates[::-1]
    names = [c.label + (" (fit failed)" if c.failed else " (fit, not effect)" if c.fit_only else "") for c in shown]
    red = [0.0 if c.failed else c.reduction for c in shown]
    bars = ax.barh(names, red, color=["C2" if c.label in added else ("0.75" if c.fit_only else "C0") for c in shown])
    for bar, c in zip(bars, shown):
        if c.failed:
            bar.set(width=0.05, hatch="///", facecolor="none", edgecolor="C3")
    if diag.sequence and diag.final is not None:
        total = diag.reduction(diag.promised, primary)
        ax.axvline(total, color="C2", ls="--", label=f"added together, as model add + compare fit it: {total:.0%}")
    ax.axvline(MIN_STEP, color="k", ls=":", label="a step needs (of the excess left)")
    ax.set_xlabel("share of excess error removed on held-out windows (alone)")
    lo = max(min(-0.2, min(red) if red else 0.0), -1.0)  # a candidate far worse than the model: off scale, said
    ax.set_xlim(lo, 1.1)
    for i, r in enumerate(red):
        if r < lo:
            ax.annotate(f"{r:.1f} (off scale)", (lo, i), xytext=(4, 0), textcoords="offset points", va="center",
                        fontsize=8)
    ax.set_title("which effect is missing? (step 1's fitted candidates; green: added; grey: the model\n"
                 "without it does as well at that fit's values)", fontsize=10)
    ax.legend(fontsize=8)
    _margins_panel(fig.add_subplot(gs[0, 1]), diag)
    # evidence: the held-out window where the base model is worst, base vs best candidate
    ax = fig.add_subplot(gs[0, 2:])
    base = diag.base
    hw = base.held.windows
    if hw.size and diag.candidates:
        wsel = np.argmax(base.ms_held[primary])
        w = hw[wsel:wsel + 1]
        sb = base.problem.shoot(base.values, w, base.held.start_values[wsel:wsel + 1])
        t = m.t[sb.index[0]]
        ax.plot(t, sb.meas[primary][0], "k.", ms=3, label="measured (held out)")
        ax.plot(t, sb.pred[primary][0], "C0-", label=f"model: {base.model.describe()}")
        bf = diag.final if diag.final is not None else diag.candidates[0].fitted
        if bf is not None:
            vel = bf.problem.fit_starts(bf.values, w, max_iter=25).start_values
            sc = bf.problem.shoot(bf.values, w, vel)
            label = (" + ".join(s.label for s in diag.sequence) if diag.final is not None
                     else diag.candidates[0].label + " (best candidate, not taken)")
            ax.plot(t, sc.pred[primary][0], "C2-", label=f"+ {label}")
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"{primary} [{unit}]")
        ax.legend(fontsize=8)
    ax.set_title("evidence: the held-out window the model fits worst")
    fig.suptitle(diag.summary[:160] + ("..." if len(diag.summary) > 160 else ""), fontsize=9)
    save_png(fig, path, dpi=90)


def _margins_panel(ax, diag) -> None:
    """Each added effect against each rival (the model without it, and substitutes refitted in its place): how
    many points of the excess it explains more, with the bootstrap's 5-95 % range; green: named, orange: a tie."""
    rows = [(v, m) for v in diag.verdicts for m in v.margins]
    if not rows:
        ax.text(0.5, 0.5, "nothing added: no margins", ha="center", va="center", transform=ax.transAxes)
        ax.set_axis_off()
        return
    y = np.arange(len(rows))[::-1]
    for yi, (v, m) in zip(y, rows):
        color = "C2" if m.decided else "C1"
        ax.errorbar(m.share, yi, xerr=[[m.share - m.lower], [max(m.upper - m.share, 0.0)]], fmt="o", color=color,
                    capsize=3)
    ax.set_yticks(y, [f"{v.cand.label}\nover {m.rival}" for v, m in rows], fontsize=7)
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel("margin: share of the base excess explained beyond the rival")
    ax.set_title("how firmly? (bootstrap over held-out windows, 5-95 %;\ngreen: named, orange: undecided)",
                 fontsize=10)


def history_figure(entries: list[dict], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(10, 4.5), constrained_layout=True)
    by_data: dict[str, list[dict]] = {}
    for e in entries:
        by_data.setdefault(e["data"], []).append(e)
    labels: list[str] = []
    for data, es in by_data.items():
        x = np.arange(len(es))
        ax.plot(x, [e["error"] for e in es], "o-", label=f"{Path(data).name}: error")
        ax.plot(x, [e["noise_floor"] for e in es], "k--", lw=0.8)
        for i, e in enumerate(es):
            ax.annotate(f"{e['error']:.3g}", (i, e["error"]), fontsize=8, textcoords="offset points", xytext=(5, 4))
        if len(es) > len(labels):  # what each revision added to the one before
            effects = [set(e["model"].split(" + ", 1)[-1].split(", ")) for e in es]
            labels = ["first"] + ["+ " + ", ".join(sorted(b - a)) if b - a else "refit"
                                  for a, b in zip(effects[:-1], effects[1:])]
    ax.set_xticks(range(len(labels)), [lab[:40] for lab in labels], fontsize=8)
    ax.set_xlabel("model revision")
    unit = entries[0]["error_unit"] if entries else ""
    ax.set_ylabel(f"error on held-out windows [{unit}]")
    ax.set_yscale("log")
    ax.set_title("model error across revisions (dashed: noise floor)")
    ax.legend(fontsize=8)
    save_png(fig, path, dpi=90)


def proposal_figure(session: Session, prop, path: Path) -> None:
    """The proposed programme (top), each rival's noise-free prediction of the primary output under it (middle), and
    how far each rival is from "nothing more" in units of the record's noise (bottom); beside it every programme
    scored (separation against z, the proposal circled)."""
    from .design.proposal import predicted  # the design imports this module's siblings; imported here, at call time

    best = prop.best
    primary = session.primary
    sigma = session.m.sigma[primary]
    fig = plt.figure(figsize=(13, 7.5), constrained_layout=True)
    grid = fig.add_gridspec(3, 2, width_ratios=(2.2, 1))
    ax_v, ax_y, ax_d = (fig.add_subplot(grid[i, 0]) for i in range(3))
    rt, rv = best.programme.table()
    ax_v.plot(rt, rv * 1e3, "k-")
    ax_v.set_ylabel("drive [mm/s]")
    ax_v.set_title(f"proposed: {best.programme.name} (z {best.z:.2f}, separation {best.separation:.1f})", fontsize=10)
    recs = {r.label: predicted(session, r, best.programme, noise=False) for r in prop.rivals}
    ref = recs[prop.rivals[0].label]
    for r in prop.rivals:
        rec = recs[r.label]
        y = np.asarray(rec.channels[primary], dtype=float)
        held = f" (held at {r.fitted.values[r.fixed]:.3g})" if r.fixed else ""  # generic, or a step below it
        ax_y.plot(rec.t, y, lw=0.8, label=r.label + held)
        if r is not prop.rivals[0]:
            ax_d.plot(rec.t, (y - np.asarray(ref.channels[primary], dtype=float)) / sigma, lw=0.8, label=r.label)
    ax_y.set_ylabel(f"{primary} [{session.m.units[primary]}]")
    ax_y.legend(fontsize=8)
    ax_d.axhspan(-1, 1, color="0.9")
    ax_d.set_ylabel("difference [noise sd]")
    ax_d.set_title(f"each rival's free run minus that of '{prop.rivals[0].label}'", fontsize=9)
    ax_d.set_xlabel("t [s]")
    ax_d.legend(fontsize=8)
    ax_s = fig.add_subplot(grid[:, 1])
    z = np.array([s.z for s in prop.scored])
    sep = np.array([s.separation for s in prop.scored])
    ax_s.scatter(sep, z, s=14, c=["C2" if s.decides else "C7" for s in prop.scored])
    ax_s.scatter([best.separation], [best.z], s=120, facecolors="none", edgecolors="C3", label="proposed")
    ax_s.axhline(MIN_T, color="k", ls=":", lw=0.8)
    ax_s.set_xscale("symlog")
    ax_s.set_xlabel("separation of the rivals [noise units]")
    ax_s.set_ylabel("consistency z (worst pair)")
    ax_s.set_title(f"{len(prop.scored)} of {prop.family_size} programmes scored (green: decides)", fontsize=10)
    ax_s.legend(fontsize=8)
    save_png(fig, path, dpi=90)
