"""What every simulated instrument shares: its clock, its sensor model, and the faults it can be told to show."""

from __future__ import annotations

import queue

import numpy as np
from pydantic import ConfigDict, Field

from daq.background import BackgroundLoop
from daq.config import ChannelCfg
from daq.sim.sensors import measure
from daq.strict import Closed

from .realtime import RealtimeRig, Tick


class DeviceClock(Closed):
    """The instrument's own clock: it starts at ``offset_s`` and runs fast by ``drift_ppm``."""

    offset_s: float = 0.0
    drift_ppm: float = 0.0

    def device_time(self, host_time: np.ndarray, host_ref: float) -> np.ndarray:
        return self.offset_s + (host_time - host_ref) * (1.0 + self.drift_ppm * 1e-6)


class Faults(Closed):
    """Faults an instrument can be told to show (switchable at run time)."""

    model_config = ConfigDict(validate_assignment=True)
    garbage_prob: float = Field(0.0, ge=0, le=1, description="chance per frame of a burst of garbage bytes before it")
    drop_prob: float = Field(0.0, ge=0, le=1, description="chance per frame of losing it")
    stuck: bool = False  # the sensor repeats its last value
    saturate_at: float | None = Field(None, gt=0, description="|value| clipped to this full scale")


class SimInstrument:
    """Subscribes to a RealtimeRig; each tick becomes measured values, then frames on a transport.

    Encoding and sending run in the instrument's own thread so a slow transport never
    slows the physics; ticks that pile up beyond ``max_backlog`` are dropped and counted.
    """

    def __init__(self, rig: RealtimeRig, name: str, channels: dict[str, ChannelCfg],
                 clock: DeviceClock | None = None, faults: Faults | None = None, seed: int = 0,
                 max_backlog: int = 100) -> None:
        self.rig = rig
        self.name = name
        self.channels = channels
        self.clock = clock or DeviceClock()
        self.faults = faults or Faults()
        self.rng = np.random.default_rng(seed)
        self._q: queue.Queue[Tick] = queue.Queue(maxsize=max_backlog)
        self._stuck_value: dict[str, float] = {}
        self.ticks_dropped = 0
        self._loop = BackgroundLoop(self._next_tick, f"sim-{name}")

    # --- sensor model plus faults
    def measured(self, tick: Tick) -> dict[str, np.ndarray]:
        out = {}
        for ch, cfg in self.channels.items():
            x = measure(cfg, tick.t, tick.channels[ch], self.rng)
            if self.faults.saturate_at is not None:
                x = np.clip(x, -self.faults.saturate_at, self.faults.saturate_at)
            if self.faults.stuck:
                x = np.full_like(x, self._stuck_value.setdefault(ch, float(x[0])))
            else:
                self._stuck_value.pop(ch, None)
            out[ch] = x
        return out

    def device_times(self, tick: Tick) -> np.ndarray:
        return self.clock.device_time(tick.host_time, self.rig.wall0)

    # --- threading
    def _on_tick(self, tick: Tick) -> None:
        try:
            self._q.put_nowait(tick)
        except queue.Full:
            self.ticks_dropped += 1

    def start(self) -> None:
        self.rig.subscribe(self._on_tick)
        self._loop.start()

    def stop(self) -> None:
        self.rig.unsubscribe(self._on_tick)
        self._loop.stop(timeout=2.0)
        self.close()

    def _next_tick(self) -> None:
        """Emit the next queued tick, or idle when none came within 50 ms."""
        try:
            tick = self._q.get(timeout=0.05)
        except queue.Empty:
            self.idle()
            return
        self.emit(tick)

    def emit(self, tick: Tick) -> None:
        """Encode and send one tick's samples (implemented by each instrument)."""
        raise NotImplementedError

    def idle(self) -> None:
        """Called when no tick arrived for a while (e.g. to serve commands)."""

    def close(self) -> None:
        """Release the transport."""
