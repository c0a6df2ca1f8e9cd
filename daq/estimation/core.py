"""The estimator's algorithm, free of any bus: aligned samples in, friction estimates out.

Why incremental: the same object serves the online adapter (blocks as they arrive)
and the offline API (whole arrays at once); feeding a run in any block sizes gives
the same numbers, which the tests check. Per block the work is O(block): one FIR
pass for all filters, one compiled loop through the rig's equations, vectorised
regime logic, and a ring-buffer append for the running fit.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from pydantic import ConfigDict, Field

from daq.config import RigConfig
from daq.strict import Closed

from .differentiate import fir_bank, noise_gain, sg_coefficients
from .fit import FitWindow, RunningLawFit, fit_law
from .regime import classify
from .rigmodels import RigModel, rig_model


class EstimatorCfg(Closed):
    """Tuning of the estimator; None means the rig's default."""

    model_config = ConfigDict(frozen=True)
    window_s: float | None = Field(None, gt=0.0, description="differentiator window (local polynomial fit)")
    lag: int | None = Field(None, ge=0, description="evaluation lag in samples; None = centre of the window")
    degree: int | None = Field(None, ge=1, le=6, description="local polynomial degree for the body's kinematics")
    hysteresis: float = Field(0.3, ge=0.0, lt=1.0, description="regime band: v_stick (1 -/+ h)")
    fit_window_s: float = Field(10.0, gt=0.0)
    fit_every_s: float = Field(1.0, gt=0.0)
    fit_max_points: int = Field(3000, ge=10)
    fit_min_points: int = Field(100, ge=5)
    fit_free: tuple[str, ...] | None = Field(None, description="law parameters the fit frees; None = the rig's")
    fit_settle_s: float | None = Field(None, ge=0.0, description="exclusion around regime switches; None = 1 window")


@dataclass
class EstimateBlock:
    """Estimates for a run of samples; ``index`` and ``t`` name the sample each estimate refers to."""

    index: np.ndarray  # sample number (since the estimator started) the estimate refers to
    t: np.ndarray  # its time [s]
    F: np.ndarray
    N: np.ndarray
    mu: np.ndarray
    v_rel: np.ndarray
    a: np.ndarray
    slip: np.ndarray  # 1 = slip, 0 = stick/creep
    growing: np.ndarray  # 1 while |v_rel| grows (accel-sign branch), else 0
    newest: np.ndarray  # sample number of the newest input sample each estimate used
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def size(self) -> int:
        """Number of estimates."""
        return int(self.index.size)

    @staticmethod
    def concat(blocks: list["EstimateBlock"]) -> "EstimateBlock":
        """Join consecutive blocks (e.g. the pieces around a gap)."""
        names = [k for k in EstimateBlock.__dataclass_fields__ if k != "extra"]
        out = {k: np.concatenate([getattr(b, k) for b in blocks]) for k in names}
        keys = blocks[0].extra.keys() if blocks else ()
        return EstimateBlock(**out, extra={k: np.concatenate([b.extra[k] for b in blocks]) for k in keys})


