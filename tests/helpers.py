"""Assertions shared by the bad-input tests: every error is one line naming file and field."""

from __future__ import annotations

from pathlib import Path

from daq.errors import InputError


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def expect_error(exc: InputError, source: str, field: str, *fragments: str) -> None:
    """The error is one line 'SOURCE: FIELD: message' with the given source and field."""
    text = str(exc)
    assert "\n" not in text
    assert (exc.source, exc.field) == (source, field), text
    assert text == f"{source}: {field}: {exc.message}"
    assert exc.message
    for frag in fragments:
        assert frag in exc.message, (frag, text)


def ramp_text(hold_s: float, stop: bool = True) -> str:
    """A ramp file for the daemon tests: 0.5 s up to 0.15 m/s, a hold, and (``stop``) 0.5 s down to rest."""
    text = ('start_m_per_s = 0.0\n[[segment]]\nkind = "linear"\nduration_s = 0.5\nto_m_per_s = 0.15\n'
            f'[[segment]]\nkind = "hold"\nduration_s = {hold_s}\n')
    return text + ('[[segment]]\nkind = "linear"\nduration_s = 0.5\nto_m_per_s = 0.0\n' if stop else "")
