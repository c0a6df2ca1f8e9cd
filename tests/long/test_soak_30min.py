"""Issue 29's soak at full length: `daq soak --minutes 30 --record-every 10` (the daemon with its page, two viewers,
one of them stalled, three recordings, ramps one after the other) must show flat memory, every stream at its rate
and nothing lost. About 31 minutes, so it runs under `make acceptance`, not in the suite (tests/test_soak.py runs
half a minute of the same).

Flat: for every process that runs on a rig (the daemon, its estimator, web page and each recorder), the upper end
of its RSS slope's 95 % interval, after its first 3 minutes, is below 0.25 MB/min. Why that threshold: 0.25 MB/min
is 360 MB a day, so a daemon restarted once a day stays well within a rig PC's memory. It is a quarter of the
~1 MB/min that issue 29's 10-minute soak saw, and 5-10 times the bound's half-width in 27 minutes of correlated
samples (0.01-0.08 MB/min measured). A week of unattended running would need about 0.05 MB/min, which takes a
24-hour soak to resolve. The simulated bench stands in for the instruments and is reported, not judged: its
test-oracle logs (the serial stream's last 200 000 frames, the thermocouple's last 100 000 answers) are bounded
and fill over 3 minutes and 2.8 hours.

Run on 2026-11-27 on an otherwise idle 2-core machine: **passes** (1814 s). Slopes ± 95 % bound [MB/min]: daemon
+0.130 ± 0.042, estimator +0.003 ± 0.001, web +0.077 ± 0.008, recorders +0.007 to +0.011; the simulated bench
+0.199 ± 0.044 (not judged). While two other jobs kept both cores busy the memory held flat too, but the motor stream
ran at 95.4 Hz of 100 and the test failed on that (docs/daemon.md, "Soak").
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FLAT_MB_PER_MIN = 0.25
ON_A_RIG = ("daemon", "estimator", "web", "recorder")


def test_thirty_minutes_flat_memory_every_stream_at_its_rate_nothing_lost(tmp_path):
    out = tmp_path / "soak"
    r = subprocess.run([sys.executable, "-m", "daq.cli", "soak", "--minutes", "30", "--record-every", "10", "--json",
                        "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=45 * 60, check=False)
    assert r.returncode == 0, r.stderr[-3000:]
    res = json.loads(r.stdout)
    print("\n".join(f"{p['role']:10s} {p['first_mb']:7.1f} -> {p['last_mb']:7.1f} MB  "
                    f"{p['slope_mb_per_min']:+.4f} ± {p['bound_mb_per_min']:.4f} MB/min" for p in res["processes"]))
    roles = [p["role"] for p in res["processes"]]
    assert {"daemon", "estimator", "web", "sim bench"} <= set(roles) and roles.count("recorder") == 3, roles
    growing = [f"{p['role']} pid {p['pid']}: {p['slope_mb_per_min'] + p['bound_mb_per_min']:.3f} MB/min"
               for p in res["processes"] if p["role"] in ON_A_RIG
               and p["slope_mb_per_min"] + p["bound_mb_per_min"] >= FLAT_MB_PER_MIN]
    assert not growing, f"not flat at the 95 % bound (limit {FLAT_MB_PER_MIN} MB/min): {growing}"
    for s in res["streams"]:
        assert s["nominal_hz"] and abs(s["ratio"] - 1) < 0.02, s  # over 30 min: within 2 % of nominal
    assert res["lost_total"] == 0, res["lost"]
    assert len(res["recordings"]) == 3 and all(x["closed_cleanly"] and x["lost_blocks"] == 0 for x in res["recordings"])
    assert res["stalled_viewer"]["connected_to_the_end"] and res["viewer"]["frames"] > 10_000
    assert res["tracebacks"] == 0 and res["daemon_exit"] is None
