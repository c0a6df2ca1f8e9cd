"""The lab's archive: one SQLite catalog of every recording, beside the data, and the results computed on them.

Why a catalog: a lab keeps years of recordings from several rigs, and "what does the new model say about everything
we ever measured?" needs to know what there is without opening every file, and to remember which recording was
diagnosed with which model. Why stdlib SQLite in WAL mode (decision 33): no server to run or administer (QCoDeS keeps
every run in one SQLite file for the same reason), readers never wait for the one writer, and a transaction per file
leaves the catalog consistent whatever kills a scan. Rows are keyed by a content hash (sha256 of the file's bytes),
not by path: a file moved or renamed is found again by its hash on the next scan, and a result stored for a
recording stays valid wherever the file goes.

Where the catalog lives: ``$DAQ_ARCHIVE`` if set, else the first ``daq-archive.sqlite`` in the data's folder or
one of its parents, else a new one in the data's folder. Not on a network file system: SQLite's WAL needs shared
memory on one host, which is why only the process that runs a job writes results (daq/models/archive/jobs.py).

    from daq.io.archive import open_entry
    rec = open_entry("3fa2c1")                 # a hash prefix or a path: the recording, read when asked for
    df = open_entry("3fa2c1", as_="pandas")    # or "xarray"

Decision record: docs/decisions/0033-archive-on-dask.md.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import sqlite3
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Literal

import h5py
import numpy as np
from pydantic import Field

from daq.errors import InputError
from daq.io import h5recover
from daq.io.interchange import FORMAT_RUN, Recording, events_from_array, open_h5, read_recording
from daq.io.jsonout import dumps_json
from daq.strict import Strict

CATALOG_NAME = "daq-archive.sqlite"
ENV = "DAQ_ARCHIVE"  # a catalog path that overrides the search beside the data
SCHEMA_VERSION = 1
SUFFIXES = (".h5", ".hdf5")  # run and simple recordings: the files that say which rig they are from
HASH_CHUNK = 1 << 20
BUSY_MS = 60_000  # a writer waits this long for another (two scans at once, a job storing results)
EVENTS_KEPT = 50  # events stored per row (a run with thousands of gap events keeps its count, not all of them)

SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS recordings (
    hash TEXT PRIMARY KEY, path TEXT NOT NULL, name TEXT NOT NULL, size INTEGER NOT NULL, mtime_ns INTEGER NOT NULL,
    rig TEXT NOT NULL, rig_config_digest TEXT NOT NULL, start TEXT NOT NULL, duration_s REAL NOT NULL,
    ramp TEXT NOT NULL, rate_hz REAL NOT NULL, rates TEXT NOT NULL, notes TEXT NOT NULL, events TEXT NOT NULL,
    n_events INTEGER NOT NULL, source TEXT NOT NULL, format TEXT NOT NULL, present INTEGER NOT NULL,
    added TEXT NOT NULL, seen TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS recordings_path ON recordings (path);
CREATE INDEX IF NOT EXISTS recordings_rig_start ON recordings (rig, start);
CREATE TABLE IF NOT EXISTS results (
    hash TEXT NOT NULL, model_digest TEXT NOT NULL, code_version TEXT NOT NULL, kind TEXT NOT NULL,
    result TEXT NOT NULL, stored_at TEXT NOT NULL, computations INTEGER NOT NULL, seconds REAL, worker TEXT,
    PRIMARY KEY (hash, model_digest, code_version, kind));
"""

# columns a --where may name: text compared as text, the rest as numbers; "~" matches a part of the text
TEXT_COLUMNS = ("hash", "path", "name", "rig", "rig_config_digest", "start", "ramp", "notes", "source", "format")
NUMBER_COLUMNS = ("duration_s", "rate_hz", "size", "present", "n_events")
COLUMNS = (*TEXT_COLUMNS, *NUMBER_COLUMNS)


