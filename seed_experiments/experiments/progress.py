"""A minimal progress bar on stderr (no dependency): ``with Progress("table", total) as p: p.update()``."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """Counts work units; redraws at most every ``min_interval_s`` (a line per 5 s if not a TTY)."""

    def __init__(self, label: str, total: int, stream: TextIO | None = None, enabled: bool = True,
                 min_interval_s: float = 0.2, width: int = 30) -> None:
        self.label = label
        self.total = max(int(total), 1)
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.width = width
        self.count = 0
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._interval = min_interval_s if self._tty else 5.0
        self._start = time.perf_counter()
        self._last_draw = -1e9

    def __enter__(self) -> Progress:
        self._start = time.perf_counter()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def elapsed_s(self) -> float:
        return time.perf_counter() - self._start

    def update(self, n: int = 1) -> None:
        self.count = min(self.count + n, self.total)
        now = time.perf_counter()
        if self.enabled and now - self._last_draw >= self._interval:
            self._last_draw = now
            self._draw(final=False)

    def _draw(self, final: bool) -> None:
        frac = self.count / self.total
        filled = int(round(frac * self.width))
        elapsed = self.elapsed_s
        eta = "" if final or frac <= 0.0 else f" eta {elapsed * (1.0 - frac) / frac:5.1f} s"
        line = (f"{self.label:<28} [{'#' * filled}{'.' * (self.width - filled)}] "
                f"{100.0 * frac:5.1f}% {elapsed:6.1f} s{eta}")
        if self._tty:
            self.stream.write("\r" + line + ("\n" if final else "\x1b[K"))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.count = self.total
            self._draw(final=True)
            self.enabled = False
