"""A simulated motor regulator (RN12-like) on a real pty, driving the simulated belt.

It obeys the protocol of docs/protocols/motor-regulator.md: limits enforced here
(independently of the daemon), a watchdog that ramps the belt to rest when no
valid command arrives within its timeout, e-stop and watchdog trips latched
until ``RST`` at standstill.
"""

from __future__ import annotations

import time

import numpy as np
from pydantic import Field

from daq.background import BackgroundLoop
from daq.config import MotorSettings
from daq.strict import Closed
from drivers.motor_protocol import (
    ERR_CHECKSUM,
    ERR_LATCHED,
    ERR_LIMIT,
    ERR_STATE,
    ERR_SYNTAX,
    LineBuffer,
    ProtocolError,
    Status,
    decode,
    encode,
    tag,
    untag,
)

from .instrument import DeviceClock
from .pty_port import PtyPort
from .realtime import RealtimeRig

STANDSTILL = 1e-3  # [m/s]


class RegulatorCfg(Closed):
    max_speed: float = Field(gt=0, description="refuses set points above this [m/s]")
    max_accel: float = Field(gt=0, description="ramp acceleration limit [m/s^2]")
    estop_decel: float = Field(gt=0, description="emergency deceleration [m/s^2]")
    watchdog_ms: int = Field(500, ge=50, le=10000)
    speed_noise: float = Field(0.0, ge=0, description="tachometer noise [m/s]")
    speed_lsb: float = Field(0.0, ge=0)

    @classmethod
    def for_rig(cls, rig: RealtimeRig) -> "RegulatorCfg":
        d = rig.cfg.drive
        vb = rig.cfg.channels.get("vb")
        return cls(max_speed=d.max_speed_m_per_s, max_accel=d.max_accel_m_per_s2,
                   estop_decel=4.0 * d.max_accel_m_per_s2,
                   speed_noise=vb.noise_std if vb else 0.0, speed_lsb=vb.lsb if vb else 0.0)


