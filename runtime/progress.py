"""A dependency-free progress line on stderr for long jobs (corpus making, conversion)."""

from __future__ import annotations

import sys
import time


class Progress:
    """`label: done/total (pct) rate/s ETA`, redrawn in place on a terminal and printed about
    every 10% otherwise (logs and CI)."""

    def __init__(self, total: int, label: str, enabled: bool = True, unit: str = "clips"):
        self.total = max(total, 1)
        self.label = label
        self.unit = unit
        self.enabled = enabled
        self.done = 0
        self.start = time.perf_counter()
        self._last_draw = 0.0
        self._last_decile = -1
        self._tty = sys.stderr.isatty()

    def update(self, n: int = 1) -> None:
        self.done += n
        if not self.enabled:
            return
        now = time.perf_counter()
        if self._tty:
            if now - self._last_draw >= 0.2 or self.done >= self.total:
                self._last_draw = now
                print(f"\r{self._line(now)}", end="", file=sys.stderr, flush=True)
        else:
            decile = 10 * self.done // self.total
            if decile != self._last_decile:
                self._last_decile = decile
                print(self._line(now), file=sys.stderr, flush=True)

    def close(self) -> float:
        """End the line; returns the elapsed seconds."""
        elapsed = time.perf_counter() - self.start
        if self.enabled and self._tty:
            print(f"\r{self._line(time.perf_counter())}", file=sys.stderr, flush=True)
        return elapsed

    def _line(self, now: float) -> str:
        elapsed = max(now - self.start, 1e-9)
        rate = self.done / elapsed
        eta = (self.total - self.done) / rate if rate > 0 else float("inf")
        return (
            f"{self.label}: {self.done}/{self.total} ({100 * self.done / self.total:.0f}%) "
            f"{rate:.1f} {self.unit}/s, elapsed {elapsed:.0f}s, eta {eta:.0f}s"
        )
