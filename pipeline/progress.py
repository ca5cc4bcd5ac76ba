"""A dependency-free progress line for long runs: bar, count and rate, on stderr."""
from __future__ import annotations

import sys
import time


class Progress:
    """`Progress(total, label)`, then `update(done)`; `close()` ends the line.

    On a terminal the line redraws in place; otherwise (CI logs, pipes) it prints at every 10 %.
    """

    def __init__(self, total: int, label: str, unit: str = "frames", stream=None, enabled: bool = True):
        self.total, self.label, self.unit = max(int(total), 1), label, unit
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start = time.perf_counter()
        self._last_decile = -1
        self._last_draw = 0.0

    def update(self, done: int) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        rate = done / max(now - self.start, 1e-9)
        if self.tty:
            if now - self._last_draw < 0.1 and done < self.total:
                return
            self._last_draw = now
            width = 30
            fill = int(width * done / self.total)
            self.stream.write(f"\r{self.label} [{'#' * fill}{'.' * (width - fill)}] "
                              f"{done}/{self.total} {self.unit} {rate:.1f} {self.unit}/s")
            self.stream.flush()
        else:
            decile = int(10 * done / self.total)
            if decile != self._last_decile:
                self._last_decile = decile
                self.stream.write(f"{self.label}: {done}/{self.total} {self.unit} ({rate:.1f} {self.unit}/s)\n")
                self.stream.flush()

    def __call__(self, done: int, total: int | None = None) -> None:
        """The stages' `progress(done, total)` callback (a total that grows is taken as it comes)."""
        if total is not None:
            self.total = max(int(total), 1)
        self.update(done)

    def close(self) -> None:
        if self.enabled and self.tty and self._last_draw:   # a bar was drawn: end its line
            self.stream.write("\n")
            self.stream.flush()
