"""The results note: Markdown sections from each experiment, written to ``<out>/results.md``
with the figures in ``<out>/results/``."""

from __future__ import annotations

import datetime
import os
import platform
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

FIGURE_DIR = "results"


@dataclass
class Section:
    """One experiment's part of the note: Markdown body, the figures it wrote, wall times (s)."""

    title: str
    markdown: str
    figures: list[Path] = field(default_factory=list)
    wall_times_s: dict[str, float] = field(default_factory=dict)
    measured_on: str = ""  # machine and load when the wall times were taken (:func:`load_note`)


def fmt(value: float, digits: int = 4) -> str:
    """A number for a table: fixed digits, '—' for NaN."""
    if value != value:  # NaN
        return "—"
    return f"{value:.{digits}f}"


def percent_change(new: float, old: float) -> str:
    """'+12%' / '−34%' of new against old."""
    if old == 0.0 or old != old or new != new:
        return "—"
    p = 100.0 * (new - old) / old
    digits = 1 if abs(p) < 10.0 else 0
    return f"{'+' if p >= 0 else '−'}{abs(p):.{digits}f}%"


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]],
                   align: Sequence[str] | None = None) -> str:
    """A GitHub-flavoured Markdown table; ``align`` entries are 'l' or 'r' (default: first l, rest r)."""
    n = len(header)
    if align is None:
        align = ["l"] + ["r"] * (n - 1)
    rule = [":---" if a == "l" else "---:" for a in align]
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(rule) + " |"]
    for r in rows:
        if len(r) != n:
            raise ValueError(f"row has {len(r)} cells, header has {n}: {r}")
        lines.append("| " + " | ".join(r) + " |")
    return "\n".join(lines)


def figure_link(path: Path, out_dir: Path, caption: str) -> str:
    """Markdown image reference relative to the note."""
    rel = os.path.relpath(path, out_dir)
    return f"![{caption}]({rel})\n\n*{caption}*"


def machine_note() -> str:
    """CPU count and Python (the wall times depend on both)."""
    return f"{os.cpu_count()} CPU cores, {platform.python_implementation()} {platform.python_version()}"


def load_note() -> str:
    """The 1-minute load average and the time now: when a wall time was measured."""
    try:
        load = f"load {os.getloadavg()[0]:.2f}"
    except OSError:  # pragma: no cover - not on Linux
        load = "load unknown"
    return f"{load}, {datetime.datetime.now().astimezone():%Y-%m-%d %H:%M}"


def write_report(sections: Sequence[Section], out_dir: Path, header_markdown: str) -> Path:
    """Write ``results.md`` (the header, a wall-time summary, then every section)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    lines = [header_markdown.rstrip(), ""]
    timing_rows = [[s.title, k, f"{v:.2f}", s.measured_on] for s in sections
                   for k, v in s.wall_times_s.items()]
    if timing_rows:
        lines += ["## Wall times", "",
                  f"Measured on this machine ({machine_note()}), shared with other work: the load "
                  "column is the 1-minute load average when the part ran (2.0 = both cores busy). "
                  "Start-up (imports, caches) is excluded: a short warm-up run first.", "",
                  markdown_table(["experiment", "part", "wall time (s)", "measured at"], timing_rows,
                                 ["l", "l", "r", "l"]),
                  ""]
    for s in sections:
        lines += [f"## {s.title}", "", s.markdown.rstrip(), ""]
    path = out_dir / "results.md"
    path.write_text("\n".join(lines))
    return path
