"""The recovery table's pair case through the user's path (tests/test_recovery.py's PAIR): two effects hidden at
once, both in other forms than the catalog's, at 100 Hz; the same conclusion under what another machine can
perturb. About 2.5 minutes on this 2-core machine, so outside `make test`: `make acceptance`.

**Fails on 2026-11-29 (4fb77d2, 142 s), at its last assertion:** the user's path passes, but the perturbed diagnosis
(tests/recovery_table.py, perturbed_diagnosis) concludes accel-sign (relative), belt-speed (measured), mechanics.m_kg
and stick-time (log) against the unperturbed accel-sign (body) + belt-speed (measured). Run by hand on the test's
saved files, the same perturbed diagnosis takes mechanics.m_kg as step 1 and ends with m_kg, belt-speed (measured)
and accel-sign (body), at 4fb77d2 and at 844603b alike: the mass first step is older than that day's changes, and
the test's own run disagrees with the run by hand on the same files (not yet explained)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/ (recovery_table, test_recovery)
from test_recovery import PAIR, check_case  # noqa: E402


def test_two_hidden_effects_through_the_users_path(tmp_path):
    check_case(PAIR, tmp_path)
