"""The project's own errors: one base, and one error type for bad input.

``DaqError`` is the base of every exception this project raises on purpose, so a caller
can tell "our error, with a message meant for a person" from a bug in a library. Classes
that also keep a builtin base (``class MotorUnavailable(DaqError, ConnectionError)``) do
so for the ``except ConnectionError`` clauses that existed before the base did.

``InputError`` is bad input, so every command can report it as one line naming file and field.
``NumericalFailure`` is good input that a computation could not carry through (linear algebra that does not
converge, a simulation that is not finite): a fit that ends this way is reported as failed, with its reason, and
whatever asked for it goes on where it can (decision 50).
"""

from __future__ import annotations

import tomllib
from pathlib import Path


class DaqError(Exception):
    """Base of the project's own exceptions (drivers, config, daemon, analyses)."""


class InputError(DaqError):
    """Bad user input (config, ramp, CSV, model file, CLI argument).

    The CLI prints ``str(err)`` on one line to stderr and exits with status 2.
    """

    def __init__(self, source: str, field: str, message: str) -> None:
        self.source = source
        self.field = field
        self.message = message
        super().__init__(f"{source}: {field}: {message}")


class NumericalFailure(DaqError):
    """A fit or simulation that could not be carried through on this input; ``str(err)`` says where and why.

    A diagnosis marks the candidate whose fit raised it as failed and goes on; a command whose own fit raised it
    prints it on one line and exits with status 2, as for bad input.
    """


def read_text(path) -> str:
    """A user's input file as text; an unreadable file is an InputError naming it."""

    try:
        return Path(path).read_text()
    except OSError as exc:
        raise InputError(str(path), "(file)", exc.strerror or str(exc)) from None


def parse_toml(text: str, source: str) -> dict:
    """TOML text as a mapping; a syntax error is an InputError naming the file."""

    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(source, "(syntax)", str(exc)) from None
