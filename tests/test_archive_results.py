"""Issue 28, results in the catalog: compare, fit and diagnose results stored keyed by (recording hash, model digest,
code version, kind), so that asking again computes nothing (counted: the analysis is not called, the stored row's
`computations` stays 1) and a changed model digest computes again; `daq archive status` says which recordings have
no result of a kind yet. And the engine's settings for a LocalCluster's workers (decision 33: what Dask with one
worker cost over serial): the configuration and environment reach the worker process.

Decision record: docs/decisions/0033-archive-on-dask.md.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from helpers import make_recordings

from daq.cli.main import main as daq
from daq.io.archive import Catalog
from daq.models.archive import jobs as archive_jobs
from daq.models.archive.jobs import ResultRow, code_version, match_models, run_job
from daq.models.spec import load_model, parse_model, parse_toml, save_model, seed_model

# two short brake records and one drum record at 100 Hz: a compare or fit of each takes about a second
SPEC = [("brake-2dof", 6.0, 1), ("brake-2dof", 6.0, 2), ("drum-pendulum", 4.0, 1)]


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("results")
    data = make_recordings(tmp / "data", SPEC)
    cat = tmp / "cat.sqlite"
    with Catalog(cat) as c:
        c.scan(data)
    brake = tmp / "brake.toml"
    save_model(seed_model("brake-2dof"), brake)
    return tmp, data, cat, brake


@pytest.fixture
def counted(monkeypatch):
    """Each analysis's calls, by kind and recording (the serial path runs them in this process)."""
    calls: dict[str, list[str]] = {k: [] for k in archive_jobs.KINDS}
    for kind, fn in list(archive_jobs.ANALYSES.items()):
        def wrapped(s, model, kind=kind, fn=fn):
            calls[kind].append(s.source)
            return fn(s, model)
        monkeypatch.setitem(archive_jobs.ANALYSES, kind, wrapped)
    return calls


def computations(cat: Path, kind: str) -> dict[tuple[str, str], int]:
    """Per (hash, model digest): how many computed results were stored under ``kind`` at this code version."""
    import sqlite3

    db = sqlite3.connect(cat)
    try:
        return {(h, d): n for h, d, n in db.execute(
            "SELECT hash, model_digest, computations FROM results WHERE kind = ? AND code_version = ?",
            (kind, code_version(kind)))}
    finally:
        db.close()


