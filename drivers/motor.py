"""The belt/drum motor regulator family: speed set points, readback, stops, and a heartbeat.

``MotorDrive`` is the family interface; ``SerialMotorRegulator`` speaks the line
protocol of docs/protocols/motor-regulator.md over any pyserial URL. Safety lives
in the regulator (its watchdog stops the belt when heartbeats stop, its limits
refuse set points), so the driver only has to keep the heartbeat going while its
process is alive, and to reconnect when the port comes back.
"""

from __future__ import annotations

import collections
import threading
import time
from abc import ABC, abstractmethod

import serial
from pydantic import Field

from daq.background import BackgroundLoop
from daq.config import MotorSettings, RigConfig
from daq.errors import DaqError

from .base import Backoff, BackoffCfg, DriverState, EventLog, close_quietly
from .motor_protocol import ERR_CHECKSUM, TAG_MODULUS, LineBuffer, ProtocolError, Status, decode, encode, tag, untag


class MotorError(DaqError, RuntimeError):
    """The regulator refused a command (``ERR <code> <text>``)."""

    def __init__(self, code: int, text: str, command: str) -> None:
        self.code = code
        self.text = text
        self.command = command
        super().__init__(f"regulator refused {command!r}: ERR {code} {text}")


class MotorUnavailable(DaqError, ConnectionError):
    """The regulator cannot be reached right now; the driver keeps reconnecting."""


class MotorCfg(MotorSettings):
    """The regulator's settings (url, baudrate, watchdog, heartbeat: ``MotorSettings`` in daq/config.py) plus the
    driver's run-time-only fields."""

    timeout_s: float = Field(0.25, gt=0, description="reply timeout per request")
    retries: int = Field(2, ge=0, description="re-sends of a request whose reply was corrupted")
    backoff: BackoffCfg = BackoffCfg()


class MotorDrive(ABC):
    """What the daemon needs from any motor regulator."""

    @abstractmethod
    def enable(self) -> None: ...

    @abstractmethod
    def disable(self) -> None: ...

    @abstractmethod
    def set_speed(self, v: float) -> None:
        """Set point [m/s]; the regulator ramps toward it under its acceleration limit."""

    @abstractmethod
    def set_accel(self, a: float) -> None: ...

    @abstractmethod
    def read_speed(self) -> tuple[float, float]:
        """(measured, set point) [m/s]."""

    @abstractmethod
    def stop(self) -> None:
        """Controlled ramp to rest."""

    @abstractmethod
    def estop(self) -> None:
        """Emergency stop, latched until reset()."""

    @abstractmethod
    def reset(self) -> None: ...

    @abstractmethod
    def status(self) -> Status: ...


