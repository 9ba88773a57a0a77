"""Helpers shared by the benchmark scripts: single-threaded numeric libraries, timing, output."""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

# One core: pin every numeric library before it is imported anywhere.
for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def machine() -> dict[str, object]:
    return {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "threads": 1,
    }


def publish(result: dict[str, object], out: Path | None, as_json: bool) -> bool:
    """Write ``result`` to ``out`` (if given) and print it as JSON (if asked); returns whether
    it was printed (the caller then prints no table)."""
    if out is not None:
        from safeswitch.io import write_json  # here: importing safeswitch waits for the pins

        write_json(out, result)
    emit(result, as_json)
    return as_json


def emit(result: dict[str, object], as_json: bool) -> None:
    if as_json:
        print(json.dumps(result, indent=2))
