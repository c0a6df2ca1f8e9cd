"""Instruments of the reference rigs: sampling clock, hold, noise, quantisation, spikes.

Channel figures (noise_std, lsb, update rate_Hz) are read from the rig config's
``[channels.*]`` tables. What an instrument does, in this order:

1. the ADC samples at nominal instants k/rate; with ``jitter_s`` > 0 the true
   instants are k/rate + N(0, jitter_s) (clipped to +-0.45 of a period, so they stay
   ordered) while the time stamps written are the nominal ones (clock jitter);
2. an instrument slower than the sampling rate (belt tachometer 200 Hz, thermocouple
   10 Hz, drum speed 100 Hz) holds its last update; its noise is drawn per update;
3. Gaussian noise of the channel's noise_std, then quantisation to its lsb;
4. with ``spike_prob`` > 0, single-sample spikes (impulsive noise: a connector, an EMI
   burst) of +-``spike_sigma`` x noise_std on the channels in ``spike_channels``; with ``burst_prob`` > 0
   also bursts of 2 or 3 samples, each of +-(0.5..1) ``spike_sigma`` x noise_std, signs at random.

Counters (``drum_rev``) and commands (``vb_set``) carry no noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class SensorOptions:
    rate: float = 1000.0
    noise: bool = True
    jitter_s: float = 0.0
    spike_prob: float = 0.0
    spike_sigma: float = 30.0
    burst_prob: float = 0.0  # per sample: a burst of 2-3 bad samples starts here
    spike_channels: tuple[str, ...] = ("x1", "phi", "force_a", "accel", "vel")
    noiseless: tuple[str, ...] = field(default=("vb_set", "drum_rev"))


def sample_instants(duration: float, opt: SensorOptions, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(nominal time stamps, true sampling instants) for a record of ``duration`` seconds."""
    n = int(np.floor(duration * opt.rate + 1e-9)) + 1
    t_nom = np.arange(n) / opt.rate
    if opt.jitter_s <= 0.0:
        return t_nom, t_nom.copy()
    half = 0.45 / opt.rate
    dt = np.clip(rng.normal(0.0, opt.jitter_s, n), -half, half)
    dt[0] = abs(dt[0])  # the record starts at t = 0
    return t_nom, t_nom + dt


def measure(name: str, ch: dict, t_nom: np.ndarray, truth: np.ndarray, opt: SensorOptions,
            rng: np.random.Generator) -> np.ndarray:
    """One channel as its instrument reports it at the nominal stamps t_nom."""
    x = np.asarray(truth, dtype=float).copy()
    rate_ch = ch.get("rate_Hz")
    if rate_ch is not None and rate_ch < opt.rate:
        upd = np.floor(t_nom * rate_ch + 1e-9)  # index of the instrument update each sample shows
        first = np.searchsorted(upd, upd, side="left")  # the sample at which that update was taken
        x = x[first]
        upd_index = (upd - upd[0]).astype(int)
    else:
        upd_index = np.arange(x.size)
    if name in opt.noiseless:
        return x
    sd = float(ch.get("noise_std", 0.0))
    if opt.noise and sd > 0:
        draws = rng.normal(0.0, sd, size=int(upd_index[-1]) + 1)
        x = x + draws[upd_index]
    x = x + float(ch.get("offset", 0.0))
    if opt.spike_prob > 0 and name in opt.spike_channels and sd > 0:
        hit = rng.random(x.size) < opt.spike_prob
        x[hit] += rng.choice([-1.0, 1.0], size=int(hit.sum())) * opt.spike_sigma * sd
    if opt.burst_prob > 0 and name in opt.spike_channels and sd > 0:
        for i in np.flatnonzero(rng.random(x.size - 3) < opt.burst_prob):
            k = int(rng.integers(2, 4))
            x[i:i + k] += rng.choice([-1.0, 1.0], size=k) * rng.uniform(0.5, 1.0, k) * opt.spike_sigma * sd
    lsb = float(ch.get("lsb", 0.0))
    if lsb > 0:
        x = np.round(x / lsb) * lsb
    return x


def measure_all(cfg: dict, t_nom: np.ndarray, true_ch: dict[str, np.ndarray], opt: SensorOptions,
                rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Every channel of the interchange format the rig has, in the config's order."""
    out = {}
    for name, ch in cfg.get("channels", {}).items():
        if name in true_ch:
            out[name] = measure(name, ch, t_nom, true_ch[name], opt, rng)
    return out
