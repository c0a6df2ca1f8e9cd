"""Re-diagnosing an archive: every catalogued recording against a model, on Dask distributed, results kept.

The same job compares or fits instead (``kind``: "diagnose", "compare", "fit"; `daq archive diagnose|compare|fit`):
each kind's result is stored under its own key, so a recording compared with a model is not yet diagnosed with it.

Why Dask distributed (decision 33): labs already run batch reprocessing on existing engines, and
``distributed.Client`` is the same code path for a ``LocalCluster`` on this machine (the default: no server to run)
and for a lab's cluster (``--scheduler tcp://HOST:PORT``); it reschedules the work of a lost worker by itself.
What this module adds around it:

- the entry point handed to workers is :func:`analyse_recording` (:func:`diagnose_recording` for the diagnosis), a
  plain Python function of this module, never a numba function (those kill workers when pickled:
  dask/distributed#7929); it runs the same ``diagnose`` as `daq diagnose` (with one process per recording,
  ``workers=1``: Dask is the parallelism), the same fit and comparison as `daq fit` and `daq compare`;
- the numba cache is warmed once, in this process, before anything fans out: workers starting together would
  otherwise compile the same kernels at once and race on the cache files (numba#4807);
- every result is stored in the catalog the moment it arrives, in its own transaction, and its future released, so a
  job killed at any point resumes without redoing finished work, and a worker lost after a result was stored cannot
  make the scheduler compute it again; a task lost with its worker is resubmitted (RESUBMIT times);
- progress for the whole job on stderr; the workers log each computation's start and end to the scheduler's event
  log (topic ``daq-archive``), which is how a job counts what was computed where (and whether anything was computed
  again after its result was stored).

Results are keyed by (recording hash, model digest, code version, kind); the code version is the package's plus the
kind's revision (:func:`code_version`): asked again, a stored result is returned (``cached``); ``recompute`` ignores
them.
"""

from __future__ import annotations

import importlib.metadata
import logging
import multiprocessing
import os
import socket
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from typing import Any

import dask
import distributed
from distributed import Client, LocalCluster, as_completed
from pydantic import Field

from daq.errors import DaqError, InputError, NumericalFailure
from daq.io.archive import Catalog, CatalogRow, file_hash
from daq.sim.run import simulate
from daq.strict import Strict

from ..diagnosis.compare import compare
from ..diagnosis.diagnose import diagnose
from ..diagnosis.report import diagnosis_json
from ..fit.linalg import FAILURES
from ..fit.session import Fitted, Session
from ..spec import Model, dumps, rig_config_for

KIND = "diagnose"  # the default kind of result, and the one `daq archive status` lists by default
# each kind's revision: raise it when that analysis changes what it concludes, and its stored results no longer count
REVISIONS = {"diagnose": 1, "compare": 1, "fit": 1}
KINDS = tuple(REVISIONS)
DONE = {"diagnose": "diagnosed", "compare": "compared", "fit": "fitted"}  # how status names a kind's results
RESULTS_REVISION = REVISIONS[KIND]
try:
    _VERSION = importlib.metadata.version("friction-daq")
except importlib.metadata.PackageNotFoundError:  # a source tree without the package installed
    _VERSION = "0"


def code_version(kind: str = KIND) -> str:
    """The version a result of ``kind`` is stored under: the package's, and the kind's revision."""
    return f"{_VERSION}+{kind}.{REVISIONS[kind]}"


