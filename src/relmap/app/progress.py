"""Progress shown on a terminal (standard error), silent otherwise (pipes, files, CI)."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["TerminalProgress"]


class TerminalProgress:
    """Rewrites one status line on standard error while work goes on, when it is a terminal.

    ``update(text)`` shows the text (at most every ``interval`` seconds); ``close()`` clears it.
    """

    def __init__(self, label: str, *, stream: TextIO | None = None, interval: float = 0.1) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)())
        self.label = label
        self.interval = interval
        self._last = 0.0
        self._start = time.perf_counter()
        self._width = 0

    def update(self, text: str, *, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if not force and now - self._last < self.interval:
            return
        self._last = now
        line = f"{self.label}: {text} ({now - self._start:.1f} s)"
        self.stream.write("\r" + line.ljust(self._width))
        self.stream.flush()
        self._width = len(line)

    def close(self) -> None:
        if self.enabled and self._width:
            self.stream.write("\r" + " " * self._width + "\r")
            self.stream.flush()
