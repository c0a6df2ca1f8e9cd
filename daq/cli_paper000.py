"""Paper 000's analyses on the command line (placeholder until they land)."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction, analyse: argparse._SubParsersAction) -> None:
    """Add this paper's commands: under ``daq analyse`` (analyse) or at the top level (sub)."""
