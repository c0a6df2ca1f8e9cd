"""The ``daq`` command line: the one place that registers every command.

Each command group is a module of daq/cli/ with a ``register(sub)`` function; they are
listed here in the order `daq --help` shows them. Bad input of any kind: one line on stderr
naming file and field, exit 2; a command's own fit that fails numerically (NumericalFailure): one line, exit 2; any
other of our own errors at run time (a DaqError: a device that stopped answering, a rig in use): one line, exit 1.

Decision record: docs/decisions/0012-layout-by-layer.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import traceback

from daq.errors import DaqError, InputError, NumericalFailure

from . import analyses, archive, bench, daemon, data, demo, models, propose, rig, sim, soak, warm

GROUPS = (rig, sim, data, bench, daemon, soak, models, propose, archive, analyses, demo, warm)
# With this set to a file, every exception a command ends in (anything but a one-line error or an interrupt) is
# appended to it as a JSON line (command, arguments, exception type, traceback) before it propagates: the suite sets
# it for all its processes and scans the file at its end (tests/conftest.py), so a traceback a test did not look at
# still fails the run (decision 50).
TRACEBACK_LOG = "DAQ_TRACEBACK_LOG"


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="daq", description="Dry-friction rig acquisition, simulation and analysis")
    sub = ap.add_subparsers(dest="command", required=True)
    for group in GROUPS:
        group.register(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"daq: error: {exc}", file=sys.stderr)
        return 2
    except NumericalFailure as exc:  # good input a fit could not carry through: said as plainly (decision 50)
        data = getattr(args, "data", None)
        where = ", ".join(map(str, data)) if isinstance(data, list) else (data or args.command)
        print(f"daq: error: {where}: the fit failed: {exc}", file=sys.stderr)
        return 2
    except DaqError as exc:  # our own failure at run time (a device that stopped answering, a busy rig): one line
        print(f"daq: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("daq: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        _log_traceback(args, argv, exc)
        raise


def _log_traceback(args: argparse.Namespace, argv: list[str] | None, exc: Exception) -> None:
    path = os.environ.get(TRACEBACK_LOG)
    if not path:
        return
    entry = {"command": args.command, "argv": list(sys.argv[1:] if argv is None else argv),
             "type": type(exc).__name__, "traceback": traceback.format_exc()}
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(entry) + "\n")


if __name__ == "__main__":
    sys.exit(main())
