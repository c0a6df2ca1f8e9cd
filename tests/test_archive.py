"""Issue 28: the archive. A catalog of recordings (SQLite, WAL, keyed by content hash), results kept per (recording,
model, code version), and re-diagnosis on Dask distributed: a real scheduler and two workers on loopback, a worker
killed with SIGKILL mid-job, the same with the default LocalCluster, results equal to the serial path's.

The suite's set is SUITE (5 short recordings of two rigs, so that three paths of it fit the suite's budget); the
issue's 12 recordings run in tests/long/test_archive_full.py (`make acceptance`) through the same functions here.

Decision record: docs/decisions/0033-archive-on-dask.md.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import warnings
from collections.abc import Callable
from pathlib import Path

import h5py
import psutil
import pytest
from helpers import free_port, make_recordings

from daq.cli.main import main as daq
from daq.config import load_rig
from daq.io.archive import CATALOG_NAME, Catalog, describe_file, open_entry
from daq.io.interchange import write_recording
from daq.models.archive import jobs as archive_jobs
from daq.models.archive.jobs import DiagnoseRow, JobReport, match_models, run_diagnoses
from daq.models.spec import Model, seed_model
from daq.sim.run import simulate

VENV_BIN = Path(sys.executable).parent
# (rig, seconds, seed): short records at 100 Hz; a brake diagnosis ~1.5 s, a drum one ~5.5 s on one core
SUITE = [("brake-2dof", 6.0, s) for s in (1, 2, 3, 4)] + [("drum-pendulum", 4.0, 1)]


# --------------------------------------------------------------------------- helpers shared with tests/long


def models_for(spec: list[tuple[str, float, int]]) -> list[Model]:
    return [seed_model(rig) for rig in sorted({rig for rig, _, _ in spec})]


def job(catalog: Path, data: Path, models: list[Model], say=lambda m: None, **kw) -> JobReport:
    with Catalog(catalog) as cat:
        cat.scan(data)
        pairs = match_models(cat.rows(), models, say)
        return run_diagnoses(cat, pairs, say=say, **kw)


def verdicts(rep: JobReport) -> dict[str, tuple]:
    return {r.hash: (r.named, r.undecided, r.error, r.noise_floor, r.failure) for r in rep.rows}


def assert_same(a: dict[str, tuple], b: dict[str, tuple]) -> None:
    """The same conclusions, and the same figures to 1e-9 (a worker's BLAS may use another number of threads)."""
    assert a.keys() == b.keys()
    for h, mine in a.items():
        assert mine[0:2] == b[h][0:2] and mine[4] == b[h][4], (h, mine, b[h])
        for x, y in zip(mine[2:4], b[h][2:4]):
            assert x == pytest.approx(y, rel=1e-9), (h, mine, b[h])


def assert_each_once(catalog: Path, rep: JobReport, n: int) -> None:
    """Exactly one stored result per recording, each computed result stored once, nothing computed again after its
    result was stored (the scheduler's event log: no computation started after the store)."""
    assert len(rep.rows) == n and rep.failed == 0, [r.failure for r in rep.rows]
    db = sqlite3.connect(catalog)
    got = db.execute("SELECT hash, COUNT(*), MAX(computations) FROM results GROUP BY hash").fetchall()
    db.close()
    assert len(got) == n and all(c == 1 and k == 1 for _, c, k in got), got
    assert rep.after_stored == 0
    assert set(rep.runs) == {r.hash for r in rep.rows}


def killer(pids: Callable[[], list[int]], first_pid_of: Callable[[str], int]) -> tuple[Callable[[str], None], dict]:
    """A progress callback that SIGKILLs a worker once the second result is in: one that is *not* the worker that
    produced it (the other is inside a computation then: the job has more than two), so the kill lands mid-task."""
    state = {"killed": None}

    def say(msg: str) -> None:
        if state["killed"] is None and msg.startswith("[2/"):
            done_by = first_pid_of(msg)
            victim = next(p for p in pids() if p != done_by)
            os.kill(victim, signal.SIGKILL)
            state["killed"] = victim

    return say, state


def worker_pid(msg: str) -> int:
    return int(msg.rsplit(":", 1)[1].rstrip(")"))


def start_tcp_cluster() -> tuple[str, list[subprocess.Popen]]:
    """A real `dask scheduler` and two `dask worker` processes on loopback (no nanny: the process killed is the worker
    itself). Started before the serial reference runs, so that their start-up overlaps it."""
    port = free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    procs = [subprocess.Popen([str(VENV_BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)]
    for name in ("a", "b"):
        procs.append(subprocess.Popen([str(VENV_BIN / "dask"), "worker", addr, "--no-nanny", "--nthreads", "1",
                                       "--no-dashboard", "--name", name],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env))
    return addr, procs


def stop_processes(procs: list[subprocess.Popen]) -> None:
    """The workers first (SIGTERM), then the scheduler: a worker whose scheduler went first waits to reconnect."""
    for group in (procs[1:], procs[:1]):
        for p in group:
            if p.poll() is None:
                p.terminate()
        for p in group:
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def run_tcp_case(tmp: Path, data: Path, models: list[Model], serial: dict[str, tuple], addr: str,
                 procs: list[subprocess.Popen]) -> JobReport:
    """The job on the scheduler at ``addr`` with its two workers (``procs[1:]``); one worker SIGKILLed mid-job."""
    from distributed import Client

    with Client(addr, timeout=30) as c:
        c.wait_for_workers(2, timeout=60)
    workers = {p.pid for p in procs[1:]}
    say, state = killer(lambda: sorted(workers), worker_pid)
    rep = job(tmp / "tcp.sqlite", data, models, say=say, scheduler=addr)
    assert state["killed"] in workers
    assert next(p for p in procs if p.pid == state["killed"]).wait(5) == -signal.SIGKILL
    assert_each_once(tmp / "tcp.sqlite", rep, len(serial))
    assert_same(verdicts(rep), serial)
    assert rep.lost >= 1  # the kill hit a running computation, which was done again elsewhere
    return rep


def local_worker_pids() -> list[int]:
    """The LocalCluster's worker processes: this process's children that are copies of it (forked by the nannies,
    archive_jobs.START_METHOD) or, where fork does not exist, spawned ones."""
    me = psutil.Process()
    mine, out = me.cmdline(), []
    for p in me.children():
        try:
            cmd = p.cmdline()
            if cmd == mine or "spawn_main" in " ".join(cmd):
                out.append(p.pid)
        except psutil.Error:  # a process that ended meanwhile (a zombie, an earlier test's)
            pass
    return sorted(out)


def run_local_case(tmp: Path, data: Path, models: list[Model], serial: dict[str, tuple]) -> JobReport:
    """The default LocalCluster (two worker processes under their nannies); one worker SIGKILLed mid-job (its nanny
    starts a new one)."""
    say, state = killer(local_worker_pids, worker_pid)
    rep = job(tmp / "local.sqlite", data, models, say=say, workers=2)
    assert state["killed"] is not None
    assert rep.engine.startswith("LocalCluster")
    assert_each_once(tmp / "local.sqlite", rep, len(serial))
    assert_same(verdicts(rep), serial)
    return rep


# --------------------------------------------------------------------------- re-diagnosis


@pytest.fixture(scope="module")
def tcp_cluster():
    addr, procs = start_tcp_cluster()
    yield addr, procs
    stop_processes(procs)


@pytest.fixture(scope="module")
def suite_data(tmp_path_factory, tcp_cluster):
    tmp = tmp_path_factory.mktemp("archive")
    data = make_recordings(tmp / "data", SUITE)
    models = models_for(SUITE)
    serial = job(tmp / "serial.sqlite", data, models, serial=True)
    assert serial.engine == "serial" and serial.computed == len(SUITE) and serial.failed == 0
    return tmp, data, models, serial


@pytest.mark.slow
def test_dask_scheduler_and_two_workers_one_killed(suite_data, tcp_cluster):
    tmp, data, models, serial = suite_data
    rep = run_tcp_case(tmp, data, models, verdicts(serial), *tcp_cluster)
    assert rep.engine.startswith("tcp://127.0.0.1:") and rep.computed == len(SUITE)


@pytest.mark.slow
def test_local_cluster_one_worker_killed(suite_data, monkeypatch):
    """... and the job leaves the caller's environment as it found it: a LocalCluster's nannies set their workers'
    variables in this process's os.environ (MALLOC_TRIM_THRESHOLD_, one BLAS thread; again when one restarts a
    killed worker) and Dask never puts them back. With Dask's default HTTP port (8787) taken, as by another job on
    the machine, the job does not reach for it (Dask warned "Port 8787 is already in use" in every suite run)."""
    tmp, data, models, serial = suite_data
    monkeypatch.setenv("OMP_NUM_THREADS", "3")  # a caller's own value, kept
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)  # and one it does not have, not added
    mine = lambda: {k: v for k, v in os.environ.items() if k != "__DASK_PARENT_PID"}  # noqa: E731 - (Dask's
    before = mine()  # marker for its children's process titles: it changes nothing a process does)
    with contextlib.ExitStack() as held, warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        with contextlib.suppress(OSError):  # Dask's default HTTP port taken, as by another job on the machine
            held.enter_context(socket.create_server(("127.0.0.1", 8787)))
        run_local_case(tmp, data, models, verdicts(serial))
    assert mine() == before
    assert not [w for w in seen if "already in use" in str(w.message)], [str(w.message) for w in seen]


@pytest.mark.slow
def test_stored_results_are_returned_and_status_says_what_is_missing(suite_data, capsys):
    tmp, _, _, serial = suite_data
    cat = tmp / "serial.sqlite"
    m = tmp / "brake.toml"
    assert daq(["model", "init", "brake-2dof", "-o", str(m)]) == 0
    capsys.readouterr()
    assert daq(["archive", "diagnose", "--catalog", str(cat), "--model", str(m), "--json"]) == 0
    rows = [DiagnoseRow(**r) for r in json.loads(capsys.readouterr().out)]
    assert len(rows) == 4 and all(r.cached for r in rows)  # the brake ones, from the serial job: nothing computed
    assert {r.hash: (r.named, r.undecided) for r in rows} == {h: v[:2] for h, v in verdicts(serial).items() if h in
                                                              {r.hash for r in rows}}
    assert set(json.loads(json.dumps(rows[0].model_dump()))) >= {"path", "hash", "model_digest", "named", "undecided",
                                                                 "error", "noise_floor", "cached"}
    assert daq(["archive", "status", "--catalog", str(cat), "--model", str(m), "--json"]) == 0
    st = json.loads(capsys.readouterr().out)["models"][0]
    assert (st["recordings"], st["diagnosed"], st["not_diagnosed"]) == (4, 4, [])
    changed = seed_model("brake-2dof").with_values({"friction.mu0": 0.3})
    with Catalog(cat) as c:
        assert archive_jobs.status(c, c.rows(), [changed])["models"][0]["diagnosed"] == 0


@pytest.mark.slow
def test_a_job_killed_resumes_without_redoing_finished_work(suite_data):
    tmp, data, models, serial = suite_data
    brake = [m for m in models if m.rig == "brake-2dof"]
    cat = tmp / "resume.sqlite"
    with Catalog(tmp / "serial.sqlite") as done, Catalog(cat) as c:  # a job killed after storing all but one result
        c.scan(data)
        rows = [r for r in c.rows() if r.rig == "brake-2dof"]
        for r in rows[:-1]:
            got = done.result(r.hash, brake[0].digest(), archive_jobs.CODE_VERSION, archive_jobs.KIND)
            c.store_result(r.hash, got.model_digest, got.code_version, got.kind, got.result, got.seconds, got.worker)
    rep = job(cat, data, brake, serial=True)
    assert (rep.cached, rep.computed) == (len(rows) - 1, 1)
    assert_same(verdicts(rep), {h: v for h, v in verdicts(serial).items() if h in {r.hash for r in rows}})


# --------------------------------------------------------------------------- the catalog


def tiny_copies(folder: Path, n: int) -> list[Path]:
    """``n`` recordings with different bytes: one short simulation, each copy with its own attribute."""
    folder.mkdir(parents=True, exist_ok=True)
    base = folder / "base.h5"
    write_recording(simulate(load_rig("brake-2dof"), rate=100.0, seed=1, duration=0.5), base)
    out = []
    raw = base.read_bytes()
    for i in range(n):
        p = folder / f"run-{i:03d}.h5"
        p.write_bytes(raw)
        with h5py.File(p, "a") as f:
            f.attrs["copy"] = i
        out.append(p)
    base.unlink()
    return out


@pytest.mark.slow
def test_scan_200_files_a_damaged_one_a_rename_and_two_scans_at_once(tmp_path, capsys):
    files = tiny_copies(tmp_path / "runs", 200)
    (tmp_path / "runs" / "damaged.h5").write_bytes(files[0].read_bytes()[:3000])  # cut short by a full disk
    assert daq(["archive", "scan", str(tmp_path / "runs")]) == 0
    err = capsys.readouterr().err
    assert [line for line in err.splitlines() if "damaged.h5" in line] == [line for line in err.splitlines()
                                                                            if "skipped" in line]
    assert sum("damaged.h5" in line for line in err.splitlines()) == 1
    cat = tmp_path / "runs" / CATALOG_NAME
    with Catalog(cat) as c:
        assert c.count() == 200
        moved = c.get(str(files[7]))
    assert sqlite3.connect(cat).execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    # a file renamed (and moved into a sub-folder) between scans: the same row, found by its hash
    (tmp_path / "runs" / "2025").mkdir()
    new = files[7].rename(tmp_path / "runs" / "2025" / "renamed.h5")
    assert daq(["archive", "scan", str(tmp_path / "runs"), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert (rep["added"], rep["moved"], rep["unchanged"], rep["recordings"]) == (0, 1, 199, 200)
    with Catalog(cat) as c:
        again = c.get(moved.hash)
        assert again.path == str(new.resolve()) and again.present
    # two scans at once of a fresh catalog: no duplicate row, no lock error
    fresh = tmp_path / "fresh.sqlite"
    cmd = [str(VENV_BIN / "daq"), "archive", "scan", str(tmp_path / "runs"), "--catalog", str(fresh)]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outs = [p.communicate(timeout=120) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    for _, e in outs:
        assert "locked" not in e and "Traceback" not in e and sum("damaged.h5" in ln for ln in e.splitlines()) == 1
    db = sqlite3.connect(fresh)
    assert db.execute("SELECT COUNT(*), COUNT(DISTINCT path) FROM recordings").fetchone() == (200, 200)


def test_list_filters_and_10000_rows(tmp_path, capsys):
    tiny_copies(tmp_path / "runs", 3)
    cat = tmp_path / "cat.sqlite"
    with Catalog(cat) as c:
        c.scan(tmp_path / "runs")
        row = c.rows()[0]
        fake = [(f"{i:064x}", f"/nowhere/run-{i}.h5", f"run-{i}.h5", 1000, 0, "belt-ndof" if i % 2 else "drum-pendulum",
                 "abc", f"2026-{1 + i % 12:02d}-01T00:00:00+00:00", 60.0, "seed" if i % 3 else "file", 250.0,
                 "{}", "[]", "[]", 0, "recorder", "friction-daq run 1", 1, "t", "t") for i in range(10_000)]
        with c.transaction() as db:
            db.executemany(f"INSERT INTO recordings VALUES ({','.join('?' * 20)})", fake)
        assert len(c.rows()) == 10_003
        belt = c.rows(rig="belt-ndof", since="2026-11-01", where=["ramp=seed"])
        assert belt and all(r.rig == "belt-ndof" and r.start >= "2026-11-01" and r.ramp == "seed" for r in belt)
        assert len(c.rows(where=["rate_hz=250", "ramp~fil"])) == sum(1 for i in range(10_000) if i % 3 == 0)
    assert daq(["archive", "list", "--catalog", str(cat), "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert len(listed) == 10_003 and {"path", "hash", "rig", "start", "duration_s", "ramp"} <= set(listed[0])
    assert daq(["archive", "list", "--catalog", str(cat), "--rig", "brake-2dof"]) == 0
    assert capsys.readouterr().out.count("run-") == 3
    # a row opened as data, read only when asked for
    entry = open_entry(row.hash[:10], catalog=cat, as_="entry")
    assert entry._rec is None
    assert entry.recording().rig == "brake-2dof"
    assert list(open_entry(row.path, catalog=cat, as_="pandas").columns)[:1]
    assert "x1" in open_entry(row.hash, catalog=cat, as_="xarray")


@pytest.mark.parametrize("args,field", [
    (["list", "--where", "ramp"], "ramp"),
    (["list", "--where", "colour=red"], "colour"),
    (["list", "--where", "rate_hz=fast"], "rate_hz"),
    (["list", "--since", "last tuesday"], "last tuesday"),
    (["status", "--model", "{model}"], "(syntax)"),
    (["diagnose", "--model", "{ok}", "--scheduler", "tcp://127.0.0.1:{port}"], "tcp://127.0.0.1:{port}"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, monkeypatch, args, field):
    tiny_copies(tmp_path / "runs", 1)
    cat = tmp_path / "cat.sqlite"
    with Catalog(cat) as c:
        c.scan(tmp_path / "runs")
    (tmp_path / "bad.toml").write_text("rig = \n")
    assert daq(["model", "init", "brake-2dof", "-o", str(tmp_path / "ok.toml")]) == 0
    monkeypatch.setattr(archive_jobs, "CONNECT_S", 1.0)
    monkeypatch.setattr(archive_jobs, "warm_numba", lambda m: None)
    port = free_port()
    sub = {"{model}": str(tmp_path / "bad.toml"), "{ok}": str(tmp_path / "ok.toml"), "{port}": str(port)}
    args = [a.replace("{port}", str(port)) if "{port}" in a else sub.get(a, a) for a in args]
    capsys.readouterr()
    assert daq(["archive", *args, "--catalog", str(cat)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 or "archive diagnose:" in err[0], err
    line = err[-1]
    assert line.startswith("daq: error: ") and f": {field.replace('{port}', str(port))}: " in line, line


def test_import_and_recorder_files_get_a_row_and_a_broken_catalog_is_a_warning(tmp_path, capsys, monkeypatch):
    rec = simulate(load_rig("brake-2dof"), rate=100.0, seed=2, duration=0.5)
    write_recording(rec, tmp_path / "in.csv")
    out = tmp_path / "lab" / "imported.h5"
    assert daq(["import", str(tmp_path / "in.csv"), "--rig", "brake-2dof", "-o", str(out)]) == 0
    with Catalog(tmp_path / "lab" / CATALOG_NAME) as c:
        (row,) = c.rows()
    assert row.path == str(out.resolve()) and row.source == "import" and row.rig == "brake-2dof"
    assert describe_file(out)["rig"] == "brake-2dof"
    (tmp_path / "not-a-db").mkdir()
    monkeypatch.setenv("DAQ_ARCHIVE", str(tmp_path / "not-a-db"))  # a catalog that cannot be opened
    capsys.readouterr()
    assert daq(["import", str(tmp_path / "in.csv"), "--rig", "brake-2dof", "-o", str(tmp_path / "b.h5")]) == 0
    err = capsys.readouterr().err
    assert (tmp_path / "b.h5").is_file()
    assert next(line for line in err.splitlines() if "warning" in line).startswith(f"warning: {tmp_path / 'b.h5'} not")
