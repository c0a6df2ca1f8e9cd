"""Driver for a slow thermocouple meter polled with an ASCII query (docs/protocols/thermocouple.md)."""

from __future__ import annotations

import re
import time

import serial
from pydantic import Field

from daq.config import RigConfig, ThermocoupleSettings
from daq.errors import DaqError

from .base import BackoffCfg, Sample, SampleSource, close_quietly

try:  # pyserial's posix backend lets termios.error escape from flushes on a vanished device
    import termios

    _TERMIOS_ERRORS: tuple[type[BaseException], ...] = (termios.error,)
except ImportError:  # pragma: no cover - not posix
    _TERMIOS_ERRORS = ()

REPLY = re.compile(rb"^\s*([+-]?\d{1,6}(?:\.\d{1,4})?)\s*$")
MAX_LINE = 64


class ThermocoupleCfg(ThermocoupleSettings):
    """One meter's settings (port, baud rate, poll rate: ``ThermocoupleSettings`` in daq/config.py) plus the driver's
    run-time-only fields: reply timeout, channel name, query, when to give the port up."""

    timeout_s: float = Field(0.25, gt=0, le=5, description="wait for the reply line after a query")
    channel: str = "temp"
    command: str = "TEMP?"
    reconnect_after_timeouts: int = Field(5, ge=0, description="consecutive silent polls that mean the device "
                                                                 "is gone and the port is reopened (0 = never)")


class DeviceSilent(DaqError, TimeoutError):
    """Too many polls without an answer: treated like a lost port so the base class reopens it."""


class ThermocoupleDriver(SampleSource):
    """Polls the meter at poll_hz; a timeout or a garbled or ERR reply is a frame error; a lost port reconnects."""

    transport_errors = (serial.SerialException, OSError) + _TERMIOS_ERRORS

    @classmethod
    def from_settings(cls, name: str, settings: ThermocoupleSettings, rig: RigConfig) -> ThermocoupleDriver:
        """The driver for one [instruments] entry (drivers/families.py registers it for thermocouple)."""
        return cls(ThermocoupleCfg(**settings.model_dump()), name=name)

    def __init__(self, cfg: ThermocoupleCfg, name: str = "thermocouple", backoff: BackoffCfg | None = None) -> None:
        super().__init__(name, backoff)
        self.cfg = cfg
        self.period = 1.0 / cfg.poll_hz
        self.query = cfg.command.encode("ascii") + b"\r\n"
        self.polls = 0
        self.silent_polls = 0  # consecutive
        self._next_poll = 0.0
        self._port: serial.SerialBase | None = None

    def _connect(self) -> None:
        """Open the port; the first poll goes out at once."""
        self._port = serial.serial_for_url(self.cfg.url, baudrate=self.cfg.baudrate, timeout=self.cfg.timeout_s)
        self.silent_polls = 0
        self._next_poll = time.monotonic()

    def _disconnect(self) -> None:
        """Close the port, swallowing errors of an already dead device."""
        port, self._port = self._port, None
        close_quietly(port)

    def _read_samples(self, timeout: float) -> list[Sample]:
        """Poll if one is due within timeout, otherwise just wait; keeps the poll cadence without drift."""
        now = time.monotonic()
        if now < self._next_poll:
            time.sleep(min(timeout, self._next_poll - now))
            if time.monotonic() < self._next_poll:
                return []
        self._next_poll = max(self._next_poll + self.period, time.monotonic())
        sample = self.poll()
        return [sample] if sample is not None else []

    def poll(self) -> Sample | None:
        """One query/reply exchange; returns the sample or None after counting a frame error."""
        port = self._port
        if port is None:
            raise serial.SerialException("port not open")
        port.reset_input_buffer()  # a late reply to an earlier, timed-out query must not be taken for this one
        t_send = time.monotonic()
        port.write(self.query)
        line = port.read_until(b"\n", MAX_LINE)
        t_recv = time.monotonic()
        self.polls += 1
        c = self.counters
        if not line.endswith(b"\n"):
            c.frame_errors += 1
            self.silent_polls += 1
            self.emit("frame_error", f"no complete reply within {self.cfg.timeout_s} s: {line[:MAX_LINE]!r}")
            if self.cfg.reconnect_after_timeouts and self.silent_polls >= self.cfg.reconnect_after_timeouts:
                raise DeviceSilent(f"{self.silent_polls} polls without a reply")
            return None
        self.silent_polls = 0
        m = REPLY.match(line)
        if m is None:
            c.frame_errors += 1
            text = line.strip().decode("ascii", "replace")
            if text.startswith("ERR"):
                c.extra["device_errors"] = c.extra.get("device_errors", 0) + 1
                self.emit("frame_error", f"device: {text}")
            else:
                self.emit("frame_error", f"garbled reply {line!r}")
            return None
        c.frames += 1
        # the meter has no clock: its reading is dated at the middle of the exchange, on the host clock
        return Sample(self.cfg.channel, float(m.group(1)), 0.5 * (t_send + t_recv), t_recv, self.polls)