class CatalogRow(Strict):
    """One recording as the catalog knows it (what `daq archive list --json` prints, one per recording)."""

    path: str
    hash: str
    name: str
    rig: str
    rig_config_digest: str
    start: str  # UTC ISO time the file was created (the run's start; an import's time for imported files)
    duration_s: float
    ramp: str  # the ramp's name ("seed", "constant", a ramp file's name), "" when none was recorded
    rate_hz: float  # the fastest stream's
    rates: dict[str, float]  # every stream's sample rate
    notes: list[str]  # the operator's notes, in order
    events: list[dict[str, Any]]  # the first EVENTS_KEPT events: t [s], kind, detail
    n_events: int
    size: int
    source: str  # simulation, import, recorder, ...
    format: str
    present: bool  # False when the last scan of its folder did not find it (moved away, deleted)


class StoredResult(Strict):
    """A result stored for (recording hash, model digest, code version, kind): asked again, it costs nothing."""

    hash: str
    model_digest: str
    code_version: str
    kind: str
    result: dict[str, Any]
    stored_at: str
    computations: int = Field(description="times a computed result was stored for this key (1 unless recomputed)")
    seconds: float | None = None
    worker: str | None = None


class ScanReport(Strict):
    added: int = 0
    moved: int = 0  # found again by hash at a new path
    unchanged: int = 0
    copies: int = 0  # the same bytes as a recording still at its own path (not a second row)
    damaged: list[str] = Field(default_factory=list)  # one line each, naming the file
    missing: int = 0  # rows of this folder whose file is gone


