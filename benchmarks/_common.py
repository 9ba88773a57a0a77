"""Helpers shared by the benchmark scripts: single-threaded numeric libraries, timing, output."""

from __future__ import annotations

import datetime
import json
import multiprocessing
import os
import platform
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

# One core: pin every numeric library before it is imported anywhere.
for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def pool(workers: int) -> ProcessPoolExecutor:
    """A pool of ``workers`` (at least one) spawned processes, not forked ones: a fork of a
    process whose threads hold locks (Ray's, torch's: an earlier run in the same process may have
    started them) can crash or hang. A worker imports the script's module by name, so what it
    runs must live at a module's top level."""
    return ProcessPoolExecutor(max(1, workers), mp_context=multiprocessing.get_context("spawn"))


def machine() -> dict[str, object]:
    """What a timing was measured on: the same computation has taken up to twice as long on one
    day of this project's machine as on another, so every result says which CPU and when."""
    return {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpu": cpu_model(),
        "simd": cpu_simd(),
        "cpus": os.cpu_count(),
        "threads": 1,
        "date": datetime.date.today().isoformat(),
    }


def cpuinfo_fields(cpuinfo: str | None = None) -> dict[str, str] | None:
    """The fields of Linux's ``/proc/cpuinfo`` (or of ``cpuinfo`` given), by name (a field the
    CPUs repeat: the last one's); ``None`` where it cannot be read."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text(encoding="utf-8")
        except OSError:
            return None
    pairs = (line.split(":", 1) for line in cpuinfo.splitlines() if ":" in line)
    return {key.strip(): value.strip() for key, value in pairs}


def cpu_model() -> str:
    """The CPU's model name and current clock (Linux's ``/proc/cpuinfo``), else the platform's
    processor string."""
    fields = cpuinfo_fields()
    if fields is None:
        return platform.processor() or "unknown"
    name = fields.get("model name", platform.processor() or "unknown")
    mhz = fields.get("cpu MHz")
    return f"{name} @ {float(mhz):.0f} MHz" if mhz else name


#: The vector instruction sets numpy's and torch's CPU kernels choose between at run time: two
#: CPUs of one model name with different sets round differently in the last bits (docs/
#: training.md, "Reproducing a run").
SIMD_FLAGS = ("avx2", "avx512f", "avx512_bf16", "avx512_fp16", "amx_tile")


def cpu_simd(cpuinfo: str | None = None) -> list[str]:
    """Which of :data:`SIMD_FLAGS` the CPU offers (the ``flags`` of Linux's ``/proc/cpuinfo``,
    or ``cpuinfo`` given; empty where it cannot be read)."""
    offered = set(((cpuinfo_fields(cpuinfo) or {}).get("flags") or "").split())
    return [flag for flag in SIMD_FLAGS if flag in offered]


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


def export_revision(root: Path, revision: str, folder: Path, paths: tuple[str, ...]) -> Path:
    """``paths`` (e.g. ``src``) of the git ``revision`` of the checkout at ``root``, unpacked
    into ``folder``; returns ``folder``."""
    import subprocess
    import tarfile

    archive = folder / "tree.tar"
    with open(archive, "wb") as handle:
        subprocess.run(
            ["git", "-C", str(root), "archive", "--format=tar", revision, *paths],
            stdout=handle,
            check=True,
        )
    with tarfile.open(archive) as tar:
        tar.extractall(folder, filter="data")
    return folder
