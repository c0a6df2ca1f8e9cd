"""A simulated thermocouple meter: answers ASCII queries on a pty with the rig's measured contact temperature."""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass

from daq.background import BackgroundLoop
from daq.config import ThermocoupleSettings

from .instrument import DeviceClock, Faults, SimInstrument
from .pty_port import PtyPort
from .realtime import RealtimeRig, Tick

IDN = "SIM,THERMOCOUPLE,0,1.0"


def format_temp(value: float) -> str:
    """The meter's reply format: sign, at least four integer digits, two decimals (``+0023.45``)."""
    return f"{value:+08.2f}"


@dataclass(slots=True)
class Answer:
    """One reply the meter gave (or withheld): the test oracle for the driver."""

    host_time: float
    command: str
    reply: str | None  # None: stayed silent
    value: float | None  # the temperature behind the reply
    truth: float | None  # the true contact temperature at that moment


class SimThermocouple(SimInstrument):
    """A 9600-baud meter on a PtyPort; each tick updates its reading, a server thread answers at once.

    Fault switches: ``garble_next`` / ``silent_next`` / ``error_next`` spoil that many coming
    TEMP? replies; ``Faults.garbage_prob`` / ``Faults.drop_prob`` do it at random.
    """

    @classmethod
    def from_settings(cls, rig: RealtimeRig, name: str, settings: ThermocoupleSettings, *, port: PtyPort | None,
                      clock: DeviceClock, seed: int) -> SimThermocouple:
        """The meter for one [instruments] entry (sim_backends/families.py registers it), at its baud rate on
        ``port``."""
        return cls(rig, port, name=name, clock=clock, seed=seed, baudrate=settings.baudrate)

    def __init__(self, rig: RealtimeRig, port: PtyPort, channel: str = "temp", name: str = "thermocouple",
                 clock: DeviceClock | None = None, faults: Faults | None = None, seed: int = 0,
                 baudrate: int = 9600) -> None:
        super().__init__(rig, name, {channel: rig.cfg.channels[channel]}, clock, faults, seed)
        self.port = port
        self.channel = channel
        self.baudrate = baudrate
        self.value: float | None = None
        self.truth: float | None = None
        self.garble_next = 0
        self.silent_next = 0
        self.error_next = 0
        self.error_text = "ERR OPEN CIRCUIT"
        self.answers: collections.deque[Answer] = collections.deque(maxlen=100_000)
        self._value_lock = threading.Lock()
        self._server = BackgroundLoop(self._serve_once, f"sim-{name}-cmd")
        self._line = bytearray()  # the command line read so far (server thread)
        self._was_plugged = True

    # --- the measurement side (instrument thread)
    def emit(self, tick: Tick) -> None:
        """Take the latest measured (and true) temperature from the tick."""
        x = self.measured(tick)[self.channel]
        with self._value_lock:
            self.value = float(x[-1])
            self.truth = float(tick.channels[self.channel][-1])

    # --- the serial side (server thread)
    def start(self) -> None:
        """Start the measurement thread and the command server."""
        super().start()
        self._line.clear()
        self._was_plugged = self.port.plugged
        self._server.start()

    def stop(self) -> None:
        """Stop both threads."""
        self._server.stop(timeout=2.0)
        super().stop()

    def _serve_once(self) -> None:
        """Read command lines (CR, LF or CRLF terminated) and answer each at once."""
        if not self.port.plugged:
            self._was_plugged = False
            time.sleep(0.02)
            return
        line = self._line
        if not self._was_plugged:  # a fresh pty: no half line from before the unplug
            line.clear()
            self._was_plugged = True
        data = self.port.read(timeout=0.05, n=256)
        for b in data:
            if b in (0x0A, 0x0D):
                if line:
                    self._answer(line.decode("ascii", "replace").strip())
                    line.clear()
            elif len(line) < 64:
                line.append(b)

    def _reply_to(self, command: str) -> tuple[str | None, float | None, float | None]:
        """The meter's command set: TEMP? and *IDN?; anything else is an error reply."""
        cmd = command.upper()
        if cmd == "*IDN?":
            return IDN, None, None
        if cmd != "TEMP?":
            return f"ERR UNKNOWN COMMAND {command[:16]}", None, None
        with self._value_lock:
            value, truth = self.value, self.truth
        if value is None:
            return "ERR NOT READY", None, None
        f = self.faults
        if self.silent_next > 0:
            self.silent_next -= 1
            return None, value, truth
        if self.garble_next > 0:
            self.garble_next -= 1
            return self._garble(format_temp(value)), value, truth
        if self.error_next > 0:
            self.error_next -= 1
            return self.error_text, value, truth
        if f.drop_prob > 0 and self.rng.random() < f.drop_prob:
            return None, value, truth
        if f.garbage_prob > 0 and self.rng.random() < f.garbage_prob:
            return self._garble(format_temp(value)), value, truth
        return format_temp(value), value, truth

    def _garble(self, text: str) -> str:
        """Corrupt one digit of a reply, as line noise would (still one line, no longer a number)."""
        k = int(self.rng.integers(1, len(text)))
        if text[k] == ".":
            k -= 1
        return text[:k] + "#" + text[k + 1:]

    def _answer(self, command: str) -> None:
        """Write the reply line (if any) and log it."""
        reply, value, truth = self._reply_to(command)
        self.answers.append(Answer(time.monotonic(), command, reply, value, truth))  # logged before the host can see it
        if reply is not None:
            payload = reply.encode("ascii") + b"\r\n"
            time.sleep(len(payload) * 10 / self.baudrate)  # the reply's time on the wire (8N1)
            self.port.write(payload)