CODE_VERSION = code_version(KIND)
EVENT_TOPIC = "daq-archive"
RESUBMIT = 2  # a task whose worker died (KilledWorker after the scheduler's own retries) is submitted again this often
CONNECT_S = 5.0  # an unreachable scheduler is an error after this long
WARM_S = 3.0  # seconds of a simulated record the numba warm-up fits
# What a LocalCluster's workers (and its scheduler and nannies, in the job's process) run with (decision 33, "Dask
# with one worker within 5 % of serial"). A worker runs its task in a thread while its event loop keeps waking, and
# each wake takes the GIL from the task: the statistical profiler samples the task's stack every 10 ms, the loop's
# health check ticks every 20 ms, the host monitor polls every 500 ms, the memory monitor every 100 ms. Measured on
# the brake bench's diagnoses (per-thread schedstat, 6 records, a loaded machine): with Dask's defaults the task
# thread waited for the GIL 3.0-9.4 % of its compute time and the loop used 6-7 % as much CPU again; without the
# first three 0.5-2.8 % and 1.3-2.3 %. What the cluster costs while nothing runs, job process and worker (30 s idle):
# 5.1 % of a core with the defaults, 2.1 % without the first three, 1.1 % with the memory monitors (the worker's
# and its nanny's) every second; a cost that grows with a job's wall time on a loaded machine. Nothing here draws a
# dashboard (dashboard_address=None); a diagnosis's memory is small, so checking it every second is enough.
# The environment is Dask's own default, chosen here on purpose rather than inherited: one BLAS/OpenMP thread a worker
# (Dask is the parallelism: a worker a core, no oversubscription) and glibc returning freed memory early (the
# nanny's memory limits read the process's RSS). The bench runs the serial path under the same environment.
# Without a dashboard the scheduler still serves its health routes over HTTP, on 8787 unless told: a second job on the
# machine (or the suite's other worker) found it taken and Dask warned "Port 8787 is already in use" before moving to
# a random port. Told a free loopback port, the routes stay off the network and two jobs never meet (the dashboard
# stays off: LocalCluster passes dashboard=False with dashboard_address=None, and these options come after).
SCHEDULER_HTTP = {"dashboard_address": "127.0.0.1:0"}
WORKER_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
              "MALLOC_TRIM_THRESHOLD_": "65536"}
WORKER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.nanny.pre-spawn-environ": WORKER_ENV,
}
# How a LocalCluster's nannies start its workers: by fork, from this process after it warmed the numba cache, so a
# worker starts with this process's imports and compiled kernels (ready in ~0.5 s) instead of a new interpreter that
# imports everything and loads every kernel again (2-4 s, and 1-2 s more on its first record): on a job of ten
# records that start was most of what Dask with one worker cost over the serial path (decision 33). Safe here
# because a forked worker touches nothing this process holds open (the catalog's SQLite connection, a pytest
# worker's sockets): it reads its recording from its path and sends its result back over its own connection; numba
# runs no threads of its own (no parallel kernels), and a nanny that restarts a lost worker forks again from the same
# process. Where fork does not exist, spawn. A lab's own workers (--scheduler) start as the lab starts them.
START_METHOD = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
LOCAL_CONFIG = {**WORKER_CONFIG, "distributed.worker.multiprocessing-method": START_METHOD}


class DiagnoseRow(Strict):
    """One recording's answer (`daq archive diagnose --json` prints a list of these)."""

    path: str
    hash: str
    model_digest: str
    named: list[str]  # the effects named, in order
    undecided: list[list[str]]  # each "undecided between A and B" as [A, B, ...]
    error: float | None  # the model's error on held-out windows (as `daq diagnose`'s "error")
    error_unit: str | None
    noise_floor: float | None
    cached: bool  # the stored result was returned, nothing computed
    failure: str | None = None  # why the recording could not be diagnosed (one line naming file and field)
    seconds: float | None = None  # of the computation (the stored one's, when cached)
    worker: str | None = None


class ResultRow(Strict):
    """One recording's compare or fit answer (`daq archive compare --json`, `daq archive fit --json`)."""

    path: str
    hash: str
    model_digest: str
    kind: str  # compare | fit
    error: float | None  # the model's error on held-out windows (as `daq compare`'s and `daq fit`'s "error")
    error_unit: str | None
    noise_floor: float | None  # compare's; None for a fit (it computes no floor)
    cached: bool  # the stored result was returned, nothing computed
    failure: str | None = None
    seconds: float | None = None
    worker: str | None = None
    # the stored answer: `daq compare --json`'s fields; for a fit its parameters, convergence and the fitted model's
    # TOML (``fitted_model``); None when the recording failed
    result: dict[str, Any] | None = None


class JobReport(Strict):
    """A whole job: its rows, where it ran, and the counts the fault tests read."""

    rows: list[DiagnoseRow | ResultRow]
    kind: str = KIND
    engine: str  # serial | LocalCluster (N workers) | the scheduler's address
    computed: int
    cached: int
    failed: int
    seconds: float
    resubmitted: int = 0  # tasks submitted again after their worker died
    runs: dict[str, int] = Field(default_factory=dict)  # per hash: computations that finished on a worker (the scheduler's event log)
    after_stored: int = 0  # computations that started after that recording's result was stored (should be 0)
    lost: int = 0  # computations started on a worker that never finished there (the worker died under them)


# --------------------------------------------------------------------------- the entry point on a worker


