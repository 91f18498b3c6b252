"""A terminal progress bar: one redrawn line on a terminal, one line per update elsewhere."""

from __future__ import annotations

import math
import sys
import time
from typing import TextIO


def duration(seconds: float) -> str:
    """``1h02m``, ``4m05s``, ``12s`` or ``--`` when unknown."""
    if not math.isfinite(seconds) or seconds < 0:
        return "--"
    s = round(seconds)
    if s >= 3600:
        return f"{s // 3600}h{s % 3600 // 60:02d}m"
    if s >= 60:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s}s"


class ProgressBar:
    """``[#####-----]  512/1024 frames  <extra>  ETA 1m05s`` for a count going to ``total``.

    The rate (and so the ETA) counts from ``start`` units at construction (a resumed training
    starts above zero).
    """

    def __init__(self, total: int, unit: str, start: int = 0, stream: TextIO | None = None,
                 enabled: bool = True, width: int = 24):
        self.total, self.unit, self.width, self.enabled = total, unit, width, enabled
        self.stream = sys.stdout if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0, self.start = time.perf_counter(), start

    def rate(self, n: int) -> float:
        """Units per second of wall time since construction."""
        wall = time.perf_counter() - self.t0
        return (n - self.start) / wall if wall > 0 else 0.0

    def line(self, n: int, extra: str = "") -> str:
        rate = self.rate(n)
        frac = min(1.0, n / self.total) if self.total else 1.0
        fill = round(frac * self.width)
        eta = (self.total - n) / rate if rate > 0 else math.inf
        digits = len(str(self.total))
        return (f"[{'#' * fill}{'-' * (self.width - fill)}] {n:{digits}d}/{self.total} "
                f"{self.unit}  {extra}  {rate:.1f} {self.unit}/s  ETA {duration(eta)}")

    def update(self, n: int, extra: str = "") -> None:
        if not self.enabled:
            return
        text = self.line(n, extra)
        if self.tty:
            self.stream.write("\r" + text + "\x1b[K")
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()
