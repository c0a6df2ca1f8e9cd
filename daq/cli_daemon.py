"""``daq daemon`` and ``daq ctl``: the operator daemon and its control client on the command line.

Kept apart from daq/cli.py because the daemon's options (keys, endpoints, sim
faults) are many and only the operator needs them.
"""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``daemon`` and ``ctl`` subcommands to the ``daq`` parser (filled in by issue 6)."""
