"""``daq bench archive``: records per minute re-diagnosed through the serial path and through Dask, same records.

The same RECORDS brake-2dof recordings (RECORD_S s each at 100 Hz, nothing hidden, different noise seeds) are
catalogued once and diagnosed three times in this run, each by a fresh `daq archive diagnose` process into its own
fresh catalog (nothing cached), as a user runs it:

- serial: ``--serial``, one recording after the other in that process (the baseline);
- Dask, 1 worker: ``--workers 1``, a LocalCluster with one single-threaded worker process (the same entry point);
- Dask, 2 workers: ``--workers 2``.

Each figure is the command's wall time: every path pays its process start, imports and numba cache loads; Dask
also the cluster's start and stop (its workers are forked from the job's process once it has warmed the kernels:
archive_jobs.START_METHOD), what its scheduler and workers do beside the diagnoses, and the results' trip back
(``dask_fixed_s``: the 1-worker job's time over the serial one's). The results must be equal on all three paths (``equal``). The numba cache is warm before
the first timing (the first path would otherwise pay the compiles). All three commands run under the environment
a LocalCluster's nanny gives its workers (``archive_jobs.WORKER_ENV``: one BLAS/OpenMP thread, glibc's trim
threshold), so the serial path computes under the same settings as a worker does.

Decision records: docs/decisions/0013-benchmarks-beside-same-run-baselines.md, docs/decisions/0033-archive-on-dask.md.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from daq.config import load_rig
from daq.io.archive import Catalog
from daq.io.interchange import write_recording
from daq.models.archive.jobs import WORKER_ENV, warm_numba
from daq.models.spec import save_model, seed_model
from daq.sim.run import simulate

RIG = "brake-2dof"
RECORDS = 10
RECORD_S = 30.0
RATE_HZ = 100.0
LIST_ROWS = 10_000


def _say(msg: str) -> None:
    print(f"  {msg}", file=sys.stderr, flush=True)


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _job(folder: Path, catalog: Path, model: Path, *flags: str) -> tuple[list[dict], float, float]:
    """One `daq archive diagnose` process over a fresh catalog of ``folder``: its JSON rows, its wall time and the
    CPU time it and its workers used (what another load on the machine does not inflate, as it does wall time)."""
    with Catalog(catalog) as cat:
        cat.scan(folder)
    cmd = [sys.executable, "-m", "daq.cli.main", "archive", "diagnose", "--catalog", str(catalog), "--model",
           str(model), "--json", *flags]
    t0, c0 = time.perf_counter(), _cpu_children()
    done = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=None, text=True, check=True,
                          env={**os.environ, **WORKER_ENV})
    return json.loads(done.stdout), time.perf_counter() - t0, _cpu_children() - c0


def _listing(tmp: Path, n: int = LIST_ROWS) -> tuple[float, float]:
    """Seconds to list a catalog of ``n`` rows: as rows in Python (``Catalog.rows``), and as the whole `daq archive
    list --json` command (the interpreter's start and imports included)."""
    path = tmp / "list.sqlite"
    with Catalog(path) as cat:
        with cat.transaction() as db:
            db.executemany(f"INSERT INTO recordings VALUES ({','.join('?' * 20)})", [
                (f"{i:064x}", f"/lab/runs/run-{i}.h5", f"run-{i}.h5", 10_000_000, 0, "belt-ndof", "0123456789",
                 f"2026-{1 + i % 12:02d}-01T00:00:00+00:00", 60.0, "seed", 2000.0, '{"laser": 2000.0}',
                 '["pad 3"]', '[{"t": 1.0, "kind": "note", "detail": "pad 3"}]', 1, "recorder",
                 "friction-daq run 1", 1, "t", "t") for i in range(n)])
        t0 = time.perf_counter()
        assert len(cat.rows()) == n
        t_rows = time.perf_counter() - t0
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "daq.cli.main", "archive", "list", "--json", "--catalog", str(path)],
                   stdout=subprocess.DEVNULL, check=True)
    return t_rows, time.perf_counter() - t0


