"""Progress in a log: when stderr is not a terminal (a farm's log file), a one-line
report every FGEN_PROGRESS_SECONDS (default 30) and at the end, instead of a progress
bar. Same interface as the tqdm bar it replaces (update, close)."""
from __future__ import annotations

import os
import sys
import time


def wants_log(stream=None) -> bool:
    """True when `stream` (stderr) is not a terminal."""
    stream = sys.stderr if stream is None else stream
    try:
        return not stream.isatty()
    except (AttributeError, ValueError):
        return True


def interval() -> float:
    try:
        return max(0.0, float(os.environ.get("FGEN_PROGRESS_SECONDS", "30")))
    except ValueError:
        return 30.0


class LogProgress:
    def __init__(self, total: int, desc: str, stream=None, every: float | None = None):
        self.total, self.desc, self.n = int(total), desc, 0
        self.stream = sys.stderr if stream is None else stream
        self.every = interval() if every is None else every
        self.t0 = self.last = time.monotonic()
        self.closed = False
        self.shown = -1  # frames done at the last line

    def line(self) -> str:
        el = time.monotonic() - self.t0
        rate = self.n / el if el > 0 else 0.0
        pct = 100.0 * self.n / self.total if self.total else 100.0
        eta = (self.total - self.n) / rate if rate > 0 else float("nan")
        eta_s = f"{eta:.0f} s" if eta == eta else "?"
        return (f"fgen: {self.desc}: {self.n}/{self.total} frames ({pct:.0f}%), "
                f"{rate:.2f} frames/s, elapsed {el:.0f} s, eta {eta_s}")

    def _emit(self) -> None:
        print(self.line(), file=self.stream, flush=True)
        self.last = time.monotonic()
        self.shown = self.n

    def update(self, k: int = 1) -> None:
        self.n += k
        if k and time.monotonic() - self.last >= self.every:
            self._emit()

    def close(self) -> None:
        if not self.closed and self.total and self.shown != self.n:
            self._emit()
        self.closed = True
