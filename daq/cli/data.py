"""``daq import`` and ``daq export``: other files into the recording format, and back to interchange CSV.

Heavy modules are imported inside the command functions (marked ``# heavy``): `daq --help`
imports every cli module and must stay fast.
"""

from __future__ import annotations

import argparse
import sys


def cmd_import(args: argparse.Namespace) -> int:
    # heavy: h5py, numpy, nptdms
    from daq.io.archive import catalog_new_file
    from daq.io.importer import import_file

    import_file(args.file, args.rig, args.output, maps=args.map, time=args.time, rate=args.rate,
                drop_nonfinite=args.drop_nonfinite)
    print(f"imported {args.file} -> {args.output}", file=sys.stderr)
    catalog_new_file(args.output, lambda line: print(line, file=sys.stderr))  # a warning at worst, never a failure
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    # heavy: h5py, numpy
    from daq.io.importer import export_csv

    export_csv(args.file, args.output)
    print(f"exported {args.file} -> {args.output}", file=sys.stderr)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    imp = sub.add_parser("import", help="bring a CSV, TDMS, MATLAB or text file into the recording format",
                         description="An interchange CSV or TDMS needs no options. Any other file: name its time "
                                     "(--time) or rate (--rate) and map its variables to the rig's channels, "
                                     "e.g. --map \"x1=F_over_mg*0.05*9.81/200\" --map vb=5e-5.")
    imp.add_argument("file", help="FILE.csv|.tsv|.txt|.dat|.mat|.tdms")
    imp.add_argument("--rig", required=True, help="a built-in rig or a rig TOML file")
    imp.add_argument("--time", metavar="EXPR", help="the time [s]: a variable, or arithmetic over variables")
    imp.add_argument("--rate", type=float, metavar="HZ", help="samples at this rate from t = 0 (no time variable)")
    imp.add_argument("--map", action="append", default=[], metavar="CHANNEL=EXPR",
                     help="a channel from arithmetic over the file's variables (+ - * / ** %%, numbers, "
                          "sqrt exp log sin cos ...; names with other characters in `backticks`); repeatable")
    imp.add_argument("--drop-nonfinite", action="store_true",
                     help="drop rows where a rig channel is NaN or inf, each dropped span an event in the "
                          "recording (default: refuse the file, naming the first such sample)")
    imp.add_argument("-o", "--output", required=True, help="OUT.h5")
    imp.set_defaults(func=cmd_import)

    exp = sub.add_parser("export", help="write a recording as interchange CSV")
    exp.add_argument("file")
    exp.add_argument("-o", "--output", required=True, help="OUT.csv")
    exp.set_defaults(func=cmd_export)
