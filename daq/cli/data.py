"""``daq import`` and ``daq export``: other files into the recording format, and back to interchange CSV.

Heavy modules are imported inside the command functions (marked ``# heavy``): `daq --help`
imports every cli module and must stay fast.
"""

from __future__ import annotations

import argparse
import sys


def cmd_import(args: argparse.Namespace) -> int:
    # heavy: h5py, numpy, nptdms
    from daq.io.importer import import_file

    import_file(args.file, args.rig, args.output)
    print(f"imported {args.file} -> {args.output}", file=sys.stderr)
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    # heavy: h5py, numpy
    from daq.io.importer import export_csv

    export_csv(args.file, args.output)
    print(f"exported {args.file} -> {args.output}", file=sys.stderr)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    imp = sub.add_parser("import", help="bring a CSV or LabVIEW TDMS file into the recording format")
    imp.add_argument("file")
    imp.add_argument("--rig", required=True)
    imp.add_argument("-o", "--output", required=True, help="OUT.h5")
    imp.set_defaults(func=cmd_import)

    exp = sub.add_parser("export", help="write a recording as interchange CSV")
    exp.add_argument("file")
    exp.add_argument("-o", "--output", required=True, help="OUT.csv")
    exp.set_defaults(func=cmd_export)