class SimMotorRegulator:
    @classmethod
    def from_settings(cls, rig: RealtimeRig, name: str, settings: MotorSettings, *, port: PtyPort | None,
                      clock: DeviceClock, seed: int) -> SimMotorRegulator:
        """The regulator for one [instruments] entry (sim_backends/families.py registers it): on ``port``, with
        the rig's drive limits; it has no device clock, and its watchdog default is its own (RegulatorCfg)."""
        return cls(rig, port, seed=seed)

    def __init__(self, rig: RealtimeRig, port: PtyPort, cfg: RegulatorCfg | None = None, seed: int = 0) -> None:
        self.rig = rig
        self.port = port
        self.cfg = cfg or RegulatorCfg.for_rig(rig)
        self.rng = np.random.default_rng(seed)
        self.state = "DISABLED"
        self.setpoint = 0.0
        self.accel = self.cfg.max_accel
        self.watchdog_ms = self.cfg.watchdog_ms
        self.last_command = time.monotonic()
        self.commands = 0
        self.checksum_errors = 0
        self.watchdog_trips = 0
        self.silent = False  # fault: stop answering (a hung regulator)
        self.corrupt_replies = 0  # fault: corrupt the next N replies
        self.late_replies = 0  # fault: answer the next N commands only after late_by_s (a starved regulator)
        self.late_by_s = 0.0
        self._lines = LineBuffer()
        self._loop = BackgroundLoop(lambda: self.serve_once(0.005), "sim-motor")

    # --- what the tachometer reads
    def measured_speed(self) -> float:
        v = self.rig.belt_speed
        if self.cfg.speed_noise:
            v += self.rng.normal(0.0, self.cfg.speed_noise)
        if self.cfg.speed_lsb:
            v = round(v / self.cfg.speed_lsb) * self.cfg.speed_lsb
        return float(v)

    # --- command handling
    def handle(self, body: str) -> str:
        parts = body.split()
        cmd = parts[0] if parts else ""
        arg = parts[1] if len(parts) > 1 else None
        latched = self.state in ("ESTOP", "WATCHDOG")
        if cmd == "ID?":
            return "ID RN12 2.1"
        if cmd == "HB":
            return f"HB {arg}" if arg is not None else f"ERR {ERR_SYNTAX} HB needs a counter"
        if cmd == "SPD?":
            return f"SPD {self.measured_speed():.5f} {self.setpoint:.5f}"
        if cmd == "STAT?":
            return Status(self.state, self.measured_speed(), self.setpoint, self.watchdog_ms,
                          self.cfg.max_speed, self.cfg.max_accel).encode()
        if cmd == "ESTOP":
            self._halt("ESTOP", self.cfg.estop_decel)
            return "OK"
        if cmd == "STOP" or cmd == "DIS":
            if not latched:
                self._halt("STOPPING", self.accel)
            return "OK"
        if cmd == "RST":
            if latched and self.rig.belt_speed > STANDSTILL:
                return f"ERR {ERR_STATE} belt still moving"
            if latched:
                self.state = "DISABLED"
            return "OK"
        if cmd == "WDT":
            try:
                ms = int(arg)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                return f"ERR {ERR_SYNTAX} WDT needs milliseconds"
            if not 50 <= ms <= 10000:
                return f"ERR {ERR_LIMIT} watchdog must be 50..10000 ms"
            self.watchdog_ms = ms
            return "OK"
        if cmd in ("ENA", "SPD", "ACC"):
            if latched:
                return f"ERR {ERR_LATCHED} {self.state} latched; RST at standstill"
            if cmd == "ENA":
                if self.state != "RUNNING":
                    self.state = "RUNNING"
                    self.setpoint = 0.0
                return "OK"
            try:
                val = float(arg)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                return f"ERR {ERR_SYNTAX} {cmd} needs a number"
            if cmd == "ACC":
                if not 0.0 < val <= self.cfg.max_accel:
                    return f"ERR {ERR_LIMIT} acceleration must be in (0, {self.cfg.max_accel:g}] m/s^2"
                self.accel = val
                if self.state == "RUNNING":
                    self.rig.set_drive(self.setpoint, self.accel)
                return "OK"
            if self.state != "RUNNING":
                return f"ERR {ERR_STATE} not enabled"
            if not 0.0 <= val <= self.cfg.max_speed:
                return f"ERR {ERR_LIMIT} speed must be in [0, {self.cfg.max_speed:g}] m/s"
            self.setpoint = val
            self.rig.set_drive(val, self.accel)
            return "OK"
        return f"ERR {ERR_SYNTAX} unknown command {cmd!r}"

    def _halt(self, state: str, decel: float) -> None:
        self.state = state
        self.setpoint = 0.0
        self.rig.set_drive(0.0, decel)

    def check_watchdog(self, now: float) -> None:
        if self.state == "RUNNING" and (now - self.last_command) * 1000.0 > self.watchdog_ms:
            self.watchdog_trips += 1
            self._halt("WATCHDOG", self.cfg.max_accel)
        if self.state == "STOPPING" and self.rig.belt_speed <= STANDSTILL:
            self.state = "DISABLED"

    def serve_once(self, timeout: float = 0.01) -> None:
        """Answer what the host wrote, then check the watchdog.

        The time is taken before the read: everything written before ``now`` is returned by this read,
        so a silence measured up to ``now`` is one the host made. Taken after it (as it was), a loop
        descheduled between an empty read and the clock counted its own stall as the host's silence,
        and tripped with a heartbeat waiting unread in the pty (a CI run under full load, stop 45).
        """
        now = time.monotonic()
        data = self.port.read(timeout)
        for line in self._lines.feed(data):
            try:
                body = decode(line)
            except ProtocolError:
                self.checksum_errors += 1
                reply = f"ERR {ERR_CHECKSUM} bad checksum"
            else:
                self.commands += 1
                self.last_command = now
                n, command = untag(body)
                reply = self.handle(command) if n is None else tag(n, self.handle(command))
            if self.silent:
                continue
            raw = encode(reply)
            if self.late_replies > 0:
                self.late_replies -= 1
                time.sleep(self.late_by_s)
            if self.corrupt_replies > 0:
                self.corrupt_replies -= 1
                raw = raw[:2] + bytes([raw[2] ^ 0x20]) + raw[3:]
            self.port.write(raw)
        self.check_watchdog(now)

    # --- threading
    def start(self) -> "SimMotorRegulator":
        self.last_command = time.monotonic()
        self._loop.start()
        return self

    def stop(self) -> None:
        self._loop.stop(timeout=2.0)