class FrictionEstimator:
    """Causal friction estimator for one rig at one sample rate (inputs already aligned)."""

    def __init__(self, model: RigModel, rate_hz: float, cfg: EstimatorCfg = EstimatorCfg()) -> None:
        self.model = model
        self.cfg = cfg
        self.rate = float(rate_hz)
        self.dt = 1.0 / self.rate
        window = cfg.window_s or model.default_window_s
        deg = cfg.degree or model.default_degree
        self.n_taps = max(deg + 3, int(round(window * self.rate))) | 1  # odd, so the centre is a sample
        self.lag = (self.n_taps - 1) // 2 if cfg.lag is None else min(cfg.lag, self.n_taps - 1)
        self.delay_s = self.lag * self.dt
        self.inputs = model.inputs
        specs = model.filters
        self.keys = [s.key for s in specs]
        self.taps = np.stack([sg_coefficients(self.n_taps, s.degree or deg, s.deriv, self.lag, self.dt)
                              for s in specs])
        self.src = np.array([self.inputs.index(s.channel) for s in specs], dtype=np.int64)
        self.gains = {s.key: noise_gain(h) for s, h in zip(specs, self.taps)}
        settle = cfg.fit_settle_s if cfg.fit_settle_s is not None else self.n_taps * self.dt
        self.fit_window = FitWindow(cfg.fit_window_s, self.rate, model.v_stick * (1.0 + cfg.hysteresis),
                                    int(round(settle * self.rate)))
        if cfg.fit_free is not None:
            unknown = set(cfg.fit_free) - set(model.law.nominal)
            if unknown:
                raise ValueError(f"fit_free: {sorted(unknown)} not parameters of the {model.rig_id} law")
        self.law = model.law if cfg.fit_free is None else dataclasses.replace(model.law, free=tuple(cfg.fit_free))
        self._next_fit_t: float | None = None
        self.n_seen = 0  # input samples ever fed (numbers the estimates' ``index``)
        self.resets = -1
        self.reset()

    def reset(self) -> None:
        """Forget the history (after a gap): the next n_taps - 1 samples only refill the window."""
        self._hist = np.empty((len(self.inputs), 0))
        self._hist_t = np.empty(0)
        self._slip = -1
        self.resets += 1

    def process(self, t: np.ndarray, x: np.ndarray) -> EstimateBlock:
        """Feed n aligned samples (x: inputs x n, rows in ``self.inputs`` order); get the estimates they complete.

        A time gap longer than 1.5 sample periods (lost blocks) restarts the window there.
        """
        t = np.asarray(t, dtype=float)
        x = np.asarray(x, dtype=float).reshape(len(self.inputs), -1)
        prev = self._hist_t[-1:] if self._hist_t.size else t[:0]
        gaps = np.flatnonzero(np.diff(np.concatenate([prev, t])) > 1.5 * self.dt) - prev.size + 1
        if gaps.size == 0:
            return self._process(t, x)
        parts, start = [], 0
        for g in gaps:  # rare: one Python step per gap, not per sample
            if g > start:
                parts.append(self._process(t[start:g], x[:, start:g]))
            self.reset()
            start = g
        parts.append(self._process(t[start:], x[:, start:]))
        return EstimateBlock.concat(parts)

    def _process(self, t: np.ndarray, x: np.ndarray) -> EstimateBlock:
        """One gap-free run of samples: FIR over history + block, inverse dynamics, regime, fit window."""
        h = self._hist_t.size
        xx = np.concatenate([self._hist, x], axis=1)
        tt = np.concatenate([self._hist_t, t])
        first = self.n_seen - h  # sample number of xx[:, 0]
        self.n_seen += t.size
        keep = self.n_taps - 1
        self._hist = xx[:, -keep:].copy()
        self._hist_t = tt[-keep:].copy()
        m = tt.size - keep
        if m <= 0:
            return self._empty()
        out = np.empty((len(self.keys), m))
        fir_bank(np.ascontiguousarray(xx), self.taps, self.src, out)
        est = self.model.infer(dict(zip(self.keys, out)))
        slip = classify(est.v_rel, self.model.v_stick, self.cfg.hysteresis, self._slip)
        self._slip = int(slip[-1])
        growing = (np.sign(est.v_rel) * (est.a - est.a_drive) > 0).astype(np.int8)
        newest = first + keep + np.arange(m)
        blk = EstimateBlock(newest - self.lag, tt[self.lag:self.lag + m], est.F, est.N, est.mu, est.v_rel, est.a,
                            slip, growing, newest, est.extra)
        self.fit_window.append(blk.index, blk.t, blk.v_rel, blk.mu, growing.astype(float), slip.astype(float))
        return blk

    def _empty(self) -> EstimateBlock:
        """No estimate yet (the window is still filling)."""
        z = np.empty(0)
        return EstimateBlock(z.astype(np.int64), z, z, z, z, z, z, z.astype(np.int8), z.astype(np.int8),
                             z.astype(np.int64), {k: z for k in self.model.extra_names})

    def fit_due(self, t_now: float) -> bool:
        """True once per ``fit_every_s`` of data time (the caller then runs or schedules a fit)."""
        if self._next_fit_t is None:
            self._next_fit_t = t_now + self.cfg.fit_every_s
            return False
        if t_now >= self._next_fit_t:
            self._next_fit_t = t_now + self.cfg.fit_every_s
            return True
        return False

    def fit_now(self) -> RunningLawFit | None:
        """Fit the law on the current window, synchronously (offline use)."""
        data = self.fit_window.select(self.cfg.fit_max_points)
        return None if data is None else fit_law(self.law, data, self.cfg.fit_min_points)


@dataclass
class ArrayEstimate:
    """Result of :func:`estimate_arrays`: the estimates plus the filter's description."""

    est: EstimateBlock
    delay_s: float
    n_taps: int
    lag: int
    fits: list[RunningLawFit]


def estimate_arrays(cfg: RigConfig, t: np.ndarray, channels: dict[str, np.ndarray], *,
                    e: np.ndarray | None = None, est_cfg: EstimatorCfg = EstimatorCfg(),
                    rate_hz: float | None = None, block: int | None = None, fit: bool = False) -> ArrayEstimate:
    """Run the online algorithm over whole arrays (offline use and tests); ``block`` feeds it in pieces.

    ``est.index`` gives, for each estimate, the input sample it refers to (delay = lag samples).
    With ``fit``, the law is refitted every ``fit_every_s`` of data, as online.
    """
    t = np.asarray(t, dtype=float)
    rate = rate_hz or 1.0 / float(np.median(np.diff(t)))
    fe = FrictionEstimator(rig_model(cfg, e), rate, est_cfg)
    x = np.stack([np.asarray(channels[c], dtype=float) for c in fe.inputs])
    step = block or t.size
    parts, fits = [], []
    for i in range(0, t.size, step):
        b = fe.process(t[i:i + step], x[:, i:i + step])
        parts.append(b)
        if fit and b.size and fe.fit_due(float(b.t[-1])) and (r := fe.fit_now()) is not None:
            fits.append(r)
    if fit and (r := fe.fit_now()) is not None:
        fits.append(r)  # the window that ends with the data
    return ArrayEstimate(EstimateBlock.concat(parts), fe.delay_s, fe.n_taps, fe.lag, fits)
