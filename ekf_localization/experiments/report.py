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
    """CPU count and load at the time of writing (the wall times depend on both)."""
    try:
        load = os.getloadavg()
        load_s = f"load average {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} (1 / 5 / 15 min)"
    except OSError:  # pragma: no cover - not on Linux
        load_s = "load average unknown"
    py = f"{platform.python_implementation()} {platform.python_version()}"
    return f"{os.cpu_count()} CPU cores, {py}, {load_s}"


def write_report(sections: Sequence[Section], out_dir: Path, header_markdown: str) -> Path:
    """Write ``results.md`` (the header, a wall-time summary, then every section)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    lines = [header_markdown.rstrip(), ""]
    timing_rows = [[s.title, k, f"{v:.2f}"] for s in sections for k, v in s.wall_times_s.items()]
    if timing_rows:
        lines += ["## Wall times", "",
                  f"Measured on this machine ({machine_note()}, at "
                  f"{datetime.datetime.now().astimezone():%Y-%m-%d %H:%M %Z}).", "",
                  markdown_table(["experiment", "part", "wall time (s)"], timing_rows, ["l", "l", "r"]),
                  ""]
    for s in sections:
        lines += [f"## {s.title}", "", s.markdown.rstrip(), ""]
    path = out_dir / "results.md"
    path.write_text("\n".join(lines))
    return path