def cli_rows(capsys, *args: str) -> list[dict]:
    capsys.readouterr()
    assert daq(["archive", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.slow
def test_compare_stored_asked_again_costs_nothing_and_a_new_digest_computes(archive, counted, capsys):
    tmp, _, cat, brake = archive
    first = cli_rows(capsys, "compare", "--catalog", str(cat), "--model", str(brake), "--serial")
    rows = [ResultRow(**r) for r in first]
    assert len(rows) == 2 and not any(r.cached for r in rows) and all(r.failure is None for r in rows)
    assert all(r.kind == "compare" and r.error > 0 and r.noise_floor > 0 and r.error_unit for r in rows)
    assert len(counted["compare"]) == 2
    digest = load_model(brake).digest()
    assert set(computations(cat, "compare").values()) == {1}
    assert {d for _, d in computations(cat, "compare")} == {digest}

    # the same answer as `daq compare` gives for the file
    one = rows[0]
    capsys.readouterr()
    assert daq(["compare", one.path, "--model", str(brake), "--json", "--no-history"]) == 0
    direct = json.loads(capsys.readouterr().out)
    assert (one.error, one.noise_floor) == pytest.approx((direct["error"], direct["noise_floor"]), rel=1e-9)
    assert one.result["worst_regime"] == direct["worst_regime"]
    assert one.result["model_digest"] == direct["model_digest"]  # compare's own field: the fitted model's digest
    assert one.model_digest == digest  # the key: the model asked with

    # asked again: every row from the catalog, nothing computed (the analysis not called, no second computation)
    again = [ResultRow(**r) for r in cli_rows(capsys, "compare", "--catalog", str(cat), "--model", str(brake))]
    assert all(r.cached for r in again) and len(counted["compare"]) == 2
    assert [r.model_dump(exclude={"cached"}) for r in again] == [r.model_dump(exclude={"cached"}) for r in rows]
    assert set(computations(cat, "compare").values()) == {1}

    # a changed model (another digest): computed again, stored beside the first model's results
    changed = tmp / "brake-mu.toml"
    save_model(seed_model("brake-2dof").with_values({"friction.mu0": 0.3}), changed)
    new = [ResultRow(**r) for r in cli_rows(capsys, "compare", "--catalog", str(cat), "--model", str(changed),
                                            "--serial")]
    assert not any(r.cached for r in new) and len(counted["compare"]) == 4
    assert {r.model_digest for r in new} == {load_model(changed).digest()} != {digest}
    assert len(computations(cat, "compare")) == 4

    # --recompute computes again and counts it on the stored row
    cli_rows(capsys, "compare", "--catalog", str(cat), "--model", str(brake), "--serial", "--recompute")
    assert len(counted["compare"]) == 6
    assert sorted(computations(cat, "compare").values()) == [1, 1, 2, 2]


@pytest.mark.slow
def test_fit_stored_with_its_fitted_model_and_status_per_kind(archive, counted, capsys):
    tmp, data, cat, brake = archive
    m = load_model(brake)
    with Catalog(cat) as c:
        pairs = match_models(c.rows(), [m], lambda msg: None)
        rep = run_job(c, pairs, kind="fit", serial=True)
        assert (rep.kind, rep.computed, rep.cached, rep.failed) == ("fit", 2, 0, 0)
        again = run_job(c, pairs, kind="fit", serial=True)
    assert (again.computed, again.cached) == (0, 2) and all(r.cached for r in again.rows)
    assert len(counted["fit"]) == 2  # the second job called nothing
    assert [r.result for r in again.rows] == [r.result for r in rep.rows]
    for r in rep.rows:
        fitted = parse_model(parse_toml(r.result["fitted_model"], "stored"), "stored")  # a stored fit is a model
        assert fitted.digest() == r.result["fitted_digest"] != m.digest()
        assert set(r.result["parameters"]) == set(m.free_names())
        for k, p in r.result["parameters"].items():
            assert fitted.params()[k].value == pytest.approx(p["value"], rel=1e-9)
    # the same figures as `daq fit` gives for the file
    out = tmp / "fitted.toml"
    capsys.readouterr()
    assert daq(["fit", rep.rows[0].path, "--model", str(brake), "-o", str(out), "--json"]) == 0
    direct = json.loads(capsys.readouterr().out)
    assert rep.rows[0].error == pytest.approx(direct["error"], rel=1e-9)
    assert {k: v["value"] for k, v in rep.rows[0].result["parameters"].items()} == pytest.approx(
        {k: v["value"] for k, v in direct["parameters"].items()}, rel=1e-9)

    # status: every kind counted on its own; fitting a recording does not make it diagnosed
    st = cli_rows(capsys, "status", "--catalog", str(cat), "--model", str(brake))
    entry = st["models"][0]
    assert (entry["recordings"], entry["fitted"], entry["not_fitted"]) == (2, 2, [])
    assert entry["diagnosed"] == 0 and len(entry["not_diagnosed"]) == 2
    assert st["code_versions"]["fit"] == code_version("fit") != code_version("diagnose")
    capsys.readouterr()
    assert daq(["archive", "status", "--catalog", str(cat), "--model", str(brake), "--kind", "fit"]) == 0
    text = capsys.readouterr().out
    assert "2 fitted" in text and "not yet fitted: 0" in text
    assert daq(["archive", "status", "--catalog", str(cat), "--model", str(brake)]) == 0
    text = capsys.readouterr().out
    assert "not yet diagnosed: 2" in text and sum(Path(p).name in text for p in os.listdir(data)) == 2


@pytest.mark.slow
def test_diagnose_asked_again_computes_nothing_and_a_new_digest_computes(archive, counted, capsys):
    tmp, _, cat, brake = archive
    one = ["--catalog", str(cat), "--where", "name=brake-2dof-00.h5"]  # a diagnosis of one short record: ~1.5 s
    first = cli_rows(capsys, "diagnose", *one, "--model", str(brake), "--serial")
    assert len(first) == 1 and not first[0]["cached"] and len(counted["diagnose"]) == 1
    again = cli_rows(capsys, "diagnose", *one, "--model", str(brake), "--serial")
    assert again[0]["cached"] and len(counted["diagnose"]) == 1
    assert {k: v for k, v in again[0].items() if k != "cached"} == {k: v for k, v in first[0].items() if k != "cached"}
    assert set(computations(cat, "diagnose").values()) == {1}
    st = cli_rows(capsys, "status", *one, "--model", str(brake))["models"][0]
    assert (st["recordings"], st["diagnosed"], st["not_diagnosed"]) == (1, 1, [])
    changed = tmp / "brake-changed.toml"
    save_model(seed_model("brake-2dof").with_values({"friction.mu0": 0.35}), changed)
    new = cli_rows(capsys, "diagnose", *one, "--model", str(changed), "--serial")
    assert not new[0]["cached"] and len(counted["diagnose"]) == 2
    assert new[0]["model_digest"] == load_model(changed).digest() != first[0]["model_digest"]
    assert sorted(computations(cat, "diagnose").values()) == [1, 1]


@pytest.mark.slow
def test_a_compare_on_a_local_cluster_stores_what_the_serial_path_does(archive, capsys):
    """The kind travels to the workers: a fresh catalog compared on a LocalCluster of one worker has the serial
    path's answers, each stored once."""
    tmp, data, cat, brake = archive
    serial = {r["hash"]: r for r in cli_rows(capsys, "compare", "--catalog", str(cat), "--model", str(brake),
                                             "--serial")}
    dask_cat = tmp / "dask.sqlite"
    with Catalog(dask_cat) as c:
        c.scan(data)
    rows = cli_rows(capsys, "compare", "--catalog", str(dask_cat), "--model", str(brake), "--workers", "1")
    assert len(rows) == 2 and not any(r["cached"] for r in rows)
    assert all(r["worker"].rsplit(":", 1)[1] != str(os.getpid()) for r in rows)  # computed on the worker
    for r in rows:
        assert (r["error"], r["noise_floor"]) == pytest.approx((serial[r["hash"]]["error"],
                                                                serial[r["hash"]]["noise_floor"]), rel=1e-9)
    assert set(computations(dask_cat, "compare").values()) == {1}


def worker_settings(dask_worker) -> dict:
    """Run on a worker by ``client.run`` (which hands it the worker)."""
    import dask

    return {"profile": dask.config.get("distributed.worker.profile.enabled"),
            "tick": dask.config.get("distributed.admin.tick.interval"),
            "memory": dask.config.get("distributed.worker.memory.monitor-interval"),
            "callbacks": sorted(dask_worker.periodic_callbacks),
            "env": {k: os.environ.get(k) for k in archive_jobs.WORKER_ENV}}


@pytest.mark.slow
def test_a_local_clusters_workers_get_the_engines_settings():
    """What keeps a worker's event loop off the task's GIL (no profiler, a slow health tick) and the environment
    chosen for the workers reach the worker process: its nanny hands them over when it starts it."""
    with archive_jobs.engine(None, 1) as (client, name):
        (got,) = client.run(worker_settings).values()
    assert name == "LocalCluster (1 worker)"
    assert got["profile"] is False and got["tick"] == "1s" and got["memory"] == "1s"
    assert "profile" not in got["callbacks"] and "profile-cycle" not in got["callbacks"]
    assert got["env"] == archive_jobs.WORKER_ENV
