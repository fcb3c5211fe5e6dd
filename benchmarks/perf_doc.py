"""docs/performance.md, written by the benchmarks: each owns one section, replaced on ``--doc``.

A section starts with the machine it ran on (CPU, load average, versions) and the command
that produced it, so every figure in the file says where it came from.
"""

from __future__ import annotations

import contextlib
import os
import platform
import re
import shlex
import sys
from importlib import metadata
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "performance.md"
HEADER = """# Performance

Written by the benchmarks in `benchmarks/` (`--doc`); each section below is replaced when its
benchmark runs again. The machine is shared (2 cores, other jobs running): read the ratios
against the peer measured in the same run; the load average says how busy the machine was.
"""


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "-"


def machine_line() -> str:
    """CPU, core count, load average and the versions that set the figures."""
    load = " ".join(f"{v:.1f}" for v in os.getloadavg())
    versions = ", ".join(f"{d} {_version(d)}" for d in ("numpy", "numba", "rclpy"))
    return (f"{_cpu_model()}, {os.cpu_count()} CPUs, load average {load}; "
            f"Python {platform.python_version()}, {versions}")


def command_line() -> str:
    script = Path(sys.argv[0])
    with contextlib.suppress(ValueError):
        script = script.resolve().relative_to(DOC.parents[1])
    return shlex.join(["python", str(script), *sys.argv[1:]])


def write_section(name: str, title: str, body: str) -> Path:
    """Replace (or append) section ``name`` of docs/performance.md with ``body``."""
    text = DOC.read_text() if DOC.exists() else HEADER
    block = (f"<!-- begin {name} -->\n## {title}\n\n`{command_line()}`\n\n"
             f"Machine: {machine_line()}.\n\n{body.rstrip()}\n<!-- end {name} -->\n")
    pattern = re.compile(rf"<!-- begin {re.escape(name)} -->.*?<!-- end {re.escape(name)} -->\n", re.S)
    text = pattern.sub(lambda _: block, text) if pattern.search(text) else text.rstrip() + "\n\n" + block
    DOC.write_text(text)
    return DOC
