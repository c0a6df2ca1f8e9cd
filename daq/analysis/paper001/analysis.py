"""The whole of paper 001's analysis of one brake-2dof deceleration run, and its result.

Why one entry point: the spectrograms (Figs. 4, 5, 10), the phase and configuration planes (Figs. 6, 7,
11), the effective friction of eq. (10) with a fit of law (7), and the regimes of section 5 all start
from the same kinematics, estimated once from x1, phi and vb. :func:`analyse_run` is pure (arrays in,
the pydantic :class:`BrakeRunResult` and the figure data in :class:`RunContext` out); the command line
writes the JSON and calls the figures.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from pydantic import Field

from daq.config import RigConfig
from daq.errors import InputError
from daq.physics import brake2dof
from daq.physics.effects import E
from daq.signals import paper_spectrogram
from daq.sim.effectset import effect_vector
from daq.strict import Closed

from .friction import FrictionResult, FrictionSeries, brake_params, friction_series, identify_friction
from .kinematics import differentiator_name, prepare, sample_rate
from .reference import PaperMark, compare_paper_160, paper_planes
from .spectra import SPEC_FS, SPEC_NOVERLAP, SPEC_NPERSEG, SpectrogramResult, dominant_line
from .transitions import TransitionCfg, TransitionResult, TransitionTrace, detect_transitions


class PlaneWindow(Closed):
    """A time window of the phase/configuration-plane figure."""

    start_s: float
    end_s: float
    vb_mean_m_per_s: float
    x1_range_mm: tuple[float, float]
    y1_range_mm: tuple[float, float]


class BrakeRunResult(Closed):
    """``daq analyse brake-run`` output (one JSON object)."""

    data: str
    rig: str = "brake-2dof"
    rig_config: str
    rate_hz: float
    duration_s: float
    n_samples: int
    resampled: bool = Field(description="the time base was not uniform and was interpolated onto one")
    belt_V0_m_per_s: float = Field(description="measured vb fitted by eq. (11): V0 (1 - t/Tmax)")
    belt_Tmax_s: float
    spectrogram: SpectrogramResult
    planes: list[PlaneWindow]
    friction: FrictionResult
    transitions: TransitionResult
    paper_160: list[PaperMark] | None = None
    figures: list[str] = Field(default_factory=list)


@dataclass
class RunContext:
    """Arrays the figures need beyond the JSON."""

    fs: FrictionSeries
    trace: TransitionTrace
    spec_x: tuple[np.ndarray, np.ndarray, np.ndarray]
    spec_v: tuple[np.ndarray, np.ndarray, np.ndarray]
    alpha: float
    beta: float
    mu0_cfg: float
    gamma_cfg: float
    paper_marks: bool


def default_planes(t0: float, t1: float, width: float, n: int = 6) -> list[tuple[float, float]]:
    """n windows of ``width`` spread evenly over the run (the first one after the start-up second)."""
    width = min(width, (t1 - t0) / n)
    a = min(t0 + 1.0, t1 - width)
    starts = np.linspace(a, t1 - width, n)
    return [(round(float(s), 2), round(float(s + width), 2)) for s in starts]


def fit_seed_ramp(t: np.ndarray, vb: np.ndarray) -> tuple[float, float]:
    """V0 and Tmax of eq. (11) from the measured belt speed (least-squares line)."""
    slope, v0 = np.polyfit(t, vb, 1)
    return float(v0), float(-v0 / slope) if slope < 0 else float("inf")


def analyse_run(t: np.ndarray, channels: dict[str, np.ndarray], cfg: RigConfig, source: str, *,
                config_source: str = "brake-2dof", plane_window_s: float = 2.0,
                planes: list[tuple[float, float]] | None = None, diff_window_s: float = 0.02,
                tcfg: TransitionCfg = TransitionCfg(), paper_marks: bool = False,
                say: Callable[[str], None] = lambda s: None) -> tuple[BrakeRunResult, RunContext]:
    """All of paper 001's analyses on one recording (pure: arrays in, result and figure data out)."""
    if cfg.rig != "brake-2dof":
        raise InputError(config_source, "rig", f"must be brake-2dof, got {cfg.rig!r}")
    if not diff_window_s > 0:
        raise InputError("--diff-window", "diff_window", "must be > 0")
    t, ch, resampled = prepare(t, channels, source)
    rate = sample_rate(t)
    p = brake_params(cfg)
    fr = cfg.friction
    say(f"kinematics and inverse dynamics ({differentiator_name(t, diff_window_s)})")
    fs = friction_series(cfg, t, ch["x1"], ch["phi"], ch["vb"], diff_window_s)
    say("fitting law (7) on slip samples away from the measured transition bias")
    fric = identify_friction(fs, p, diff_window_s, fr.alpha_s_per_m, fr.beta, cfg.contact.v_stick_m_per_s, source)
    say("spectrograms (512/256 at 100 Hz) and transition detection")
    spec_x = paper_spectrogram(t, fs.x1, SPEC_FS, SPEC_NPERSEG, SPEC_NOVERLAP)
    spec_v = paper_spectrogram(t, fs.x1d, SPEC_FS, SPEC_NPERSEG, SPEC_NOVERLAP)
    modes = brake2dof.linear_modes(p, _geo_weight(cfg))
    spec = SpectrogramResult(times_s=spec_x[1].tolist(), line_hz=dominant_line(spec_x[0], spec_x[2]).tolist(),
                             line_hz_velocity=dominant_line(spec_v[0], spec_v[2]).tolist(),
                             modes_hz=[float(m) for m in modes])
    trans, trace = detect_transitions(t, fs.x1, fs.x1d, tcfg, "x1")
    t0, t1 = float(t[0]), float(t[-1])
    if planes is None:
        planes = (paper_planes(t0, t1) if paper_marks else []) or default_planes(t0, t1, plane_window_s)
    pw = []
    for a, b in planes:
        if not (t0 <= a < b <= t1 + 1e-9):
            raise InputError("--planes", f"{a:g}:{b:g}", f"must lie inside the run ({t0:g}..{t1:g} s)")
        m = (t >= a) & (t <= b)
        pw.append(PlaneWindow(start_s=a, end_s=b, vb_mean_m_per_s=float(np.mean(fs.vb[m])),
                              x1_range_mm=(float(fs.x1[m].min() * 1e3), float(fs.x1[m].max() * 1e3)),
                              y1_range_mm=(float(fs.y1[m].min() * 1e3), float(fs.y1[m].max() * 1e3))))
    v0, tmax = fit_seed_ramp(t, fs.vb)
    res = BrakeRunResult(data=source, rig_config=config_source, rate_hz=rate, duration_s=t1 - t0, n_samples=int(t.size),
                         resampled=resampled, belt_V0_m_per_s=v0, belt_Tmax_s=tmax, spectrogram=spec, planes=pw,
                         friction=fric, transitions=trans,
                         paper_160=compare_paper_160(trans) if paper_marks else None)
    ctx = RunContext(fs, trace, spec_x, spec_v, fr.alpha_s_per_m, fr.beta, fr.mu0, fr.gamma_s_per_m, paper_marks)
    return res, ctx


def _geo_weight(cfg: RigConfig) -> float:
    """Weight of the geometric effect in the rig's seed model (1 = the paper's nonlinear model)."""

    return float(effect_vector(cfg)[0][E.GEO_WEIGHT])
