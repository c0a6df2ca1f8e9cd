"""The motor regulator's line protocol (docs/protocols/motor-regulator.md), pure functions only.

Shared by the driver and the simulated regulator so the protocol is written once.
A line is ``BODY*HH\\r\\n`` with HH the XOR of BODY's bytes in hex (as NMEA 0183):
a flipped bit on the wire becomes a rejected command, never a wrong speed.
"""

from __future__ import annotations

from dataclasses import dataclass

from daq.errors import DaqError

EOL = b"\r\n"

# error codes of ``ERR <code> <text>`` replies
ERR_CHECKSUM = 1
ERR_SYNTAX = 2
ERR_LIMIT = 3
ERR_STATE = 4
ERR_LATCHED = 5

STATES = ("DISABLED", "RUNNING", "STOPPING", "ESTOP", "WATCHDOG")

TAG_MODULUS = 10000  # request tags run 0..9999 and wrap


class ProtocolError(DaqError, ValueError):
    """A line that is not a valid protocol line (bad framing or checksum)."""


def checksum(body: bytes) -> int:
    c = 0
    for b in body:
        c ^= b
    return c


def encode(body: str) -> bytes:
    """``SPD 0.1200`` -> ``b'SPD 0.1200*5C\\r\\n'``."""
    raw = body.encode("ascii")
    return raw + b"*%02X" % checksum(raw) + EOL


def decode(line: bytes) -> str:
    """Body of one received line (without EOL); raises ProtocolError on bad framing or checksum."""
    line = line.strip(b"\r\n")
    star = line.rfind(b"*")
    if star < 0 or len(line) - star != 3:
        raise ProtocolError(f"no checksum in {line[:40]!r}")
    body, hh = line[:star], line[star + 1:]
    try:
        want = int(hh, 16)
    except ValueError:
        raise ProtocolError(f"bad checksum field {hh!r}") from None
    if checksum(body) != want:
        raise ProtocolError(f"checksum mismatch in {line[:40]!r}")
    try:
        return body.decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError("non-ASCII body") from None


def tag(n: int, body: str) -> str:
    """``SPD?`` with tag 7 -> ``@7 SPD?``: the regulator answers ``@7 <reply>``, so a late reply is never
    taken for the answer to a later command."""
    return f"@{n % TAG_MODULUS} {body}"


def untag(body: str) -> tuple[int | None, str]:
    """``@7 SPD?`` -> (7, ``SPD?``); an untagged body -> (None, body) (a terminal typing commands by hand)."""
    if body.startswith("@"):
        head, _, rest = body.partition(" ")
        if head[1:].isdigit():
            return int(head[1:]), rest
    return None, body


class LineBuffer:
    """Splits a byte stream into lines; garbage without an EOL is bounded and discarded."""

    def __init__(self, max_line: int = 256) -> None:
        self.buf = bytearray()
        self.max_line = max_line
        self.discarded = 0

    def feed(self, data: bytes) -> list[bytes]:
        self.buf += data
        lines = []
        while True:
            i = self.buf.find(b"\n")
            if i < 0:
                break
            lines.append(bytes(self.buf[: i + 1]))
            del self.buf[: i + 1]
        if len(self.buf) > self.max_line:
            self.discarded += len(self.buf)
            self.buf.clear()
        return lines

    def clear(self) -> None:
        self.buf.clear()


@dataclass(frozen=True)
class Status:
    """Reply to ``STAT?``."""

    state: str
    measured: float  # belt speed from the tachometer [m/s]
    setpoint: float  # target the regulator ramps toward [m/s]
    watchdog_ms: int
    max_speed: float
    max_accel: float

    def encode(self) -> str:
        return (f"STAT {self.state} {self.measured:.5f} {self.setpoint:.5f} {self.watchdog_ms} "
                f"{self.max_speed:.4f} {self.max_accel:.4f}")

    @classmethod
    def parse(cls, body: str) -> "Status":
        parts = body.split()
        if len(parts) != 7 or parts[0] != "STAT" or parts[1] not in STATES:
            raise ProtocolError(f"bad STAT reply {body!r}")
        return cls(parts[1], float(parts[2]), float(parts[3]), int(parts[4]), float(parts[5]), float(parts[6]))
