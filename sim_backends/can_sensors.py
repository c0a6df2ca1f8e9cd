"""Simulated CAN sensors: a rig's measured channels as DBC frames on a python-can bus.

The frames are encoded with cantools from the same DBC the driver decodes
(drivers/rig_sensors.dbc), one message per channel and sample, in sample order.
Faults: ``Faults.drop_prob`` skips frames but still advances the message's
sequence counter (the loss is visible to the host); ``bus_error()`` puts an error
frame on the bus; ``unplug()``/``replug()`` stop and resume sending (the sensor keeps
sampling and counting, as with a pulled cable), which the host sees as silence.
"""

from __future__ import annotations

import threading
import time

import can
import numpy as np
from cantools.database.can import Message, Signal

from daq.config import CanSettings, ChannelCfg
from drivers.can_sensors import (
    SEQ_MODULUS,
    SEQ_SIGNAL,
    TIME_MODULUS,
    TIME_SIGNAL,
    TIME_UNIT_S,
    CanBusCfg,
    SensorSelection,
    value_signal,
    wall_minus_monotonic,
)

from .instrument import DeviceClock, Faults, SimInstrument
from .pty_port import PtyPort
from .realtime import RealtimeRig, Tick

FRAME_BITS = 125  # an 8-byte classic frame with an 11-bit id: 111 bits plus typical stuff bits and the gap
NOMINAL_BITRATE = 1_000_000  # for the transmit-time model when the bus config leaves the bitrate open


