"""The recovery table's pair case through the user's path (tests/test_recovery.py's PAIR): two effects hidden at
once, both in other forms than the catalog's, at 100 Hz; the same conclusion under what another machine can
perturb. About 2.5 minutes on this 2-core machine, so outside `make test`: `make acceptance`.

Failed on 2026-11-29 morning at its last assertion (the perturbed diagnosis took the mass as its first step), for
two reasons mended that day: one held-out window of 28 fell into a poor basin from the data's start (255 um against
75 um from the base fit's start: the mass's held-out error 61 um in one run, 40 um in the other), and the measured
drive, a structural switch, was pushed out of the first step's pairs by a spring. Passes since (157 s); by hand the
same diagnosis had also differed from the test's because tests/recovery_table.py loaded numpy before daq pinned the
BLAS kernels."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/ (recovery_table, test_recovery)
from test_recovery import PAIR, check_case  # noqa: E402


def test_two_hidden_effects_through_the_users_path(tmp_path):
    check_case(PAIR, tmp_path)
