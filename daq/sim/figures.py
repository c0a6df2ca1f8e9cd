"""Figures a person would rather look at than read (PNG, no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from daq.io.interchange import Recording  # noqa: E402
from daq.io.png import save_png  # noqa: E402
from daq.signals import paper_spectrogram  # noqa: E402

# the main displacement channel and its label, per rig
MAIN_CHANNEL = {"brake-2dof": ("x1", "x1 [m]"), "belt-ndof": ("x1", "x1 [m]"),
                "drum-pendulum": ("phi", "phi [rad]")}


# the main channel's true velocity in a simulated recording's truth group
VEL_TRUTH = {"brake-2dof": "x1_dot", "belt-ndof": "x1_dot", "drum-pendulum": "phi_dot"}


def _velocity(rec: Recording, name: str) -> np.ndarray:
    """Velocity of the main channel: the simulator's truth if present, else a central difference."""
    key = VEL_TRUTH.get(rec.rig or "")
    if key in rec.truth:
        return rec.truth[key]
    return np.gradient(rec.channels[name], rec.t)


def sim_figure(rec: Recording, path: str | Path, title: str = "") -> None:
    """Time history, phase plane in two windows, and the paper-001 spectrogram of the main channel."""
    name, label = MAIN_CHANNEL.get(rec.rig or "", ("x1", "x1"))
    t = rec.t
    x = rec.channels[name]
    v = _velocity(rec, name)
    fig = plt.figure(figsize=(13, 9), constrained_layout=True)
    gs = fig.add_gridspec(3, 3)
    ax = fig.add_subplot(gs[0, :])
    ax.plot(t, x, lw=0.4, color="C0", label=name)
    ax.set_xlabel("t [s]")
    ax.set_ylabel(label)
    drive = "vb" if "vb" in rec.channels else ("vel" if "vel" in rec.channels else None)
    ax2 = fig.add_subplot(gs[1, :], sharex=ax)
    ax2.plot(t, v, lw=0.4, color="C0", label=f"d{name}/dt")
    if drive == "vb":
        ax2.plot(t, rec.channels["vb"], lw=0.8, color="C3", label="vb (belt)")
    ax2.set_ylabel(f"d{name}/dt")
    ax2.set_xlabel("t [s]")
    ax2.legend(loc="lower right", fontsize=8)
    # phase plane in early / middle / late windows
    T = t[-1]
    for k, (a, b) in enumerate([(0.2 * T, 0.3 * T), (0.55 * T, 0.65 * T), (0.85 * T, 0.95 * T)]):
        if k < 2:
            axp = fig.add_subplot(gs[2, k])
            m = (t >= a) & (t <= b)
            axp.plot(x[m], v[m], lw=0.5)
            axp.set_title(f"phase plane {a:.1f} < t < {b:.1f} s", fontsize=9)
            axp.set_xlabel(label)
            axp.set_ylabel(f"d{name}/dt")
    axs = fig.add_subplot(gs[2, 2])
    f, ts, pxx = paper_spectrogram(t, x)
    axs.pcolormesh(ts, f, 10 * np.log10(pxx + 1e-30), shading="auto", cmap="viridis")
    axs.set_ylim(0, 25)
    axs.set_title(f"spectrogram of {name} (512/256, 100 Hz) [dB]", fontsize=9)
    axs.set_xlabel("t [s]")
    axs.set_ylabel("f [Hz]")
    fig.suptitle(title or f"{rec.rig} simulation")
    save_png(fig, path, dpi=90)
