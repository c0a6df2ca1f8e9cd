"""How the suite's workers spent their time: ``DAQ_TEST_TIMELINE=/tmp/t.tsv make test``, then
``python tests/timeline.py /tmp/t.tsv [BASELINE.tsv]``. Prints, per worker, its files in the order it ran them (start,
seconds), and when each worker finished: the gap between the two is what a better RUN_FIRST order (conftest.py) can
win. Then the CPU by file, the costliest first (the suite is compute-bound: a cut shows there, not in a file's wall
time beside another), and with a BASELINE timeline (another commit, or the same on another machine) each file's
ratio to it and the whole suite's: what a change saved, measured in the same units.
"""

from __future__ import annotations

import sys
from collections import defaultdict


def spans(lines: list[str]) -> dict[str, list[tuple[str, float, float]]]:
    """worker -> [(file, start, end)] in run order, times from the suite's first start."""
    rows = [ln.rstrip("\n").split("\t") for ln in lines if ln.strip()]
    t0 = min(float(r[1]) for r in rows)
    out: dict[str, list[tuple[str, float, float]]] = defaultdict(list)
    for worker, start, end, nodeid, *_ in sorted(rows, key=lambda r: float(r[1])):
        file = nodeid.split("::")[0].split("/")[-1]
        runs = out[worker]
        if runs and runs[-1][0] == file:
            runs[-1] = (file, runs[-1][1], float(end) - t0)
        else:
            runs.append((file, float(start) - t0, float(end) - t0))
    return out


def cpu_by_file(lines: list[str]) -> dict[str, float]:
    """file -> CPU seconds of its tests (the worker's own and its reaped children's); lines written before the CPU
    columns existed count nothing."""
    out: dict[str, float] = defaultdict(float)
    for ln in lines:
        r = ln.rstrip("\n").split("\t")
        if len(r) >= 6:
            out[r[3].split("::")[0].split("/")[-1]] += float(r[4]) + float(r[5])
    return dict(out)


def cpu_table(cpu: dict[str, float], base: dict[str, float] | None = None, top: int = 25) -> list[str]:
    """The costliest files first and the suite's total, each with its ratio to ``base`` where given."""
    def ratio(now: float, before: float | None) -> str:
        return f"  {now / before:5.2f}x" if before else ""

    base = base or {}
    lines = [f"  {sec:7.1f} s{ratio(sec, base.get(file))}  {file}"
             for file, sec in sorted(cpu.items(), key=lambda kv: -kv[1])[:top]]
    total, total_base = sum(cpu.values()), sum(base.values())
    lines.append(f"  {total:7.1f} s{ratio(total, total_base)}  all {len(cpu)} files")
    return lines


def main(path: str, baseline: str | None = None) -> None:
    with open(path, encoding="utf-8") as f:
        lines = f.readlines()
    by_worker = spans(lines)
    for worker, runs in sorted(by_worker.items()):
        print(f"{worker}: ends at {runs[-1][2]:.0f} s")
        for file, start, end in runs:
            if end - start >= 5.0:
                print(f"  {start:6.0f} s  {end - start:6.1f} s  {file}")
    cpu = cpu_by_file(lines)
    if cpu:
        base = None
        if baseline:
            with open(baseline, encoding="utf-8") as f:
                base = cpu_by_file(f.readlines())
        print("CPU by file" + (f" (ratio to {baseline})" if base else ""))
        print("\n".join(cpu_table(cpu, base)))


if __name__ == "__main__":
    main(*sys.argv[1:3])
