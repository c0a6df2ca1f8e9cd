"""Sensor models: what an instrument does to the true signal (update rate, offset, noise, quantisation)."""

from __future__ import annotations

import numpy as np

from daq.config import ChannelCfg


def measure(cfg: ChannelCfg, t: np.ndarray, truth: np.ndarray, rng: np.random.Generator,
            noise: bool = True) -> np.ndarray:
    """Degrade a true signal sampled at times t the way the channel's instrument would.

    An instrument slower than the output rate holds its last reading (zero-order hold);
    noise is drawn once per instrument update, so held samples repeat it too.
    """
    x = np.asarray(truth, dtype=float)
    if cfg.rate_Hz is not None:
        t_upd = np.floor((t - t[0]) * cfg.rate_Hz + 1e-9) / cfg.rate_Hz + t[0]
        x = np.interp(t_upd, t, x)
        upd_index = np.concatenate([[0], np.cumsum(np.diff(t_upd) > 0)])
    else:
        upd_index = np.arange(x.size)
    x = x + cfg.offset
    if noise and cfg.noise_std > 0:
        draws = rng.normal(0.0, cfg.noise_std, size=int(upd_index[-1]) + 1)
        x = x + draws[upd_index]
    if cfg.lsb > 0:
        x = np.round(x / cfg.lsb) * cfg.lsb
    return x
