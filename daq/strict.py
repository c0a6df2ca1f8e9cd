"""The one base of every pydantic model that crosses a boundary: unknown fields are errors.

Configs, control and web messages, ramp and model files, stream headers, session and campaign state
files, analysis results: a typo in a field name must fail loudly, never fall back to a default
(docs/decisions/0010-strict-configs-one-line-errors.md). Each such model derives from ``Closed``
instead of repeating ``ConfigDict(extra="forbid")``; a model adds its own options on top
(``model_config = ConfigDict(frozen=True)``), and pydantic merges them with the base's.

``Strict`` is ``Closed``, frozen, and refusing NaN/inf: rig configs (daq/config.py, which re-exports
it), programmes, archive rows, soak reports.

This module sits in the bottom layer (tests/test_layering.py) so that every layer can import it,
and it imports nothing of ours.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Closed(BaseModel):
    """Unknown fields are errors (pydantic's "Extra inputs are not permitted")."""

    model_config = ConfigDict(extra="forbid")


class Strict(Closed):
    """Closed, frozen, and finite: NaN and inf are refused."""

    model_config = ConfigDict(frozen=True, allow_inf_nan=False)
