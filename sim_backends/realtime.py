"""A simulated rig running in (scaled) real time: the shared physics, driven by a motor command.

The same equations as ``daq sim`` (daq.physics via daq.sim.rigs), advanced tick by
tick. The drive follows the regulator's target speed under its acceleration
limit; instruments subscribe to each tick's samples (true channel values) and
turn them into frames on their own transport. Hidden physical effects are
catalog effects passed at construction.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from daq.background import BackgroundLoop
from daq.config import RigConfig
from daq.sim.effectset import EffectRequest, effect_vector
from daq.sim.rigs import Chunk, make_sim


@dataclass
class Tick:
    """One tick of simulated samples, handed to every instrument."""

    t: np.ndarray  # simulated time of each sample [s]
    host_time: np.ndarray  # the host monotonic time each sample corresponds to [s]
    channels: dict[str, np.ndarray]  # true values of the interchange channels
    truth: dict[str, np.ndarray]


Listener = Callable[[Tick], None]


class RealtimeRig:
    def __init__(self, cfg: RigConfig, effects: list[EffectRequest] = (), time_scale: float = 1.0,
                 tick_s: float = 0.01, rate_hz: float | None = None) -> None:
        self.cfg = cfg
        e, self.active_effects = effect_vector(cfg, list(effects))
        self.sim = make_sim(cfg, e)
        self.rate = float(rate_hz or cfg.sensors.rate_Hz)
        self.n_sub = max(1, int(np.ceil((1.0 / self.rate) / cfg.integrator.dt_s - 1e-9)))
        self.h = 1.0 / self.rate / self.n_sub
        self.time_scale = time_scale
        self.tick_s = tick_s
        self.state = self.sim.initial_state(0.0)  # belt at rest until the regulator drives it
        # compile (or load) the integrator now, on a throwaway copy, not in the first real-time tick
        make_sim(cfg, self.sim.e).advance(self.state, 0.0, self.h, self.n_sub, 2, np.array([0.0, 1.0]),
                                          np.zeros(2))
        self.t = 0.0
        self.v_cmd = 0.0  # the drive's commanded surface speed (after the regulator's ramp limiter)
        self.target = 0.0
        self.accel = cfg.drive.max_accel_m_per_s2
        self.last_tick: Tick | None = None
        self._listeners: list[Listener] = []
        self._lock = threading.Lock()
        self._loop = BackgroundLoop(self._tick, "realtime-rig")
        self.wall0 = time.monotonic()

    # --- the motor's side
    def set_drive(self, target: float, accel: float | None = None) -> None:
        """Ramp the drive toward target [m/s] at accel [m/s^2] (default: the rig's limit)."""
        with self._lock:
            self.target = max(0.0, float(target))
            self.accel = float(accel if accel is not None else self.cfg.drive.max_accel_m_per_s2)

    @property
    def belt_speed(self) -> float:
        """The actual drive speed at the last sample (what a tachometer would read)."""
        tick = self.last_tick
        return float(tick.truth["v_drive"][-1]) if tick is not None else 0.0

    @property
    def running(self) -> bool:
        """True while the rig advances in real time on its own thread (not stepped by a caller)."""
        return self._loop.running

    def subscribe(self, fn: Listener) -> None:
        self._listeners.append(fn)

    def unsubscribe(self, fn: Listener) -> None:
        if fn in self._listeners:
            self._listeners.remove(fn)

    # --- stepping
    def _ramp(self, t0: float, dur: float) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            target, accel, v = self.target, self.accel, self.v_cmd
        t_reach = abs(target - v) / accel if accel > 0 else np.inf
        if t_reach <= 0.0:
            return np.array([t0, t0 + dur + 1.0]), np.array([v, v])
        if t_reach >= dur:
            v_end = v + np.sign(target - v) * accel * dur
            return np.array([t0, t0 + dur, t0 + dur + 1.0]), np.array([v, v_end, v_end])
        return np.array([t0, t0 + t_reach, t0 + dur + 1.0]), np.array([v, target, target])

    def step(self, duration: float) -> Tick:
        """Advance the physics by ``duration`` simulated seconds and hand the samples to listeners."""
        n = max(1, int(round(duration * self.rate)))
        dur = n / self.rate
        rt, rv = self._ramp(self.t, dur)
        chunk = self.sim.advance(self.state, self.t, self.h, self.n_sub, n + 1, rt, rv)
        self.state = chunk.states[-1].copy()
        chunk = Chunk(chunk.states[1:], chunk.aux[1:], {k: v[1:] for k, v in chunk.extra.items()})
        t = self.t + np.arange(1, n + 1) / self.rate
        self.t = float(t[-1])
        with self._lock:
            self.v_cmd = float(np.interp(self.t, rt, rv))
        tick = Tick(t=t, host_time=self.wall0 + t / self.time_scale, channels=self.sim.channels(t, chunk),
                    truth=self.sim.truth(chunk))
        self.last_tick = tick
        for fn in list(self._listeners):
            fn(tick)
        return tick

    def start(self) -> None:
        """Run in a background thread, paced to the wall clock (times time_scale)."""
        if self._loop.running:
            return
        self.wall0 = time.monotonic() - self.t / self.time_scale
        self._loop.start()

    def stop(self) -> None:
        self._loop.stop(timeout=2.0)

    def _tick(self) -> None:
        """Wait until the next tick is due on the wall clock, then step."""
        due = self.wall0 + (self.t + self.tick_s * self.time_scale) / self.time_scale
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        self.step(self.tick_s * self.time_scale)