def bench_archive(records: int = RECORDS, record_s: float = RECORD_S, progress=_say) -> dict:
    cfg = load_rig(RIG)
    with tempfile.TemporaryDirectory(prefix="daq-bench-archive-") as tmp:
        data, model = Path(tmp) / "data", Path(tmp) / "model.toml"
        data.mkdir()
        for i in range(records):
            write_recording(simulate(cfg, rate=RATE_HZ, seed=100 + i, duration=record_s), data / f"run-{i:02d}.h5")
        save_model(seed_model(RIG), model)
        list_rows_s, list_cli_s = _listing(Path(tmp))
        warm_numba(seed_model(RIG))
        load_before = os.getloadavg()[0]
        progress(f"{records} recordings of {RIG}, {record_s:g} s at {RATE_HZ:g} Hz; serial path")
        serial, t_serial, c_serial = _job(data, Path(tmp) / "serial.sqlite", model, "--serial")
        progress("Dask, LocalCluster with 1 worker")
        one, t_one, c_one = _job(data, Path(tmp) / "one.sqlite", model, "--workers", "1")
        progress("Dask, LocalCluster with 2 workers")
        two, t_two, c_two = _job(data, Path(tmp) / "two.sqlite", model, "--workers", "2")

    def same(a: list[dict], b: list[dict]) -> bool:
        keys = ("hash", "named", "undecided", "error", "noise_floor", "failure")
        return [[r[k] for k in keys] for r in a] == [[r[k] for k in keys] for r in b]

    def compute(rows: list[dict]) -> float:
        return sum(r["seconds"] or 0.0 for r in rows)

    return {
        "rig": RIG, "records": records, "record_s": record_s, "rate_Hz": RATE_HZ, "cores": os.cpu_count(),
        "serial_s": t_serial, "dask1_s": t_one, "dask2_s": t_two,
        "serial_per_min": 60 * records / t_serial, "dask1_per_min": 60 * records / t_one,
        "dask2_per_min": 60 * records / t_two,
        "dask1_cost": t_one / t_serial - 1.0,  # the share Dask with one worker adds to the serial path's time
        "dask2_speedup": t_serial / t_two,
        "dask_fixed_s": t_one - t_serial,  # cluster start, worker imports and cache loads, per job
        "serial_cpu_s": c_serial, "dask1_cpu_s": c_one, "dask2_cpu_s": c_two,
        "dask1_cpu_cost": c_one / c_serial - 1.0,
        "serial_compute_s": compute(serial), "dask1_compute_s": compute(one), "dask2_compute_s": compute(two),
        "equal": same(serial, one) and same(serial, two),
        "list_rows": LIST_ROWS, "list_rows_s": list_rows_s, "list_command_s": list_cli_s,
        "load_before": load_before, "load_after": os.getloadavg()[0],  # 1-minute load average: others' work too
        "named": sorted({n for r in serial for n in r["named"]}),
        "failed": sum(r["failure"] is not None for r in serial + one + two),
    }


def format_archive(r: dict) -> str:
    fixed = r["dask_fixed_s"]
    # records per job from which Dask's fixed cost is under 5 % of the serial path, by CPU time (wall time swings
    # with whatever else runs on the machine)
    cpu_fixed, cpu_per = r["dask1_cpu_s"] - r["serial_cpu_s"], r["serial_cpu_s"] / r["records"]
    at5 = max(cpu_fixed, 0.0) / (0.05 * cpu_per)
    per1, per2 = r["serial_compute_s"] / r["records"], r["dask2_compute_s"] / r["records"]
    cores_got = 2 * per1 / per2 if per2 > 0 else 0.0  # what two workers computed at once, in serial-path cores
    return "\n".join([
        f"benchmark archive: {r['records']} {r['rig']} recordings ({r['record_s']:g} s at {r['rate_Hz']:g} Hz), "
        f"re-diagnosed with the seed model on {r['cores']} cores; results equal on every path: {r['equal']}",
        f"  serial        {r['serial_s']:7.1f} s  {r['serial_per_min']:6.1f} records/min  (baseline: one after the "
        "other in this process)",
        f"  Dask 1 worker {r['dask1_s']:7.1f} s  {r['dask1_per_min']:6.1f} records/min  cost over serial "
        f"{r['dask1_cost']:+.1%} ({fixed:+.1f} s a job: the cluster's start and stop, its scheduler and worker beside "
        "the diagnoses, and any difference per record)",
        f"  Dask 2 workers{r['dask2_s']:7.1f} s  {r['dask2_per_min']:6.1f} records/min  {r['dask2_speedup']:.2f} x "
        "the serial rate",
        f"  CPU time      serial {r['serial_cpu_s']:.1f} s, Dask 1 worker {r['dask1_cpu_s']:.1f} s "
        f"({r['dask1_cpu_cost']:+.1%}), 2 workers {r['dask2_cpu_s']:.1f} s (each command with its workers: what "
        "another load on the machine does not inflate)",
        f"  listing       {r['list_rows']} rows in {r['list_rows_s']:.2f} s as rows (Catalog.rows); the whole "
        f"`daq archive list --json` command {r['list_command_s']:.2f} s (interpreter start and imports included)",
        f"  per record    serial {per1:.2f} s, on the 1 worker {r['dask1_compute_s'] / r['records']:.2f} s, on each "
        f"of 2 workers {per2:.2f} s (the diagnosis alone, as each path timed it); load average "
        f"{r['load_before']:.1f} before, {r['load_after']:.1f} after",
        f"  the 2-worker ratio: this machine has {r['cores']} cores, so two workers are all of it, shared with the "
        f"job's own process (scheduler, client, catalog writes), the OS and any other load; here the two together "
        f"computed as {cores_got:.2f} serial-path cores would (each record took {per2 / per1:.2f} x its serial "
        f"time), and the job's fixed cost and its tail (one worker idle while the other finishes the last record) "
        f"come on top. At best it is a little under 2 x. Dask's fixed cost is {cpu_fixed:.1f} CPU-s a job here, "
        f"under 5 % of the serial path's CPU time from about {at5:.0f} records of this size per job.",
    ])
