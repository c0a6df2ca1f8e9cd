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
        self.target = 0.0  # the last command's target (what the regulator was last told)
        self.accel = cfg.drive.max_accel_m_per_s2
        self._acting = (0.0, self.accel)  # the (target, accel) the drive follows at self.t
        self._pending: list[tuple[float, float, float]] = []  # commands not yet reached: (t, target, accel)
        self.last_tick: Tick | None = None
        self._listeners: list[Listener] = []
        self._lock = threading.Lock()
        self._loop = BackgroundLoop(self._tick, "realtime-rig")
        self.wall0 = time.monotonic()
        self.behind_max_s = 0.0  # the most the physics has been behind the wall clock, running on its own [s]

    # --- the motor's side
    def set_drive(self, target: float, accel: float | None = None) -> None:
        """Ramp the drive toward target [m/s] at accel [m/s^2] (default: the rig's limit), from the simulated
        instant this call's wall-clock time stands for.

        Why that instant and not the next tick: on a loaded machine the physics runs behind the wall clock
        (measured here: up to 154 ms beside two busy processes; ``behind_max_s``). A command applied at the
        next tick would act that much earlier in the record than the host saw it sent, as if the belt answered
        before it was told; a real rig never runs late. Stepped by a caller (not running), there is no wall
        clock to follow: the command acts from the next step.
        """
        target = max(0.0, float(target))
        accel = float(accel if accel is not None else self.cfg.drive.max_accel_m_per_s2)
        at = (time.monotonic() - self.wall0) * self.time_scale if self._loop.running else self.t
        with self._lock:
            self.target, self.accel = target, accel
            self._pending.append((max(at, self.t), target, accel))

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
        """The drive's commanded speed over [t0, t0 + dur] as knots (t, v): the regulator's ramp limiter
        following each command from its own instant; one knot past the end holds the last speed."""
        t_end = t0 + dur
        with self._lock:
            v = self.v_cmd
            (target, accel), todo = self._acting, [c for c in self._pending if c[0] < t_end]
        knots_t, knots_v = [t0], [v]

        def follow(t_from: float, t_to: float, v: float) -> float:  # limiter toward target over [t_from, t_to]
            t_reach = abs(target - v) / accel if accel > 0 else np.inf
            if t_reach >= t_to - t_from:
                v_to = v + np.sign(target - v) * accel * (t_to - t_from)
            else:
                if t_reach > 0:
                    knots_t.append(t_from + t_reach), knots_v.append(target)
                v_to = target
            if t_to > knots_t[-1]:
                knots_t.append(t_to), knots_v.append(v_to)
            return v_to

        t = t0
        for t_at, new_target, new_accel in todo:
            v = follow(t, max(t, t_at), v)
            t, target, accel = max(t, t_at), new_target, new_accel
        v = follow(t, t_end, v)
        knots_t.append(t_end + 1.0), knots_v.append(v)
        return np.array(knots_t), np.array(knots_v)

    def _reached(self, t: float) -> None:
        """The commands due by simulated time t now act; the drive's speed is the limiter's at t."""
        with self._lock:
            while self._pending and self._pending[0][0] <= t:
                self._acting = self._pending.pop(0)[1:]

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
        self._reached(self.t)
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
        else:
            self.behind_max_s = max(self.behind_max_s, -delay)
        self.step(self.tick_s * self.time_scale)