def _log(msg: dict[str, Any]) -> None:
    """To the scheduler's event log when on a Dask worker (the job counts computations from it); nothing else."""
    try:
        distributed.get_worker().log_event(EVENT_TOPIC, msg)
    except ValueError:  # not on a worker: the serial path
        pass


def fit_json(session: Session, fitted: Fitted) -> dict[str, Any]:
    """A fit's answer as `daq fit --json` gives it (the error on held-out and on all windows, each parameter's value
    and std, convergence), with the fitted model itself as TOML (``fitted_model``), so a stored fit is a model."""
    primary = session.primary
    return {"error": fitted.rms(primary), "error_unit": session.m.units[primary],
            "error_all_windows": fitted.rms(primary, "all"),
            "parameters": {k: {"value": fitted.values[k], "std": fitted.fit.std.get(k)}
                           for k in fitted.model.free_names()},
            "converged": fitted.fit.success, "message": fitted.fit.message, "cost": fitted.fit.cost,
            "fitted_model": dumps(fitted.model), "fitted_digest": fitted.model.digest()}


def _compare(s: Session, model: Model) -> dict[str, Any]:
    f = s.fit(model)
    return compare(s, f, s.noise_floor(f))[0]  # the JSON; the figures' arrays are not a result to keep


ANALYSES: dict[str, Callable[[Session, Model], dict[str, Any]]] = {
    "diagnose": lambda s, model: diagnosis_json(diagnose(s, model, workers=1), s),
    "compare": _compare,
    "fit": lambda s, model: fit_json(s, s.fit(model)),
}


def analyse_recording(path: str, digest: str, model: Model, kind: str = KIND) -> dict[str, Any]:
    """Diagnose (compare, fit) one recording with ``model``: a plain function of a module, so any worker can import
    it. Bad input (a damaged file, a file changed since it was catalogued, a recording of another rig) is a
    ``failure`` line in the answer, not an exception: one bad recording must not cost the others their results."""
    t0 = time.time()
    _log({"hash": digest, "phase": "start", "t": t0, "pid": os.getpid()})
    result, failure = None, None
    try:
        if file_hash(path) != digest:
            raise InputError(path, "(file)", "changed since it was catalogued: `daq archive scan` it again")
        result = ANALYSES[kind](Session.open(path, model), model)
    except NumericalFailure as exc:  # good input a fit could not carry through: stored as failed, with why
        failure = f"{path}: ({kind}): the fit failed: {exc}"
    except (DaqError, OSError) as exc:
        failure = str(exc) if isinstance(exc, DaqError) else f"{path}: (file): {exc}"
    except Exception as exc:  # noqa: BLE001 - a numerical failure on one record is reported, the job goes on
        failure = f"{path}: ({kind}): {type(exc).__name__}: {exc}"
    t1 = time.time()
    _log({"hash": digest, "phase": "done", "t0": t0, "t": t1, "pid": os.getpid()})
    return {"hash": digest, "result": result, "failure": failure, "seconds": t1 - t0,
            "worker": f"{socket.gethostname()}:{os.getpid()}"}


def diagnose_recording(path: str, digest: str, model: Model) -> dict[str, Any]:
    """Diagnose one recording with ``model`` (:func:`analyse_recording` of the diagnosis)."""
    return analyse_recording(path, digest, model, "diagnose")


def warm_numba(model: Model) -> None:
    """Compile (or load from the on-disk cache) the kernels a diagnosis of ``model`` runs, in this process, before
    any worker starts on them: simultaneous first compiles race on the cache files (numba#4807)."""
    cfg = rig_config_for(model)
    rec = simulate(cfg, duration=WARM_S, rate=100.0, seed=0)
    try:
        Session(rec, "numba warm-up", cfg).fit(model)
    except FAILURES:  # the kernels are compiled by then; the records' own fits say whether this model fits (decision 50)
        pass


# --------------------------------------------------------------------------- rows and their results


def _row(rec: CatalogRow, model_digest: str, stored: dict[str, Any], cached: bool,
         kind: str = KIND) -> DiagnoseRow | ResultRow:
    res, failure = stored.get("result"), stored.get("failure")
    if kind != "diagnose":
        return ResultRow(
            path=rec.path, hash=rec.hash, model_digest=model_digest, kind=kind, cached=cached, failure=failure,
            error=res.get("error") if res else None, error_unit=res.get("error_unit") if res else None,
            noise_floor=res.get("noise_floor") if res else None, seconds=stored.get("seconds"),
            worker=stored.get("worker"), result=res)
    return DiagnoseRow(
        path=rec.path, hash=rec.hash, model_digest=model_digest, cached=cached, failure=failure,
        named=list(res["named"]) if res else [],
        undecided=[list(u["between"]) for u in res["undecided"]] if res else [],
        error=res["error"] if res else None, error_unit=res["error_unit"] if res else None,
        noise_floor=res["noise_floor"] if res else None, seconds=stored.get("seconds"), worker=stored.get("worker"))


