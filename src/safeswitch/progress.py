"""Progress of long work: a bar on a terminal, plain periodic lines otherwise."""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO


class Progress:
    """Count of items done out of ``total``.

    On a terminal: a tqdm bar (count, rate, ETA). Otherwise (a log file, CI): one line every
    ``every`` seconds and one at the end, so a long job is never silent. ``enabled=False``
    prints nothing.

    Args:
        total: Items to do.
        label: What is being done (``"evaluate rule"``).
        unit: What an item is (``"episodes"``).
        enabled: Print anything at all.
        stream: Where to print (standard error by default).
        every: Seconds between plain lines.
    """

    def __init__(
        self,
        total: int,
        label: str,
        unit: str = "episodes",
        enabled: bool = True,
        stream: TextIO | None = None,
        every: float = 10.0,
    ) -> None:
        self.total, self.label, self.unit = total, label, unit
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.every = every
        self.done = 0
        self._started = self._last = time.perf_counter()
        self._bar: Any = None
        if enabled and getattr(self.stream, "isatty", lambda: False)():
            from tqdm import tqdm

            self._bar = tqdm(total=total, desc=label, unit=f" {unit}", file=self.stream)

    def update(self, count: int) -> None:
        self.done += count
        if self._bar is not None:
            self._bar.update(count)
            return
        now = time.perf_counter()
        if self.enabled and now - self._last >= self.every:
            self._last = now
            self._line(now)

    def _line(self, now: float) -> None:
        elapsed = max(now - self._started, 1e-9)
        rate = self.done / elapsed
        left = (self.total - self.done) / rate if rate > 0 else float("inf")
        eta = f", ETA {left:,.0f} s" if self.done < self.total else ""
        print(
            f"{self.label}: {self.done:,}/{self.total:,} {self.unit} ({rate:,.0f}/s{eta})",
            file=self.stream,
            flush=True,
        )

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        elif self.enabled:
            self._line(time.perf_counter())