def now_iso() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def file_hash(path: str | Path) -> str:
    """sha256 of the file's bytes, read in 1 MB pieces (a recording may be larger than memory)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(HASH_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def find_catalog(start: str | Path) -> Path | None:
    """``$DAQ_ARCHIVE``, else the first catalog in ``start`` (a folder) or one of its parents."""
    if os.environ.get(ENV):
        return Path(os.environ[ENV])
    here = Path(start).resolve()
    for d in (here, *here.parents):
        if (d / CATALOG_NAME).is_file():
            return d / CATALOG_NAME
    return None


def catalog_for_data(path: str | Path) -> Path:
    """The catalog a file (or folder) of data belongs to: found beside it or above, else a new one beside it."""
    p = Path(path).resolve()
    folder = p if p.is_dir() else p.parent
    return find_catalog(folder) or folder / CATALOG_NAME


# --------------------------------------------------------------------------- reading a file's description


def _text(v: object) -> str:
    return v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)


def _ramp_name(attrs: dict[str, object], events: list[dict[str, object]]) -> str:
    """A simulation stores its ramp's name ("seed V0=0.17 Tmax=45.0": the first word names it); a recorder stores
    the ramp file's TOML (its ``name``, if it has one); else the daemon's ramp_start event says which it ran."""
    text = _text(attrs.get("ramp", "")).strip()
    if text and "\n" not in text and "=" not in text.split()[0]:
        return text.split()[0]
    for line in text.splitlines():
        key, _, value = line.partition("=")
        if key.strip() == "name":
            return value.strip().strip('"\'')
    for ev in events:
        if ev["kind"] == "ramp_start" and ev["detail"]:
            return str(ev["detail"]).split()[0]
    return "file" if text else ""


def _time_span(ds: h5py.Dataset) -> tuple[float, float, int]:
    n = ds.shape[0]
    if n == 0:
        return np.nan, np.nan, 0
    return float(ds[0]), float(ds[n - 1]), int(n)


def describe_file(path: str | Path) -> dict[str, Any]:
    """What the catalog stores of a recording, read from its attributes, the ends of its time columns and its
    events (never the samples: a scan of years of data reads kilobytes per file). A file that is not a readable
    recording is an InputError naming it."""
    src = str(path)
    if h5recover.is_unclean(path):
        raise InputError(src, "(file)", "marked open for write (still recording, or left by a crash: "
                                        "daq.io.runfile.recover_run repairs it); not indexed")
    with open_h5(path) as f:
        attrs = {k: (_text(v) if isinstance(v, (bytes, str)) else v) for k, v in f.attrs.items()}
        fmt = _text(attrs.get("format", ""))
        rates: dict[str, float] = {}
        spans: list[tuple[float, float]] = []
        if "streams" in f:
            for name, g in f["streams"].items():
                if "t" not in g:
                    raise InputError(src, f"streams/{name}/t", "missing dataset")
                a, b, n = _time_span(g["t"])
                if n < 2:
                    continue
                declared = float(g.attrs.get("rate_hz", np.nan))
                rates[name] = declared if np.isfinite(declared) and declared > 0 else (n - 1) / (b - a)
                spans.append((a, b))
        elif "t" in f and "channels" in f:
            a, b, n = _time_span(f["t"])
            if n >= 2:
                rates["channels"] = (n - 1) / (b - a) if b > a else 0.0
                spans.append((a, b))
        else:
            raise InputError(src, "t" if "t" not in f else "channels", "missing dataset: not a recording")
        t0 = float(attrs.get("start_host_time", 0.0)) if fmt == FORMAT_RUN else 0.0
        events = events_from_array(f["events"][()], t0) if "events" in f else []
    rig = _text(attrs.get("rig", ""))
    if not rig:
        raise InputError(src, "rig", "the file does not say which rig it is from")
    config = _text(attrs.get("rig_config", ""))
    duration = max(b for _, b in spans) - min(a for a, _ in spans) if spans else 0.0
    return {
        "rig": rig,
        "rig_config_digest": hashlib.sha256(config.encode()).hexdigest()[:10] if config else "",
        "start": _text(attrs.get("created", "")),
        "duration_s": float(duration),
        "ramp": _ramp_name(attrs, events),
        "rate_hz": max(rates.values(), default=0.0),
        "rates": rates,
        "notes": [str(e["detail"]) for e in events if e["kind"] == "note"],
        "events": [{"t": e["t"], "kind": e["kind"], "detail": e["detail"]} for e in events[:EVENTS_KEPT]],
        "n_events": len(events),
        "source": _text(attrs.get("source", "recorder" if fmt == FORMAT_RUN else "")),
        "format": fmt,
    }


# --------------------------------------------------------------------------- the catalog


class Catalog:
    """One catalog file. Every write is its own short ``BEGIN IMMEDIATE`` transaction (a file added, a result
    stored), so a crash leaves what was committed and nothing half; two writers wait for each other
    (busy_timeout) instead of failing with "database is locked"."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.db = sqlite3.connect(self.path, timeout=BUSY_MS / 1000, isolation_level=None,
                                      check_same_thread=False)
        except (OSError, sqlite3.Error) as exc:
            raise InputError(str(self.path), "(catalog)", f"cannot open: {exc}") from None
        self.db.execute(f"PRAGMA busy_timeout = {BUSY_MS}")
        self._retry(self._setup)

    def _retry(self, fn: Callable[[], Any]) -> Any:
        """Switching to WAL and creating the tables need a moment alone with the file; a second process doing the
        same at the same instant can get SQLITE_BUSY without the busy handler (SQLite's rule for journal-mode
        changes): try again, briefly."""
        for attempt in range(100):
            try:
                return fn()
            except sqlite3.OperationalError as exc:
                if "locked" not in str(exc) and "busy" not in str(exc) or attempt == 99:
                    raise InputError(str(self.path), "(catalog)", str(exc)) from None
                time.sleep(0.05)
        return None

    def _setup(self) -> None:
        if self.db.execute("PRAGMA journal_mode").fetchone()[0].lower() != "wal":
            self.db.execute("PRAGMA journal_mode = WAL")
        self.db.execute("PRAGMA synchronous = NORMAL")  # WAL: durable at checkpoints, never corrupt
        with self.transaction() as db:
            for stmt in SCHEMA.split(";"):
                if stmt.strip():
                    db.execute(stmt)
            db.execute("INSERT OR IGNORE INTO meta VALUES ('schema', ?)", (str(SCHEMA_VERSION),))
        got = int(self.db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()[0])
        if got != SCHEMA_VERSION:
            raise InputError(str(self.path), "schema", f"version {got}; this software reads {SCHEMA_VERSION}")

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> Catalog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """One write, all or nothing; taken with the write lock at once (IMMEDIATE), so two writers queue rather
        than deadlock on upgrading a read."""
        self.db.execute("BEGIN IMMEDIATE")
        try:
            yield self.db
        except BaseException:
            self.db.execute("ROLLBACK")
            raise
        self.db.execute("COMMIT")

    # ------------------------------------------------------------------ recordings

    def add_file(self, path: str | Path, status: dict[str, int] | None = None) -> str:
        """Catalog one file (one transaction); returns its hash. A file seen before at the same path, size and
        modification time is not read again. ``status`` counts what happened (added, moved, unchanged, copies)."""
        p = Path(path).resolve()
        st = p.stat()
        status = status if status is not None else {}
        row = self.db.execute("SELECT hash FROM recordings WHERE path = ? AND size = ? AND mtime_ns = ?",
                              (str(p), st.st_size, st.st_mtime_ns)).fetchone()
        if row is not None:
            with self.transaction() as db:
                db.execute("UPDATE recordings SET present = 1, seen = ? WHERE hash = ?", (now_iso(), row[0]))
            status["unchanged"] = status.get("unchanged", 0) + 1
            return row[0]
        digest = file_hash(p)
        info = describe_file(p)
        t = now_iso()
        with self.transaction() as db:
            old = db.execute("SELECT path FROM recordings WHERE hash = ?", (digest,)).fetchone()
            if old is not None and old[0] != str(p) and Path(old[0]).exists():
                kind = "copies"  # the same bytes elsewhere: one recording, its first path kept
                db.execute("UPDATE recordings SET present = 1, seen = ? WHERE hash = ?", (t, digest))
            else:
                kind = "added" if old is None else ("unchanged" if old[0] == str(p) else "moved")
                db.execute(
                    "INSERT INTO recordings VALUES (:hash, :path, :name, :size, :mtime_ns, :rig, :rig_config_digest,"
                    " :start, :duration_s, :ramp, :rate_hz, :rates, :notes, :events, :n_events, :source, :format, 1,"
                    " :t, :t) ON CONFLICT (hash) DO UPDATE SET path = excluded.path, name = excluded.name,"
                    " size = excluded.size, mtime_ns = excluded.mtime_ns, present = 1, seen = excluded.seen",
                    {**info, "rates": json.dumps(info["rates"]), "notes": json.dumps(info["notes"]),
                     "events": json.dumps(info["events"]), "hash": digest, "path": str(p), "name": p.name,
                     "size": st.st_size, "mtime_ns": st.st_mtime_ns, "t": t})
        status[kind] = status.get(kind, 0) + 1
        return digest

    def scan(self, folder: str | Path, say: Callable[[str], None] | None = None) -> ScanReport:
        """Every recording under ``folder`` (recursively): new ones added, moved ones found by hash, damaged ones
        named (one line each) and skipped. Rows of this folder whose file is gone are marked not present."""
        root = Path(folder).resolve()
        if not root.is_dir():
            raise InputError(str(folder), "DIR", "not a folder")
        status: dict[str, int] = {}
        damaged: list[str] = []
        seen: set[str] = set()
        for p in sorted(q for q in root.rglob("*") if q.suffix.lower() in SUFFIXES and q.is_file()):
            try:
                self.add_file(p, status)
                seen.add(str(p))
            except sqlite3.Error as exc:  # the catalog's trouble, not the file's: stop and say so
                raise InputError(str(self.path), "(catalog)", str(exc)) from None
            except Exception as exc:  # noqa: BLE001 - a damaged file can make h5py raise anything: one line, go on
                damaged.append(str(exc) if isinstance(exc, InputError) else
                               f"{p}: (file): {exc.strerror if isinstance(exc, OSError) and exc.strerror else exc}")
                if say:
                    say(f"skipped {damaged[-1]}")
        gone = [h for h, path in self.db.execute("SELECT hash, path FROM recordings WHERE present = 1 AND path LIKE ?",
                                                  (str(root) + os.sep + "%",))
                if path not in seen and not Path(path).exists()]
        if gone:
            with self.transaction() as db:
                db.executemany("UPDATE recordings SET present = 0 WHERE hash = ?", [(h,) for h in gone])
        return ScanReport(added=status.get("added", 0), moved=status.get("moved", 0),
                          unchanged=status.get("unchanged", 0), copies=status.get("copies", 0), damaged=damaged,
                          missing=len(gone))

    def rows(self, rig: str | None = None, since: str | None = None, where: list[str] = (),
             hashes: list[str] | None = None) -> list[CatalogRow]:
        """The recordings that match, oldest first. ``where``: KEY=VALUE (equal) or KEY~TEXT (contains) on the
        catalog's columns; ``since``: a date or time (ISO), compared with the start."""
        sql, args = "SELECT * FROM recordings WHERE 1", []
        if rig:
            sql += " AND rig = ?"
            args.append(rig)
        if since:
            sql += " AND start >= ?"
            args.append(_iso_since(since))
        for cond in where:
            clause, value = parse_where(cond)
            sql += f" AND {clause}"
            args.append(value)
        if hashes is not None:
            sql += f" AND hash IN ({','.join('?' * len(hashes))})"
            args.extend(hashes)
        cur = self.db.execute(sql + " ORDER BY start, path", args)
        names = [d[0] for d in cur.description]
        return [_row(dict(zip(names, r))) for r in cur.fetchall()]

    def get(self, ref: str) -> CatalogRow:
        """One recording by a hash (or a prefix of at least 6 characters) or a path."""
        path = str(Path(ref).resolve()) if Path(ref).exists() else ref
        cur = self.db.execute("SELECT * FROM recordings WHERE path = ? OR hash LIKE ?",
                              (path, ref + "%" if len(ref) >= 6 else ref))
        names = [d[0] for d in cur.description]
        found = [_row(dict(zip(names, r))) for r in cur.fetchall()]
        if len(found) != 1:
            raise InputError(str(self.path), ref, "no such recording in the catalog" if not found else
                             f"{len(found)} recordings match: give more of the hash")
        return found[0]

    def count(self) -> int:
        return int(self.db.execute("SELECT COUNT(*) FROM recordings").fetchone()[0])

    # ------------------------------------------------------------------ results

    def result(self, digest: str, model_digest: str, code_version: str, kind: str) -> StoredResult | None:
        r = self.db.execute("SELECT * FROM results WHERE hash = ? AND model_digest = ? AND code_version = ? AND "
                            "kind = ?", (digest, model_digest, code_version, kind)).fetchone()
        return _result(r) if r is not None else None

    def results(self, model_digest: str, code_version: str, kind: str) -> dict[str, StoredResult]:
        cur = self.db.execute("SELECT * FROM results WHERE model_digest = ? AND code_version = ? AND kind = ?",
                              (model_digest, code_version, kind))
        return {r[0]: _result(r) for r in cur.fetchall()}

    def store_result(self, digest: str, model_digest: str, code_version: str, kind: str, result: dict[str, Any],
                     seconds: float | None = None, worker: str | None = None) -> int:
        """Store a computed result (one transaction, at once: a job killed after this keeps it); returns how many
        times a computed result has now been stored for this key (``computations``: 1 unless it was recomputed)."""
        with self.transaction() as db:
            db.execute("INSERT INTO results VALUES (?, ?, ?, ?, ?, ?, 1, ?, ?) ON CONFLICT DO UPDATE SET "
                       "result = excluded.result, stored_at = excluded.stored_at, seconds = excluded.seconds, "
                       "worker = excluded.worker, computations = results.computations + 1",
                       (digest, model_digest, code_version, kind, dumps_json(result, indent=None),
                        now_iso(), seconds, worker))
            n = db.execute("SELECT computations FROM results WHERE hash = ? AND model_digest = ? AND code_version = ?"
                           " AND kind = ?", (digest, model_digest, code_version, kind)).fetchone()[0]
        return int(n)