class SerialMotorRegulator(MotorDrive):
    @classmethod
    def from_settings(cls, name: str, settings: MotorSettings, rig: RigConfig) -> SerialMotorRegulator:
        """The driver for one [instruments] entry (drivers/families.py registers it for motor-regulator)."""
        return cls(MotorCfg(**settings.model_dump()), name=name)

    def __init__(self, cfg: MotorCfg, name: str = "motor") -> None:
        self.cfg = cfg
        self.name = name
        self.state = DriverState.CLOSED
        self.log = EventLog(name)
        self.frame_errors = 0
        self.reconnects = 0
        self._port: serial.SerialBase | None = None
        self._lines = LineBuffer()
        self._pending: collections.deque[bytes] = collections.deque()  # lines read but not yet consumed
        self.stale_replies = 0  # late replies to timed-out requests, discarded
        self._tag = 0  # the tag of the last request sent
        self._lock = threading.RLock()
        self._backoff = Backoff(cfg.backoff)
        self._hb_seq = 0
        self._hb = BackgroundLoop(self._heartbeat, f"{name}-heartbeat", interval=cfg.heartbeat_s)
        self._lost_at: float | None = None

    # --- connection
    def open(self, heartbeat: bool = True) -> None:
        """Connect, configure the watchdog, start the heartbeat. Raises MotorUnavailable if absent."""
        self.state = DriverState.CONNECTING
        with self._lock:
            self._connect()
        if heartbeat:
            self.start_heartbeat()

    def close(self) -> None:
        """Stop the heartbeat and release the port (the regulator's watchdog then stops the belt)."""
        self.stop_heartbeat()
        with self._lock:
            self._drop_port()
            self.state = DriverState.CLOSED

    def _connect(self) -> None:
        try:
            self._port = serial.serial_for_url(self.cfg.url, baudrate=self.cfg.baudrate, timeout=0.01,
                                               write_timeout=self.cfg.timeout_s)
        except (serial.SerialException, OSError) as exc:
            self._port = None
            self._backoff.failed(time.monotonic())
            self._mark_lost(f"cannot open: {exc}")
            raise MotorUnavailable(str(exc)) from None
        self._lines.clear()
        self._pending.clear()
        self._port.reset_input_buffer()
        was_lost = self._lost_at is not None
        self._backoff.succeeded()
        self._exchange(f"WDT {self.cfg.watchdog_ms}")
        if was_lost:
            self.reconnects += 1
            self.log.emit("gap", "regulator unreachable", gap_s=time.monotonic() - self._lost_at)
            self._lost_at = None
        self.log.emit("connected", "reconnected" if was_lost else "opened")
        self.state = DriverState.CONNECTED  # last: whoever sees CONNECTED also sees the events

    def _drop_port(self) -> None:
        port, self._port = self._port, None
        close_quietly(port)

    def _mark_lost(self, why: str) -> None:
        if self.state != DriverState.RECONNECTING:
            self.state = DriverState.RECONNECTING
            self._lost_at = time.monotonic()
            self.log.emit("disconnected", why)

    def _ensure(self) -> None:
        if self.state == DriverState.CLOSED:
            raise RuntimeError(f"{self.name}: closed; call open() first")
        if self._port is None:
            if not self._backoff.ready(time.monotonic()):
                raise MotorUnavailable(f"{self.name}: reconnecting")
            self._connect()

    # --- request/reply
    def _exchange(self, body: str) -> str:
        """Send one command and return ITS reply body; retries corrupted, refused-as-corrupt or missing replies.

        Every request carries a fresh tag (``@n SPD?``) that the regulator echoes, so a reply that
        arrives after its request timed out is recognised and discarded instead of being read as
        the answer to the next command (which would leave the link one reply behind for good).
        A write timeout is a starved host or a full line, not a lost port: pyserial raises it
        after a complete write when the thread was descheduled past ``write_timeout``, so it is
        handled like a missing reply (retry), and only an OS error drops the port.
        """
        assert self._port is not None
        for _ in range(self.cfg.retries + 1):
            self._tag = (self._tag + 1) % TAG_MODULUS
            try:
                self._discard_stale()
                try:
                    self._port.write(encode(tag(self._tag, body)))
                except serial.SerialTimeoutException:
                    self.frame_errors += 1
                    self.log.emit("frame_error", f"write timeout sending {body!r}")
                    continue
                reply = self._read_reply(self._tag)
            except (serial.SerialException, OSError) as exc:
                self._drop_port()
                self._backoff.failed(time.monotonic())
                self._mark_lost(f"{type(exc).__name__}: {exc}")
                raise MotorUnavailable(str(exc)) from None
            if reply is not None:
                if reply.startswith("ERR "):
                    code, _, text = reply[4:].partition(" ")
                    raise MotorError(int(code), text, body)
                return reply
        raise MotorUnavailable(f"{self.name}: no valid reply to {body!r}")

    def _discard_stale(self) -> None:
        """Drop replies to earlier, timed-out requests (the regulator never speaks unasked)."""
        assert self._port is not None
        waiting = self._port.in_waiting
        stale = len(self._pending) + (1 if waiting or self._lines.buf else 0)
        if waiting:
            self._port.read(waiting)
        self._lines.clear()
        self._pending.clear()
        if stale:
            self.stale_replies += stale
            self.log.emit("frame_error", f"discarded {stale} late reply(ies) before the next command")

    def _read_reply(self, want: int) -> str | None:
        """The body of the reply tagged ``want``; None on a corrupted reply, a command the regulator
        received corrupted (untagged ``ERR 1``), or a timeout: the caller re-sends.

        The deadline is judged *before* each read and the loop ends only after the read that followed it: a thread
        descheduled past the deadline (a starved host) first reads what arrived meanwhile. Judged after the read
        (before 2026-11-28), a reply waiting in the port was a timeout, a re-send and a discarded late reply; with
        every re-send starved alike, a failed poll on a regulator that had answered each time."""
        deadline = time.monotonic() + self.cfg.timeout_s
        assert self._port is not None
        expired = False
        while not expired:
            expired = time.monotonic() >= deadline
            if not self._pending:
                data = self._port.read(self._port.in_waiting or 1)
                self._pending.extend(self._lines.feed(data))
            while self._pending:
                line = self._pending.popleft()
                try:
                    n, reply = untag(decode(line))
                except ProtocolError as exc:
                    self.frame_errors += 1
                    self.log.emit("frame_error", str(exc))
                    return None
                if n == want:
                    return reply
                if n is None and reply.startswith(f"ERR {ERR_CHECKSUM} "):
                    self.frame_errors += 1  # our command arrived damaged: its tag could not be trusted
                    self.log.emit("frame_error", "regulator received a corrupted command")
                    return None
                self.stale_replies += 1  # a late reply to an earlier request
                self.log.emit("frame_error", f"discarded reply {reply!r} tagged {n}: waiting for tag {want}")
        self.frame_errors += 1
        self.log.emit("frame_error", "reply timeout")
        return None

    def request(self, body: str) -> str:
        with self._lock:
            self._ensure()
            return self._exchange(body)

    # --- the family interface
    def enable(self) -> None:
        self.request("ENA")

    def disable(self) -> None:
        self.request("DIS")

    def set_speed(self, v: float) -> None:
        self.request(f"SPD {v:.5f}")

    def set_accel(self, a: float) -> None:
        self.request(f"ACC {a:.5f}")

    def read_speed(self) -> tuple[float, float]:
        parts = self.request("SPD?").split()
        if len(parts) != 3 or parts[0] != "SPD":
            raise MotorUnavailable(f"bad SPD? reply {parts!r}")
        return float(parts[1]), float(parts[2])

    def stop(self) -> None:
        self.request("STOP")

    def estop(self) -> None:
        self.request("ESTOP")

    def reset(self) -> None:
        self.request("RST")

    def status(self) -> Status:
        """STAT?, parsed. A latched state is reported once, by whoever watches the regulator (the daemon polls it),
        not here on every read: a read every 0.2 s would write five events a second into the recording."""
        return Status.parse(self.request("STAT?"))

    def identify(self) -> str:
        return self.request("ID?")

    # --- heartbeat
    def start_heartbeat(self) -> None:
        self._hb.start()

    def stop_heartbeat(self) -> None:
        self._hb.stop(timeout=2.0)

    def _heartbeat(self) -> None:
        """One beat, every ``heartbeat_s`` (the first one period after start)."""
        self._hb_seq = (self._hb_seq + 1) % 10000
        try:
            reply = self.request(f"HB {self._hb_seq}")
        except (MotorUnavailable, MotorError):
            return  # reconnecting; the regulator's watchdog covers the gap
        if reply != f"HB {self._hb_seq}":
            self.frame_errors += 1
            self.log.emit("frame_error", f"heartbeat echo {reply!r}")
