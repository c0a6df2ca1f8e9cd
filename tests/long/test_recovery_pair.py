"""The recovery table's pair case through the user's path (tests/test_recovery.py's PAIR): two effects hidden at
once, both in other forms than the catalog's, at 100 Hz; the same conclusion under what another machine can
perturb. About 2.5 minutes on this 2-core machine, so outside `make test`: `make acceptance`."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/ (recovery_table, test_recovery)
from test_recovery import PAIR, check_case  # noqa: E402


def test_two_hidden_effects_through_the_users_path(tmp_path):
    check_case(PAIR, tmp_path)