def match_models(rows: list[CatalogRow], models: list[Model], say: Callable[[str], None]) -> list[tuple[CatalogRow, Model]]:
    """Each recording with the model for its rig (one model per rig); recordings of a rig without one are named and
    left out."""
    by_rig: dict[str, Model] = {}
    for m in models:
        if m.rig in by_rig:
            raise InputError("--model", m.rig, "two models for one rig: give one per rig")
        by_rig[m.rig] = m
    out = [(r, by_rig[r.rig]) for r in rows if r.rig in by_rig]
    skipped: dict[str, int] = {}
    for r in rows:
        if r.rig not in by_rig:
            skipped[r.rig] = skipped.get(r.rig, 0) + 1
    for rig, n in skipped.items():
        say(f"{n} recording(s) of {rig} left out: no --model for that rig")
    return out


def status(cat: Catalog, rows: list[CatalogRow], models: list[Model]) -> dict[str, Any]:
    """For each model, of the recordings of its rig: how many have a stored result of each kind at this code version
    (``diagnosed``, ``compared``, ``fitted``) and which have none yet (``not_diagnosed``, ...)."""
    out: dict[str, Any] = {"code_version": CODE_VERSION, "code_versions": {k: code_version(k) for k in KINDS},
                           "models": []}
    for m in models:
        digest = m.digest()
        mine = [r for r in rows if r.rig == m.rig]
        entry: dict[str, Any] = {"model_digest": digest, "rig": m.rig, "model": m.describe(), "recordings": len(mine)}
        for kind in KINDS:
            have = cat.results(digest, code_version(kind), kind)
            entry[DONE[kind]] = sum(r.hash in have for r in mine)
            entry[f"not_{DONE[kind]}"] = [{"path": r.path, "hash": r.hash} for r in mine if r.hash not in have]
        out["models"].append(entry)
    return out


# --------------------------------------------------------------------------- the job


def _count(events: list[tuple[float, dict]], stored_at: dict[str, float],
           since: float) -> tuple[dict[str, int], int, int]:
    """From the workers' event log (this job's part: started at or after ``since``; a lab's scheduler keeps earlier
    jobs' too): computations finished per hash, those started after the hash's result was stored, and those started
    that never finished (their worker died)."""
    runs: dict[str, int] = {}
    started, finished = set(), set()
    after = 0
    for _, msg in events:
        if msg.get("t0", msg["t"]) < since:
            continue
        key = (msg["hash"], msg["pid"], msg.get("t0", msg["t"]))
        if msg.get("phase") == "start":
            started.add(key)
        elif msg.get("phase") == "done":
            finished.add(key)
            runs[msg["hash"]] = runs.get(msg["hash"], 0) + 1
            after += int(msg["hash"] in stored_at and msg["t0"] > stored_at[msg["hash"]])
    return runs, after, len(started - finished)


async def _preload() -> None:
    """Run on every worker at the start of a job, not waited for (``client.run`` takes that only for a coroutine):
    on a lab's worker unpickling it imports this module and with it the models (not the compiled kernels: those load
    on the first diagnosis, after this process warmed the cache); a forked LocalCluster worker has them already."""


def _close(client: Client | None, cluster: LocalCluster | None) -> None:
    if client is not None:
        client.close()
    if cluster is not None:
        cluster.close()
        _put_back(_CALLERS_ENVIRON)  # a nanny that restarted a lost worker set its variables here once more


# What a LocalCluster's nannies do to this process: each sets its workers' variables (WORKER_ENV, PYTHONHASHSEED) in
# os.environ before it spawns a worker, and never puts them back (distributed/nanny.py, WorkerProcess.start). A
# job run in a caller's process (a notebook, the test suite) then left MALLOC_TRIM_THRESHOLD_ and one BLAS thread to
# every process started after it (seen: the suite's check of glibc's default allocator failed once, in the xdist
# worker that had run the archive's tests first). The caller's values are kept here and put back.
_ENV_KEYS = (*WORKER_ENV, "PYTHONHASHSEED")
_CALLERS_ENVIRON: dict[str, str | None] = {}


