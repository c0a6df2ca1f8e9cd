"""One error type for bad input, so every command can report it as one line naming file and field."""

from __future__ import annotations


class InputError(Exception):
    """Bad user input (config, ramp, CSV, model file, CLI argument).

    The CLI prints ``str(err)`` on one line to stderr and exits with status 2.
    """

    def __init__(self, source: str, field: str, message: str) -> None:
        self.source = source
        self.field = field
        self.message = message
        super().__init__(f"{source}: {field}: {message}")