class SimCanSensors(SimInstrument):
    """The CAN sensors of one rig, fed by a RealtimeRig, sharing one device clock."""

    @classmethod
    def from_settings(cls, rig: RealtimeRig, name: str, settings: CanSettings, *, port: PtyPort | None,
                      clock: DeviceClock, seed: int) -> SimCanSensors:
        """The sensors for one [instruments] entry (sim_backends/families.py registers it): the channels it
        carries, on its bus (no ``port``: CAN needs none)."""
        return cls(rig, CanBusCfg.of(settings), SensorSelection(rig=rig.cfg.rig, channels=list(settings.channels)),
                   name=name, clock=clock, seed=seed)

    def __init__(self, rig: RealtimeRig, bus: CanBusCfg, select: SensorSelection | None = None,
                 channels: dict[str, ChannelCfg] | None = None, *, name: str = "sim-can",
                 clock: DeviceClock | None = None, faults: Faults | None = None, seed: int = 0,
                 max_backlog: int = 100) -> None:
        """Sensors of ``select`` (default: the rig's in the DBC), channels as ``channels`` (default: rig config)."""
        select = select or SensorSelection(rig=rig.cfg.rig)
        if select.rig != rig.cfg.rig:
            raise ValueError(f"selection is for {select.rig}, the rig is {rig.cfg.rig}")
        cfgs = channels if channels is not None else rig.cfg.channels
        msgs = [m for m in select.messages() if value_signal(m) in cfgs]
        super().__init__(rig, name, {value_signal(m): cfgs[value_signal(m)] for m in msgs}, clock, faults, seed,
                         max_backlog)
        self._msgs: list[Message] = msgs
        self._checked = False  # channels the rig does not produce (belt x2, x3 with one mass) are dropped at tick 1
        self._drop_rng = np.random.default_rng([seed, 1])  # apart from the noise, so drops do not change values
        self._seq = {m.frame_id: 0 for m in msgs}
        self._send_lock = threading.Lock()
        self._plugged = True
        self.bus_cfg = bus
        # on the virtual bus the receive timestamp is ours to set: see _rx_times
        self._bus: can.BusABC | None = bus.open(**({"preserve_timestamps": True} if bus.interface == "virtual" else {}))
        self.frame_s = FRAME_BITS / (bus.bitrate or NOMINAL_BITRATE)
        self.sent = {value_signal(m): 0 for m in msgs}  # frames put on the bus, per channel
        self.dropped = dict.fromkeys(self.sent, 0)  # skipped by drop_prob
        self.unplugged_frames = dict.fromkeys(self.sent, 0)  # sampled while unplugged
        self.send_errors = 0
        self.error_frames = 0

    @property
    def frames_sent(self) -> int:
        """Frames put on the bus, all channels."""
        return sum(self.sent.values())

    @property
    def frames_dropped(self) -> int:
        """Frames skipped by drop_prob (each one a sequence gap the host can count)."""
        return sum(self.dropped.values())

    # --- stepping without the instrument thread
    def attach(self) -> None:
        """Encode and send inside rig.step() (deterministic: for stepped tests and benchmarks)."""
        self.rig.subscribe(self.emit)

    def detach(self) -> None:
        """Undo attach()."""
        self.rig.unsubscribe(self.emit)

    # --- faults
    def bus_error(self) -> None:
        """Put an error frame on the bus (as a controller does after a bit or stuff error)."""
        with self._send_lock:
            if self._bus is not None:
                self._bus.send(can.Message(is_error_frame=True, is_extended_id=False, timestamp=time.time()))
                self.error_frames += 1

    def unplug(self) -> None:
        """Stop sending (the sensor keeps sampling and counting): the host hears silence."""
        with self._send_lock:
            self._plugged = False

    def replug(self) -> None:
        """Resume sending."""
        with self._send_lock:
            self._plugged = True

    @property
    def plugged(self) -> bool:
        """Whether frames currently reach the bus."""
        return self._plugged

    # --- frames
    def _check_channels(self, tick: Tick) -> None:
        """Keep only messages whose channel this rig produces."""
        self._msgs = [m for m in self._msgs if value_signal(m) in tick.channels]
        self.channels = {value_signal(m): self.channels[value_signal(m)] for m in self._msgs}
        self._checked = True

    def emit(self, tick: Tick) -> None:
        """Encode one tick: per sample, one frame per channel in id order."""
        if not self._checked:
            self._check_channels(tick)
        values = self.measured(tick)
        raw_t = np.rint(self.device_times(tick) / TIME_UNIT_S).astype(np.int64) % TIME_MODULUS
        n, msgs = tick.t.size, self._msgs
        p = self.faults.drop_prob
        drops = self._drop_rng.random((n, len(msgs))) < p if p > 0 else np.zeros((n, len(msgs)), bool)
        cols = [(m, value_signal(m), m.get_signal_by_name(value_signal(m))) for m in msgs]
        vals = [values[ch].tolist() for _, ch, _ in cols]
        times = raw_t.tolist()
        rx = self._rx_times(tick, len(cols))
        with self._send_lock:
            for i in range(n):
                for j, (m, ch, sig) in enumerate(cols):
                    seq = self._seq[m.frame_id]
                    self._seq[m.frame_id] = (seq + 1) % SEQ_MODULUS
                    if not self._plugged:
                        self.unplugged_frames[ch] += 1
                    elif drops[i, j]:
                        self.dropped[ch] += 1
                    else:
                        self._send(m, ch, sig, vals[j][i], times[i], seq, rx[i, j])

    def _rx_times(self, tick: Tick, n_msgs: int) -> np.ndarray:
        """When each frame would be received (time.time() scale): the sample's instant plus its turn on the bus.

        A sensor queues its frames at the sampling instant and the bus carries them back to
        back in id order, one every ``frame_s``; never later than now. A rig stepped by hand
        has a synthetic timeline: its frames get the send time. A hardware interface stamps reception itself;
        on the virtual bus this stands in for it, so the host's clock estimate does not
        depend on how Python threads happen to be scheduled.
        """
        now = time.monotonic()
        if not self._paced():
            return np.full((tick.t.size, n_msgs), time.time())
        rx = tick.host_time[:, None] + self.frame_s * np.arange(1, n_msgs + 1)[None, :]
        return np.minimum(rx, now) + wall_minus_monotonic()

    def _paced(self) -> bool:
        """Whether tick host times are real: the rig runs in its own thread, paced to the wall clock."""
        return self.rig.running

    def _send(self, m: Message, ch: str, sig: Signal, value: float, raw_t: int, seq: int, rx_time: float) -> None:
        """Encode and send one frame; the value is clipped to the signal's full scale, as a sensor would."""
        if not np.isfinite(value):
            self.send_errors += 1
            return
        if sig.minimum is not None:
            value = max(value, sig.minimum)
        if sig.maximum is not None:
            value = min(value, sig.maximum)
        # strict=False: cantools' own range checks repeat the clip above (time and sequence are taken modulo their
        # fields' ranges); they were 35 % of this thread's time, 2000 frames a second at 1 kHz
        data = m.encode({ch: value, TIME_SIGNAL: raw_t, SEQ_SIGNAL: seq}, strict=False)
        if self._bus is None:
            self.send_errors += 1
            return
        try:
            self._bus.send(can.Message(arbitration_id=m.frame_id, data=data, is_extended_id=m.is_extended_frame,
                                       timestamp=float(rx_time)))
        except can.CanError:
            self.send_errors += 1
            return
        self.sent[ch] += 1

    def close(self) -> None:
        """Stop listening to the rig and release the bus."""
        self.rig.unsubscribe(self.emit)
        with self._send_lock:
            bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()