def _put_back(saved: dict[str, str | None]) -> None:
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


def _connect(scheduler: str | None, workers: int | None) -> tuple[Client, LocalCluster | None, str]:
    """A client of the given scheduler, or of a LocalCluster started here: the one code path after this."""
    logging.getLogger("distributed").setLevel(logging.ERROR)  # our own progress lines say what happens
    if scheduler:
        try:
            return Client(scheduler, timeout=CONNECT_S), None, scheduler
        except Exception as exc:  # noqa: BLE001 - OSError, TimeoutError, ValueError for a malformed address ...
            raise InputError("--scheduler", scheduler, f"cannot reach a Dask scheduler there ({type(exc).__name__}: "
                                                       f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
    n = workers or os.cpu_count() or 1
    _CALLERS_ENVIRON.clear()
    _CALLERS_ENVIRON.update({k: os.environ.get(k) for k in _ENV_KEYS})
    try:  # under LOCAL_CONFIG (engine holds it for the cluster's life: a restarted worker starts as the first did)
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               scheduler_kwargs=SCHEDULER_HTTP, silence_logs=logging.ERROR)
    finally:
        _put_back(_CALLERS_ENVIRON)
    return Client(cluster), cluster, f"LocalCluster ({n} worker{'s' if n > 1 else ''})"


class Fanned:
    """What :func:`fan_out` yields for each task: its index, its result, or the error once resubmitting gave up."""

    def __init__(self, index: int, result: Any = None, error: BaseException | None = None) -> None:
        self.index, self.result, self.error = index, result, error


def fan_out(client: Client, fn: Callable[..., Any], tasks: list[tuple], names: list[str],
            say: Callable[[str], None], counter: dict[str, int] | None = None) -> Iterator[Fanned]:
    """Submit ``fn(*task)`` for every task (in the given order: put the longest first) and yield each as it finishes.
    The caller stores the result before asking for the next one: the future is released right after, so a worker
    lost later cannot make the scheduler compute it again. A task whose worker died under it more often than the
    scheduler allows (KilledWorker) is submitted again RESUBMIT times, then yielded with its error.
    ``counter["resubmitted"]`` counts those."""
    futures: dict[distributed.Future, tuple[int, int]] = {}
    for i, task in enumerate(tasks):
        futures[client.submit(fn, *task, key=f"{names[i]}-0", pure=False, retries=1)] = (i, 0)
    queue = as_completed(list(futures))
    for f in queue:
        i, attempt = futures.pop(f)
        try:
            out = Fanned(i, result=f.result())
        except Exception as exc:  # noqa: BLE001 - KilledWorker (its worker died too often), a lost task
            if attempt < RESUBMIT:
                if counter is not None:
                    counter["resubmitted"] = counter.get("resubmitted", 0) + 1
                say(f"{names[i]}: {type(exc).__name__} ({exc}); submitted again")
                g = client.submit(fn, *tasks[i], key=f"{names[i]}-{attempt + 1}", pure=False, retries=1)
                futures[g] = (i, attempt + 1)
                queue.add(g)
                continue
            out = Fanned(i, error=exc)
        finally:
            f.release()  # forgotten by the scheduler: a lost worker cannot make it compute this again
        yield out


@contextmanager
def engine(scheduler: str | None, workers: int | None) -> Iterator[tuple[Client, str]]:
    """A client of ``scheduler``, or of a LocalCluster of ``workers`` started here, closed after; with the engine's
    name. A lab's workers import this module (and the models) at once, while the caller warms the numba cache; a
    LocalCluster's are forked from this process (START_METHOD) with all of it loaded."""
    with ExitStack() as stack:
        if not scheduler:  # the nannies read it whenever they start a worker: at the start and after a lost one
            stack.enter_context(dask.config.set(LOCAL_CONFIG))
        client, cluster, name = _connect(scheduler, workers)
        try:
            client.run(_preload, wait=False)
            yield client, name
        finally:
            _close(client, cluster)


def verdict(row: DiagnoseRow | ResultRow) -> str:
    """A row's answer in a few words (a progress line, the table of `daq archive diagnose|compare|fit`)."""
    if row.failure:
        return f"failed: {row.failure}"
    if isinstance(row, DiagnoseRow):
        return ("named " + ", ".join(row.named) if row.named else "nothing named") + (
            "; undecided " + "; ".join(" / ".join(u) for u in row.undecided) if row.undecided else "")
    if row.error is None:
        return "no error figure"
    floor = f" (floor {row.noise_floor:.4g})" if row.noise_floor is not None else ""
    return f"error {row.error:.4g} {row.error_unit}{floor}"


