"""Paper 002 (Furmanik, drum-pendulum): ``daq analyse drum-mu`` — mu(t) by eq. (2) and law (3) fitted to it.

Why in two steps: the paper identifies its friction model in two steps, and so do we.

1. mu(t) by eq. (2), from the measured phi, phi', phi'' and the thrust N (``kinematics.mu_series``:
   the measured gauges, nothing differentiated, and the selection of the samples that slide fast
   enough and far enough from a stick-slip transition to be fitted).
2. Law (3) fitted by nonlinear least squares in v = |v_wz| (``law.fit_law``: variable projection,
   standard errors inflated by the residuals' autocorrelation).

This module reads the recording (``daq.io.loading.load_data``; the rig config it carries, else
``--rig``), checks the options, runs both steps and returns the ``DrumMuResult`` the command prints.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from pydantic import Field

from daq.config import RigConfig, config_for_recording
from daq.errors import InputError
from daq.io.interchange import Recording
from daq.io.loading import load_data
from daq.strict import Closed

from .kinematics import GUARD_S, V_MIN, MuSeries, differentiation_check, mu_series
from .law import LAW, DrumLawFit, fit_law

RIG = "drum-pendulum"


def rig_config_of(rec: Recording, source: str, rig: str | None) -> RigConfig:
    """The rig config a recording carries (its own geometry and thrust), else ``rig`` (id or TOML)."""
    return config_for_recording(rec.meta.get("rig_config"), source, rig, RIG, "drum-mu needs")


class DrumMuResult(Closed):
    """What ``daq analyse drum-mu`` prints with --json (and writes to REPORT/drum-mu.json)."""

    analysis: str = "drum-mu"
    data: str
    rig: str
    law: str = LAW
    sgn_eps_m_per_s: float = Field(description="sgn(v) regularisation of the law as the rig applies it")
    kinematics: dict[str, str]
    thrust_N: dict[str, float] = Field(description="the thrust gauge over the used samples: mean, std, min, max")
    drum_speed_m_per_s: dict[str, float] = Field(description="surface speed: median, min, max over the record")
    selection: dict[str, float | int]
    fit: DrumLawFit
    differentiation_check: dict[str, object]
    seconds: float
    figures: list[str] = Field(default_factory=list)


def analyse_drum_mu(path: str | Path, *, rig: str | None = None, v_min: float = V_MIN, guard_s: float = GUARD_S,
                    mu1: float = 0.0, t_from: float | None = None,
                    t_to: float | None = None) -> tuple[DrumMuResult, MuSeries]:
    """Read a drum-pendulum recording, mu(t) by eq. (2), law (3) fitted; (result, the series for figures)."""
    t0 = time.perf_counter()
    src = str(path)
    if not Path(path).is_file():
        raise InputError(src, "(file)", "no such file")
    if not v_min > 0:
        raise InputError("--v-min", "--v-min", "must be > 0")
    if not guard_s >= 0:
        raise InputError("--guard", "--guard", "must be >= 0")
    if not mu1 >= 0:
        raise InputError("--mu1", "--mu1", "must be >= 0")
    rec = load_data(path, rig or (RIG if Path(path).suffix.lower() in (".csv", ".tdms") else None))
    cfg = rig_config_of(rec, src, rig)
    if t_from is not None or t_to is not None:
        m = (rec.t >= (t_from if t_from is not None else -np.inf)) & (rec.t <= (t_to if t_to is not None else np.inf))
        if m.sum() < 50:
            raise InputError(src, "--from/--to", "fewer than 50 samples in the interval")
        rec = Recording(rec.rig, rec.t[m], {k: v[m] for k, v in rec.channels.items()}, rec.units, rec.meta)
    s = mu_series(rec, cfg, src, v_min=v_min, guard_s=guard_s, mu1=mu1)
    u = s.used
    if u.sum() < 200:
        raise InputError(src, "vel", f"only {int(u.sum())} samples slide faster than {v_min:g} m/s away from "
                         "stick: nothing to fit law (3) to (did the drum turn?)")
    eps = float(cfg.friction.sgn_eps_m_per_s)
    fit = fit_law(np.abs(s.v[u]), s.mu[u], eps)
    res = DrumMuResult(
        data=src, rig=cfg.rig, sgn_eps_m_per_s=eps, kinematics=s.kinematics,
        thrust_N={"mean": float(np.mean(s.N[u])), "std": float(np.std(s.N[u])), "min": float(np.min(s.N[u])),
                  "max": float(np.max(s.N[u]))},
        drum_speed_m_per_s=_drum_stats(rec, cfg),
        selection={k: v for k, v in s.info.items() if isinstance(v, (int, float))},
        fit=fit, differentiation_check=differentiation_check(s), seconds=time.perf_counter() - t0)
    return res, s


def _drum_stats(rec: Recording, cfg: RigConfig) -> dict[str, float]:
    v = np.asarray(rec.channels["drum_speed"], dtype=float) * cfg.mechanics.R_m
    return {"median": float(np.median(v)), "min": float(np.min(v)), "max": float(np.max(v))}
