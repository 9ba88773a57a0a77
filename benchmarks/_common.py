"""Helpers shared by the benchmark scripts: single-threaded numeric libraries, timing, output."""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable

# One core: pin every numeric library before it is imported anywhere.
for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def time_per_call(fn: Callable[[], object], min_seconds: float = 1.0, warmup: int = 3) -> float:
    """Median over repeated timing blocks of the wall time of one call [s]."""
    for _ in range(warmup):
        fn()
    blocks = []
    calls, start = 0, time.perf_counter()
    while True:
        t0 = time.perf_counter()
        fn()
        blocks.append(time.perf_counter() - t0)
        calls += 1
        if time.perf_counter() - start > min_seconds and calls >= 5:
            break
    blocks.sort()
    return blocks[len(blocks) // 2]


def machine() -> dict[str, object]:
    return {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "threads": 1,
    }


def emit(result: dict[str, object], as_json: bool) -> None:
    if as_json:
        print(json.dumps(result, indent=2))
