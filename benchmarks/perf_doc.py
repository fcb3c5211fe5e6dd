"""docs/performance.md, written by the benchmarks: one table, a row per figure.

``write_row(figure, value, peer)`` replaces the row of that figure (or adds it) with the
command that produced it (this process's command line), the value, the peer measured in the
same run, the date and the machine's load. The table comes first; sections written by hand
may follow it.
"""

from __future__ import annotations

import contextlib
import datetime
import os
import shlex
import sys
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "performance.md"
HEADER = """# Performance

Written by the benchmarks in `benchmarks/` with `--doc`: one row per figure, replaced when its
benchmark runs again. The machine is shared (2 cores); compare a value with its peer from the
same run, and look at the load average.

| figure | command | value | peer (same run) | date, load |
|---|---|---|---|---|
"""


def command_line() -> str:
    script = Path(sys.argv[0])
    with contextlib.suppress(ValueError):
        script = script.resolve().relative_to(DOC.parents[1])
    return shlex.join(["python", str(script), *sys.argv[1:]])


def write_row(figure: str, value: str, peer: str) -> Path:
    """Replace (or add) the row of ``figure`` in docs/performance.md."""
    lines = (DOC.read_text() if DOC.exists() else HEADER).rstrip("\n").split("\n")
    stamp = f"{datetime.date.today().isoformat()}, {os.getloadavg()[0]:.1f}"
    row = f"| {figure} | `{command_line()}` | {value} | {peer} | {stamp} |"
    key = f"| {figure} |"
    for i, line in enumerate(lines):
        if line.startswith(key):
            lines[i] = row
            break
    else:  # after the last row of the first table (hand-written tables may follow)
        first = next(i for i, line in enumerate(lines) if line.startswith("|"))
        last = first
        while last + 1 < len(lines) and lines[last + 1].startswith("|"):
            last += 1
        lines.insert(last + 1, row)
    DOC.write_text("\n".join(lines) + "\n")
    return DOC
