"""The drum campaign's results: one table row per cell (CSV and JSON) and the grid figure of A-E and R^2.

Layout of OUT (the campaign's folder): campaign.json (state), rigs/ (config per thrust row),
ramps/ (programme per cell), recordings/ (one run file per cell), cells/<cell>/ (drum-mu.json and
figures), partial/, logs/ (daemon output), table.csv, table.json, coefficients.png.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter, NullLocator

from daq.analysis.paper002.law import UNITS
from daq.config import load_rig
from daq.io.files import atomic_path
from daq.io.jsonout import write_json
from daq.io.png import save_png

from .state import CampaignCfg, CampaignState

COLUMNS = ("thrust_N", "v0_m_per_s", "status", "A", "A_se", "B", "B_se", "C", "C_se", "D", "D_se", "E", "E_se",
           "R2", "n", "thrust_measured_N", "recording")


def table_rows(st: CampaignState) -> list[dict[str, Any]]:
    rows = []
    for c in st.cells:
        r: dict[str, Any] = {"thrust_N": c.thrust_N, "v0_m_per_s": c.v0_m_per_s, "status": c.status}
        res = c.result
        for k in ("A", "B", "C", "D", "E"):
            r[k] = res.coefficients[k].value if res else None
            r[f"{k}_se"] = res.coefficients[k].se if res else None
        r["R2"] = res.R2 if res else None
        r["n"] = res.n if res else None
        r["thrust_measured_N"] = res.thrust_measured_N if res else None
        r["recording"] = c.recording
        rows.append(r)
    return rows


def write_table(out: Path, st: CampaignState) -> tuple[Path, Path]:

    rows = table_rows(st)
    csv_path, json_path = out / "table.csv", out / "table.json"
    with atomic_path(csv_path) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=COLUMNS)
            w.writeheader()
            for r in rows:
                w.writerow({k: ("" if v is None else v) for k, v in r.items()})
    write_json(json_path, {"law": "mu(v) = A [1 - exp(-B v)] exp(-C v) + D v + E", "cells": rows})
    return csv_path, json_path


def _config_law(c: CampaignCfg) -> dict[str, float]:
    """The simulated rig's own law (3): its config's A, B, C, E and the seed effect's D (reference lines)."""

    cfg = load_rig(c.rig)
    f = cfg.friction
    d = float((cfg.seed_effects.get("velocity-strengthening") or {}).get("D", 0.0))
    return {"A": f.A, "B": f.B_s_per_m, "C": f.C_s_per_m, "D": d, "E": f.E}


def grid_figures(out: Path, st: CampaignState) -> list[Path]:
    """A-E against drum speed, one line per thrust, error bars = 1 standard error; R^2 likewise."""

    matplotlib.use("Agg")

    c = st.cfg
    done = [x for x in st.cells if x.status == "done" and x.result is not None]
    colors = plt.cm.viridis(np.linspace(0, 0.85, max(len(c.thrusts_N), 1)))
    nominal = _config_law(c) if c.sim else {}
    fig, axs = plt.subplots(2, 3, figsize=(15, 8.5), constrained_layout=True)
    names = ("A", "B", "C", "D", "E", "R2")
    n_rows = len(c.thrusts_N)
    for ax, name in zip(axs.flat, names):
        for i, (color, p) in enumerate(zip(colors, c.thrusts_N)):
            cells = sorted((x for x in done if x.thrust_N == p), key=lambda x: x.v0_m_per_s)
            if not cells:
                continue
            dodge = 10 ** (0.012 * (i - (n_rows - 1) / 2))  # side by side, so the error bars stay readable
            v = np.array([x.v0_m_per_s * 1e3 for x in cells]) * dodge
            if name == "R2":
                y = np.array([x.result.R2 for x in cells])
                ax.plot(v, y, "o-", color=color, label=f"P = {p:g} N")
                continue
            y = np.array([x.result.coefficients[name].value for x in cells])
            e = np.array([x.result.coefficients[name].se or np.nan for x in cells])
            ok = np.array([x.result.coefficients[name].identified for x in cells])
            ax.errorbar(v, y, yerr=e, color=color, lw=1, capsize=3, marker=None, label=f"P = {p:g} N")
            ax.plot(v[ok], y[ok], "o", color=color)
            ax.plot(v[~ok], y[~ok], "o", mfc="white", color=color)
        if name in nominal:
            ax.axhline(nominal[name], color="0.4", ls="--", lw=1, label="simulated rig's law (config)")
        if name != "R2" and done:  # a cell with a huge error bar, or not identified, must not flatten the others
            scaled = [x for x in done if x.result.coefficients[name].identified] or done
            ys = np.array([x.result.coefficients[name].value for x in scaled]
                          + ([nominal[name]] if name in nominal else []))
            ses = np.array([x.result.coefficients[name].se or 0.0 for x in scaled])
            pad = 2.5 * float(np.median(ses)) + 0.05 * float(np.ptp(ys)) + 1e-12
            lo_y, hi_y = ys.min() - pad, ys.max() + pad
            ax.set_ylim(lo_y, hi_y)
            off = sum(1 for x in done if not lo_y <= x.result.coefficients[name].value <= hi_y)
            if off:
                ax.text(0.98, 0.97, f"{off} cell(s) off scale (not identified)", transform=ax.transAxes,
                        fontsize=8, color="0.3", ha="right", va="top")
        ax.set_xscale("log")
        speeds = sorted(c.speeds_m_per_s)
        ax.set_xlim(speeds[0] * 1e3 / 1.25, speeds[-1] * 1e3 * 1.25)

        ax.xaxis.set_major_locator(FixedLocator([v * 1e3 for v in speeds]))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
        ax.xaxis.set_minor_locator(NullLocator())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("drum speed v0 [mm/s] (log scale)")
        unit = "" if name == "R2" or UNITS[name] == "-" else f" [{UNITS[name]}]"
        ax.set_ylabel(("R²" if name == "R2" else name) + unit)
        ax.set_title("goodness of fit R²" if name == "R2" else f"law (3) coefficient {name}", fontsize=10)
        ax.grid(alpha=0.3)
    axs.flat[0].legend(fontsize=8)
    n_done = len(done)
    fig.suptitle(f"paper 002 campaign: law (3) μ(v) = A[1−exp(−Bv)]exp(−Cv) + Dv + E per (P, v0); "
                 f"{n_done}/{len(st.cells)} cells; bars = ±1 standard error, open markers: se > 25 %", fontsize=11)
    return [save_png(fig, out / "coefficients.png", dpi=110)]
