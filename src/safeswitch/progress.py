"""Progress of long work: a bar on a terminal, plain periodic lines otherwise."""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO


def format_duration(seconds: float) -> str:
    """A duration as a person reads it: ``42 s``, ``17 min``, ``5.2 h``, ``3.1 days``,
    ``22.6 years``."""
    if seconds != seconds or seconds == float("inf"):
        return "unknown"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 2 * 3600:
        return f"{seconds / 60:.0f} min"
    if seconds < 2 * 86400:
        return f"{seconds / 3600:.1f} h"
    if seconds < 2 * 365.25 * 86400:
        return f"{seconds / 86400:,.1f} days"
    return f"{seconds / (365.25 * 86400):,.1f} years"


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
        self.skipped = 0
        self._started = self._last = time.perf_counter()
        self._bar: Any = None
        if enabled and getattr(self.stream, "isatty", lambda: False)():
            from tqdm import tqdm

            self._bar = tqdm(total=total, desc=label, unit=f" {unit}", file=self.stream)

    def skip(self, count: int) -> None:
        """Items found already done (a resumed job): counted as done, not in the rate."""
        self.skipped += count
        self.done += count
        if self._bar is not None:
            self._bar.update(count)

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
        rate = (self.done - self.skipped) / elapsed
        left = (self.total - self.done) / rate if rate > 0 else float("inf")
        eta = f", ETA {format_duration(left)}" if self.done < self.total else ""
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
