"""What every command prints besides its result: progress on stderr (the result goes to stdout).

``--json`` output goes through :func:`daq.io.jsonout.print_json`, the one JSON printer.
"""

from __future__ import annotations

import sys


def say(msg: str) -> None:
    """One progress line on stderr (indented under the command's first line)."""
    print(f"  {msg}", file=sys.stderr, flush=True)


def progress(label: str):
    """A rich progress bar on stderr when it is a terminal; silent otherwise."""
    # heavy: rich costs ~30 ms; imported only by the commands that show a bar (start-up time of daq --help)
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    return Progress(TextColumn(label), BarColumn(), TextColumn("{task.completed:.1f}/{task.total:.1f} s"),
                    TimeRemainingColumn(), transient=True, disable=not sys.stderr.isatty())
