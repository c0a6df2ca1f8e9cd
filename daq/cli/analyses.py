"""``daq analyse ...`` and ``daq campaign``: the seed papers' own identification experiments.

Each paper's analyses live in their own CLI module (daq/cli/paper000.py, paper001.py, paper002.py) so they can be read,
and grow, independently; this module only gathers them under one ``analyse`` command.
"""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from .paper000 import register as register_000
    from .paper001 import register as register_001
    from .paper002 import register as register_002
    from .rsf import register as register_rsf

    an = sub.add_parser("analyse", help="the seed papers' analyses on a recording (JSON + figures)")
    asub = an.add_subparsers(dest="analysis", required=True, metavar="ANALYSIS")
    register_000(sub, asub)
    register_001(sub, asub)
    register_002(sub, asub)
    register_rsf(asub)