def run_job(cat: Catalog, pairs: list[tuple[CatalogRow, Model]], *, kind: str = KIND, scheduler: str | None = None,
            workers: int | None = None, serial: bool = False, recompute: bool = False,
            say: Callable[[str], None] = lambda msg: None) -> JobReport:
    """Diagnose (``kind``: compare, fit) every (recording, model) pair without a stored result of that kind yet
    (all with ``recompute``), each result stored as it arrives; ``serial``: in this process, one after the other
    (the baseline the bench compares Dask with)."""
    if kind not in REVISIONS:
        raise InputError("--kind", kind, f"not one of {', '.join(KINDS)}")
    version = code_version(kind)
    t_start, wall_start = time.perf_counter(), time.time()
    digests = {id(m): m.digest() for _, m in pairs}
    answers: dict[str, DiagnoseRow | ResultRow] = {}
    todo: list[tuple[CatalogRow, Model]] = []
    for rec, m in pairs:
        stored = None if recompute else cat.result(rec.hash, digests[id(m)], version, kind)
        if stored is not None:
            answers[rec.hash] = _row(rec, stored.model_digest, stored.result, True, kind)
        else:
            todo.append((rec, m))
    total, done = len(pairs), len(answers)
    say(f"{total} recording(s); {done} answered from the catalog; {len(todo)} to {kind}")
    stored_at: dict[str, float] = {}

    def store(rec: CatalogRow, m: Model, out: dict[str, Any]) -> None:
        nonlocal done
        stored_at[rec.hash] = time.time()
        cat.store_result(rec.hash, digests[id(m)], version, kind, out, out.get("seconds"), out.get("worker"))
        row = answers[rec.hash] = _row(rec, digests[id(m)], out, False, kind)
        done += 1
        say(f"[{done}/{total}] {rec.name}: {verdict(row)} ({out.get('seconds', 0.0):.1f} s, {out.get('worker')})")

    def warm() -> None:
        for m in {id(m): m for _, m in todo}.values():
            say(f"warming the numba cache for {m.rig} before fanning out")
            warm_numba(m)

    name, counter, runs, after, lost = ("serial" if serial or not todo else "dask"), {}, {}, 0, 0
    if todo and serial:
        warm()
        for rec, m in todo:
            store(rec, m, analyse_recording(rec.path, rec.hash, m, kind))
    elif todo:
        if not scheduler:
            warm()  # before the LocalCluster starts: its workers are forked with the kernels loaded (START_METHOD)
        with engine(scheduler, workers) as (client, name):
            if scheduler:
                warm()  # while the lab's workers import this module (_preload)
            say(f"on {name}: {len(client.scheduler_info().get('workers', {}))} worker(s) connected")
            # the largest files first (a diagnosis's cost grows with the record): the last one to finish is then a
            # short one, not a long one started late with the other workers idle
            order = sorted(todo, key=lambda pair: -pair[0].size)
            tasks = [(rec.path, rec.hash, m, kind) for rec, m in order]
            names = [f"daq-{kind}-{rec.hash[:16]}-{digests[id(m)]}" for rec, m in order]
            for got in fan_out(client, analyse_recording, tasks, names, say, counter):
                rec, m = order[got.index]
                store(rec, m, got.result if got.error is None else
                      {"hash": rec.hash, "result": None, "failure": f"{rec.path}: (worker): {got.error}"})
            runs, after, lost = _count(client.get_events(EVENT_TOPIC), stored_at, wall_start)
    rows = [answers[rec.hash] for rec, _ in pairs]
    seconds = time.perf_counter() - t_start
    failed = sum(r.failure is not None for r in rows)
    report = JobReport(rows=rows, kind=kind, engine=name, computed=len(todo), cached=total - len(todo), failed=failed,
                       seconds=seconds, resubmitted=counter.get("resubmitted", 0), runs=runs, after_stored=after,
                       lost=lost)
    say(f"done: {total} recording(s), {report.computed} {DONE[kind]}, {report.cached} from the catalog, "
        f"{failed} failed, {seconds:.1f} s" + (f" on {name} ({60 * len(todo) / seconds:.1f} records/min)" if todo else ""))
    return report


run_diagnoses = run_job  # the diagnosis's name for the job (kind="diagnose" is the default)
