"""Run a simulated rig: physics + hidden effects + instruments -> a recording in the interchange format."""

from __future__ import annotations

import datetime as _dt
import math
from typing import Callable

import numpy as np

from daq import __version__
from daq.config import RigConfig, config_text
from daq.errors import InputError
from daq.io.interchange import Recording
from daq.ramps import check_limits, constant_ramp, ramp_table, seed_ramp

from .effectset import EffectRequest, effect_vector
from .rigs import Chunk, make_sim
from .sensors import measure

CHUNK_S = 5.0  # simulated seconds per progress step


def default_ramp(cfg: RigConfig, duration: float) -> tuple[np.ndarray, np.ndarray, str]:
    d = cfg.drive
    if d.ramp == "seed":
        tmax = d.Tmax_s or duration
        ramp = seed_ramp(d.V0_m_per_s, tmax, min(duration, tmax))
    else:
        ramp = constant_ramp(d.V0_m_per_s, duration)
    rt, rv = ramp_table(ramp)
    return rt, rv, ramp.name


def simulate(cfg: RigConfig, *, effects: list[EffectRequest] = (), ramp: tuple[np.ndarray, np.ndarray] | None = None,
             ramp_source: str = "ramp", duration: float | None = None, rate: float | None = None,
             seed: int = 0, dt: float | None = None, noise: bool = True, e: np.ndarray | None = None,
             progress: Callable[[float, float], None] | None = None, keep_states: bool = False) -> Recording:
    """Simulate ``duration`` seconds of a rig; ``e`` overrides the effect vector entirely if given; with
    ``keep_states`` the simulator's whole state at each sample is in ``truth["state"]`` (n_samples, n_state)."""
    duration = float(duration if duration is not None else cfg.drive.default_duration_s)
    if not duration > 0:
        raise InputError("--duration", "duration", "must be > 0")
    rate = float(rate or cfg.sensors.rate_Hz)
    dt = float(dt or cfg.integrator.dt_s)
    active: dict[str, dict[str, float]]
    if e is None:
        e, active = effect_vector(cfg, list(effects))
    else:
        active = {"(explicit vector)": {}}
    if ramp is None:
        rt, rv, ramp_name = default_ramp(cfg, duration)
    else:
        rt, rv = ramp
        ramp_name = ramp_source
    check_limits(rt, rv, cfg.drive.max_speed_m_per_s, cfg.drive.max_accel_m_per_s2, ramp_source)

    # internal step: an integer number of steps per output sample, no longer than the config's dt
    n_sub = max(1, int(math.ceil((1.0 / rate) / dt - 1e-9)))
    h = 1.0 / rate / n_sub
    n_total = int(math.floor(duration * rate + 1e-9)) + 1
    sim = make_sim(cfg, e)
    rt = np.ascontiguousarray(rt, dtype=float)
    rv = np.ascontiguousarray(rv, dtype=float)
    chunk = _integrate(sim, rt, rv, rate, h, n_sub, n_total, duration, progress)
    t = np.arange(n_total) / rate
    true_ch = sim.channels(t, chunk)
    channels, units = _measure_channels(cfg, t, true_ch, seed, noise)
    truth = sim.truth(chunk)
    truth.update({f"true_{k}": v for k, v in true_ch.items()})
    if keep_states:
        truth["state"] = chunk.states
    meta = {
        "rig": cfg.rig,
        "software": f"friction-daq {__version__}",
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "source": "simulation",
        "effects": {k: v for k, v in active.items()},
        "seed": seed,
        "rate_Hz": rate,
        "dt_s": h,
        "duration_s": duration,
        "ramp": ramp_name,
        "ramp_table": np.column_stack([rt, rv]).tolist(),
        "rig_config": config_text(cfg),
        "modes_hz": sim.modes_hz(),
    }
    if hasattr(sim, "n_events"):
        meta["stick_slip_events"] = int(getattr(sim, "n_events"))
    return Recording(cfg.rig, t, channels, units, meta, truth)


def _integrate(sim, rt: np.ndarray, rv: np.ndarray, rate: float, h: float, n_sub: int, n_total: int,
               duration: float, progress: Callable[[float, float], None] | None) -> Chunk:
    """Advance the rig from rest on the belt's start speed through ``n_total`` output samples, as one chunk.

    With ``progress`` the run goes in chunks of CHUNK_S simulated seconds (only to report progress).
    """
    s = sim.initial_state(float(rv[0]))
    chunks: list[Chunk] = []
    per_chunk = max(2, int(CHUNK_S * rate)) if progress else n_total  # chunks only to report progress
    done = 0
    t0 = 0.0
    while done < n_total:
        n_out = min(per_chunk, n_total - done + (1 if done else 0))
        c = sim.advance(s, t0, h, n_sub, n_out, rt, rv)
        if done:  # the first sample of a continuation chunk repeats the last one
            c = Chunk(c.states[1:], c.aux[1:], {k: v[1:] for k, v in c.extra.items()})
        chunks.append(c)
        done += len(c.states)
        s = c.states[-1].copy()
        t0 = (done - 1) / rate
        if progress:
            progress(min(t0, duration), duration)
    if len(chunks) == 1:
        return chunks[0]
    return Chunk(np.concatenate([c.states for c in chunks]), np.concatenate([c.aux for c in chunks]),
                 {k: np.concatenate([c.extra[k] for c in chunks]) for k in chunks[0].extra})


def _measure_channels(cfg: RigConfig, t: np.ndarray, true_ch: dict[str, np.ndarray], seed: int,
                      noise: bool) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The configured channels as the instruments read the simulated truth (noise from ``seed``), and units."""
    rng = np.random.default_rng(seed)
    channels: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    for name, ccfg in cfg.channels.items():
        if name not in true_ch:
            continue  # e.g. x3 on a one-mass belt rig
        channels[name] = measure(ccfg, t, true_ch[name], rng, noise=noise)
        units[name] = ccfg.unit
    return channels, units
