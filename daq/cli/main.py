"""The ``daq`` command line: the one place that registers every command.

Each command group is a module of daq/cli/ with a ``register(sub)`` function; they are
listed here in the order `daq --help` shows them. Bad input of any kind: one line on stderr
naming file and field, exit 2.

Decision record: docs/decisions/0012-layout-by-layer.md.
"""

from __future__ import annotations

import argparse
import sys

from daq.errors import InputError

from . import analyses, archive, bench, daemon, data, demo, models, propose, rig, sim, soak, warm

GROUPS = (rig, sim, data, bench, daemon, soak, models, propose, archive, analyses, demo, warm)


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
    except KeyboardInterrupt:
        print("daq: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
