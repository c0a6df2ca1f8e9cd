"""How the suite's workers spent their time: ``DAQ_TEST_TIMELINE=/tmp/t.tsv make test``, then
``python tests/timeline.py /tmp/t.tsv``. Prints, per worker, its files in the order it ran them (start, seconds),
and when each worker finished: the gap between the two is what a better RUN_FIRST order (conftest.py) can win.
"""

from __future__ import annotations

import sys
from collections import defaultdict


def spans(lines: list[str]) -> dict[str, list[tuple[str, float, float]]]:
    """worker -> [(file, start, end)] in run order, times from the suite's first start."""
    rows = [ln.rstrip("\n").split("\t") for ln in lines if ln.strip()]
    t0 = min(float(r[1]) for r in rows)
    out: dict[str, list[tuple[str, float, float]]] = defaultdict(list)
    for worker, start, end, nodeid in sorted(rows, key=lambda r: float(r[1])):
        file = nodeid.split("::")[0].split("/")[-1]
        runs = out[worker]
        if runs and runs[-1][0] == file:
            runs[-1] = (file, runs[-1][1], float(end) - t0)
        else:
            runs.append((file, float(start) - t0, float(end) - t0))
    return out


def main(path: str) -> None:
    with open(path, encoding="utf-8") as f:
        by_worker = spans(f.readlines())
    for worker, runs in sorted(by_worker.items()):
        print(f"{worker}: ends at {runs[-1][2]:.0f} s")
        for file, start, end in runs:
            if end - start >= 5.0:
                print(f"  {start:6.0f} s  {end - start:6.1f} s  {file}")


if __name__ == "__main__":
    main(sys.argv[1])
