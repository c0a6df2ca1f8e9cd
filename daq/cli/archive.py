"""``daq archive``: the lab's catalog of recordings (scan, list, status) and re-diagnosis on Dask.

    daq archive scan DIR                          # every recording under DIR into the catalog beside it
    daq archive list --rig belt-ndof --since 2026-11-01 --where "ramp=seed" [--json]
    daq archive status --model M.toml [--kind compare]   # which recordings are not yet diagnosed (compared) with M
    daq archive diagnose --model M.toml [--where ...] [--scheduler tcp://HOST:PORT] [--workers N] [--recompute]
    daq archive compare --model M.toml ...        # the same job, `daq compare`'s answer kept per recording
    daq archive fit --model M.toml ...            # the same job, `daq fit`'s answer (and fitted model) kept

The catalog is ``--catalog PATH``, else ``$DAQ_ARCHIVE``, else the first daq-archive.sqlite in the current folder or
above (``scan``: in DIR or above, else a new one in DIR). Heavy modules (h5py, numpy, numba, dask) are imported
inside the command functions (marked ``# heavy``): `daq --help` imports every cli module and must stay fast.

Decision record: docs/decisions/0033-archive-on-dask.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from daq.errors import InputError
from daq.io.jsonout import print_json

from .output import say


def _catalog(args: argparse.Namespace):
    # heavy: h5py, numpy
    from daq.io.archive import open_catalog

    return open_catalog(args.catalog)


def _models(args: argparse.Namespace) -> list:
    # heavy: numpy, scipy, numba and the models only when the command runs
    from daq.models.spec import load_model

    return [load_model(p) for p in args.model]


def cmd_scan(args: argparse.Namespace) -> int:
    # heavy: h5py, numpy
    from daq.io.archive import Catalog, catalog_for_data

    folder = Path(args.dir)
    if not folder.is_dir():
        raise InputError(str(folder), "DIR", "not a folder")
    path = Path(args.catalog) if args.catalog else catalog_for_data(folder)
    print(f"archive scan: {folder} into {path}", file=sys.stderr)
    with Catalog(path) as cat:
        rep = cat.scan(folder, say=say)
        total = cat.count()
    if args.json:
        print_json({"catalog": str(path), "recordings": total, **rep.model_dump()})
    else:
        print(f"{rep.added} added, {rep.moved} moved (found by hash), {rep.unchanged} unchanged, {rep.copies} copies, "
              f"{len(rep.damaged)} skipped, {rep.missing} missing; {total} recordings in {path}")
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    with _catalog(args) as cat:
        rows = cat.rows(rig=args.rig, since=args.since, where=args.where)
    if args.json:
        print_json([r.model_dump() for r in rows])
        return 0
    print(f"{'hash':12s}  {'rig':13s}  {'start':25s}  {'duration':>9s}  {'ramp':9s}  {'rate':>8s}  path")
    for r in rows:
        print(f"{r.hash[:12]}  {r.rig:13s}  {r.start:25s}  {r.duration_s:8.1f}s  {r.ramp:9s}  {r.rate_hz:6.0f}Hz  "
              f"{r.path}{'' if r.present else '  (missing)'}")
    print(f"{len(rows)} recording(s)", file=sys.stderr)
    return 0


def cmd_status(args: argparse.Namespace) -> int:
    # heavy: numpy, scipy, numba, dask and the models only when the command runs
    from daq.models.archive.jobs import DONE, KINDS, status

    models = _models(args)
    with _catalog(args) as cat:
        res = status(cat, cat.rows(where=args.where), models)
    if args.json:
        print_json(res)
        return 0
    done = DONE[args.kind]
    for m in res["models"]:
        print(f"{m['model']} (digest {m['model_digest']}): of {m['recordings']} recording(s) of {m['rig']}, "
              + ", ".join(f"{m[DONE[k]]} {DONE[k]}" for k in KINDS) + f"; not yet {done}: {len(m['not_' + done])}")
        for r in m["not_" + done]:
            print(f"  {r['hash'][:12]}  {r['path']}")
    return 0


def cmd_job(args: argparse.Namespace) -> int:
    """`daq archive diagnose`, `compare` and `fit`: one job, its kind from the command."""
    # heavy: numpy, scipy, numba, dask and the models only when the command runs
    from daq.models.archive.jobs import match_models, run_job, verdict

    if args.workers is not None and args.workers < 1:
        raise InputError("--workers", "--workers", f"must be a whole number >= 1, got {args.workers}")
    if args.serial and args.scheduler:
        raise InputError("--serial", "--scheduler", "give one: --serial runs here, --scheduler on a cluster")
    models = _models(args)
    with _catalog(args) as cat:
        rows = cat.rows(rig=args.rig, since=args.since, where=args.where)
        print(f"archive {args.kind}: {len(rows)} recording(s) in {cat.path} against "
              + "; ".join(m.describe() for m in models), file=sys.stderr)
        pairs = match_models(rows, models, say)
        rep = run_job(cat, pairs, kind=args.kind, scheduler=args.scheduler, workers=args.workers, serial=args.serial,
                      recompute=args.recompute, say=say)
    if args.json:
        print_json([r.model_dump() for r in rep.rows])
        return 0
    for r in rep.rows:
        err = (f"  {r.error:.4g} {r.error_unit} (floor {r.noise_floor:.4g})"
               if args.kind == "diagnose" and r.error is not None and r.noise_floor is not None else "")
        print(f"{r.hash[:12]}  {Path(r.path).name:28s} {verdict(r)}{err}{'  (cached)' if r.cached else ''}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    arc = sub.add_parser("archive", help="the lab's catalog of recordings; re-diagnose it on Dask")
    asub = arc.add_subparsers(dest="archive_command", required=True)

    def catalog(p: argparse.ArgumentParser) -> None:
        p.add_argument("--catalog", help="the catalog file (default: $DAQ_ARCHIVE, else daq-archive.sqlite here or "
                                         "in a parent folder)")
        p.add_argument("--json", action="store_true")

    def select(p: argparse.ArgumentParser) -> None:
        p.add_argument("--rig", help="only this rig's recordings")
        p.add_argument("--since", help="only recordings started on or after this date (YYYY-MM-DD) or ISO time")
        p.add_argument("--where", action="append", default=[], metavar="KEY=VALUE",
                       help="only rows whose column KEY equals VALUE (KEY~TEXT: contains TEXT); repeatable; columns: "
                            "hash path name rig rig_config_digest start ramp notes source format duration_s rate_hz "
                            "size present n_events")

    p = asub.add_parser("scan", help="catalog every recording (.h5) under DIR; moved files are found by hash")
    p.add_argument("dir", metavar="DIR")
    catalog(p)
    p.set_defaults(func=cmd_scan)

    p = asub.add_parser("list", help="the catalogued recordings (table, or --json)")
    catalog(p)
    select(p)
    p.set_defaults(func=cmd_list)

    p = asub.add_parser("status", help="which recordings are not yet diagnosed (compared, fitted) with a model")
    p.add_argument("--model", action="append", required=True, help="model TOML (one per rig; repeatable)")
    p.add_argument("--where", action="append", default=[], metavar="KEY=VALUE", help="only rows that match")
    p.add_argument("--kind", choices=("diagnose", "compare", "fit"), default="diagnose",
                   help="whose missing recordings the table lists (default diagnose; --json has every kind's)")
    catalog(p)
    p.set_defaults(func=cmd_status)

    for kind, hlp in (("diagnose", "diagnose every catalogued recording with a model, on Dask; results kept"),
                      ("compare", ("compare every catalogued recording with a model (`daq compare`), on Dask; "
                                   "results kept")),
                      ("fit", ("fit a model to every catalogued recording (`daq fit`), on Dask; results (and the "
                               "fitted models) kept"))):
        p = asub.add_parser(kind, help=hlp)
        p.add_argument("--model", action="append", required=True,
                       help="model TOML (one per rig, repeatable: each recording gets its rig's model)")
        catalog(p)
        select(p)
        p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="a running Dask scheduler (default: a "
                                                                       "LocalCluster on this machine)")
        p.add_argument("--workers", type=int, help="LocalCluster workers (default: one per core)")
        p.add_argument("--serial", action="store_true", help="one recording after another in this process, no Dask")
        p.add_argument("--recompute", action="store_true", help="ignore stored results")
        p.set_defaults(func=cmd_job, kind=kind)