def _row(d: dict[str, Any]) -> CatalogRow:
    d["rates"], d["notes"], d["events"] = json.loads(f"[{d['rates']},{d['notes']},{d['events']}]")  # one parse
    d["present"] = bool(d["present"])
    for k in ("mtime_ns", "added", "seen"):
        d.pop(k)
    return CatalogRow.model_construct(**d)  # our own rows, validated when written: 10 000 list in ~0.1 s


def _result(r: tuple) -> StoredResult:
    return StoredResult(hash=r[0], model_digest=r[1], code_version=r[2], kind=r[3], result=json.loads(r[4]),
                        stored_at=r[5], computations=r[6], seconds=r[7], worker=r[8])


def parse_where(cond: str) -> tuple[str, object]:
    """``KEY=VALUE`` or ``KEY~TEXT`` as an SQL clause (the column checked against the catalog's) and its value."""
    op = "=" if "=" in cond else ("~" if "~" in cond else None)
    if op is None:
        raise InputError("--where", cond, "expected KEY=VALUE (or KEY~TEXT for a part of a text)")
    key, _, value = cond.partition(op)
    key = key.strip()
    if key not in COLUMNS:
        raise InputError("--where", key or cond, f"unknown column (have: {', '.join(COLUMNS)})")
    if op == "~":
        return f"instr({key}, ?) > 0", value
    if key in NUMBER_COLUMNS:
        if key == "present" and value.strip().lower() in ("true", "false"):
            value = "1" if value.strip().lower() == "true" else "0"
        try:
            return f"{key} = ?", float(value)
        except ValueError:
            raise InputError("--where", key, f"{value!r} is not a number") from None
    return f"{key} = ?", value


def _iso_since(since: str) -> str:
    try:
        t = _dt.datetime.fromisoformat(since)
    except ValueError:
        raise InputError("--since", since, "not a date (YYYY-MM-DD) or ISO time") from None
    if t.tzinfo is None:
        t = t.replace(tzinfo=_dt.UTC)
    return t.astimezone(_dt.UTC).isoformat(timespec="seconds")


def open_catalog(path: str | Path | None = None, start: str | Path = ".") -> Catalog:
    """The catalog at ``path``, else ``$DAQ_ARCHIVE``, else the first one in ``start`` or above (none there: an
    InputError saying how to make one)."""
    found = Path(path) if path else find_catalog(start)
    if found is None or not found.is_file():
        where = str(found) if found is not None else f"{Path(start).resolve()} or its parents"
        raise InputError(where, "--catalog", f"no catalog ({CATALOG_NAME}) here: `daq archive scan DIR` makes one")
    return Catalog(found)


def catalog_new_file(path: str | Path, warn: Callable[[str], None]) -> str | None:
    """Add a file just written (by the recorder, by `daq import`) to its catalog. Never raises: the recording is
    what matters, so a catalog that cannot take it is one warning line (``warn``) and the file stays as it is."""
    try:
        with Catalog(catalog_for_data(path)) as cat:
            return cat.add_file(path)
    except Exception as exc:  # noqa: BLE001 - whatever the catalog's trouble, the recording is kept
        warn(f"warning: {path} not added to the archive catalog ({type(exc).__name__}: {exc})")
        return None


# --------------------------------------------------------------------------- a row opened as data


class Entry:
    """A catalog row whose data are read only when asked for (a listing never opens a file)."""

    def __init__(self, row: CatalogRow) -> None:
        self.row = row
        self._rec: Recording | None = None

    def recording(self) -> Recording:
        if self._rec is None:
            if not Path(self.row.path).is_file():
                raise InputError(self.row.path, "(file)", f"recording {self.row.hash[:12]} is not at its catalogued "
                                                          "path: scan the folder it moved to")
            self._rec = read_recording(self.row.path)
        return self._rec

    def to_pandas(self):
        return self.recording().to_pandas()

    def to_xarray(self):
        return self.recording().to_xarray()


def open_entry(ref: str, catalog: str | Path | None = None,
               as_: Literal["entry", "recording", "pandas", "xarray"] = "recording"):
    """A catalogued recording in one call: ``ref`` is a hash (prefix) or a path; ``as_`` what to return (an
    :class:`Entry` reads nothing until asked)."""
    with open_catalog(catalog) as cat:
        entry = Entry(cat.get(ref))
    if as_ == "entry":
        return entry
    return {"recording": entry.recording, "pandas": entry.to_pandas, "xarray": entry.to_xarray}[as_]()
