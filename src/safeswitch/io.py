"""Writing run outputs so that a reader never sees half a file (no torch, no SB3 here)."""

from __future__ import annotations

import csv
import json
import os
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` (``.NAME.tmp``) to write a file into: renamed onto
    ``path`` when the block ends, deleted if the block raises or is interrupted (Ctrl-C), so
    that readers see either nothing or all of it and an interrupted run leaves no debris."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_atomic(path: str | Path, text: str) -> None:
    """Write a text file so that readers see either nothing or all of it (:func:`replacing`)."""
    with replacing(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def append_row(path: str | Path, fields: tuple[str, ...], row: dict[str, Any]) -> None:
    """Append ``row`` to the CSV log ``path`` (columns ``fields``; a header first in a new
    file; a column the row lacks left empty): a run's per-rollout logs, one line per write, so
    that a killed run leaves at most its last line short (``--resume`` sets it aside)."""
    path = Path(path)
    new_file = not path.exists()
    with open(path, "a", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields)
        if new_file:
            writer.writeheader()
        writer.writerow({k: row.get(k, "") for k in fields})


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """:func:`write_atomic` for binary content."""
    with replacing(path) as tmp:
        tmp.write_bytes(data)


def write_policy_files(folder: str | Path, model: Any, normalizer: Any) -> None:
    """``folder/model.zip`` and ``folder/vecnormalize.pkl`` (a run's policy), each written whole
    (:func:`replacing`); ``model`` and ``normalizer`` are anything with ``save(path)``."""
    folder = Path(folder)
    with replacing(folder / "model.zip") as tmp:
        model.save(tmp)
    with replacing(folder / "vecnormalize.pkl") as tmp:
        normalizer.save(str(tmp))


#: The files of a policy in a run or snapshot folder (:func:`write_policy_files`).
POLICY_FILES = ("model.zip", "vecnormalize.pkl")


def copy_policy_files(source: str | Path, folder: str | Path) -> None:
    """``source``'s policy files (:data:`POLICY_FILES`) copied into ``folder`` byte for byte,
    each written whole (:func:`replacing`)."""
    for name in POLICY_FILES:
        with replacing(Path(folder) / name) as tmp:
            shutil.copyfile(Path(source) / name, tmp)


def write_snapshot(
    folder: str | Path,
    model: Any,
    normalizer: Any,
    state: dict[str, Any],
    extra: Callable[[Path], None] | None = None,
) -> Path:
    """A policy snapshot ``folder/{model.zip, vecnormalize.pkl, state.json}`` (a checkpoint, the
    best policy so far), written into ``.NAME.tmp`` beside it and renamed whole; the folder it
    replaces is kept until the new one is in place. Interrupted, it leaves the old snapshot
    and no temporary folder. ``model`` and ``normalizer`` are anything with ``save(path)``
    (Stable-Baselines3's models and ``VecNormalize``); ``extra(folder)`` writes further files
    into the temporary folder before it is renamed."""
    folder = Path(folder)
    tmp = folder.with_name(f".{folder.name}.tmp")
    old = folder.with_name(f".{folder.name}.old")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        tmp.mkdir(parents=True)
        model.save(tmp / "model.zip")
        normalizer.save(str(tmp / "vecnormalize.pkl"))
        (tmp / "state.json").write_text(json.dumps(state), encoding="utf-8")
        if extra is not None:
            extra(tmp)
        shutil.rmtree(old, ignore_errors=True)
        if folder.exists():
            os.replace(folder, old)
        os.replace(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if old.exists() and not folder.exists():
            os.replace(old, folder)
        raise
    shutil.rmtree(old, ignore_errors=True)
    return folder


def complete_checkpoints(run: Path) -> list[Path]:
    """The run's checkpoints (``run/checkpoints/step_N``, :func:`write_snapshot`'s) that
    were written whole, oldest first."""
    folder = run / "checkpoints"
    if not folder.is_dir():
        return []
    done = [
        p for p in folder.iterdir() if p.name.startswith("step_") and (p / "state.json").is_file()
    ]
    return sorted(done, key=lambda p: int(p.name.split("_")[1]))


def to_json(value: Any) -> str:
    """Strict JSON (RFC 8259) with a final newline: NaN and infinities become ``null`` (Python's
    ``json`` would write ``NaN``, which ``jq`` and strict parsers reject), numpy scalars and
    arrays plain numbers and lists."""
    return json.dumps(_jsonable(value), indent=2, allow_nan=False) + "\n"


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, str | bytes):  # numpy
        return _jsonable(value.tolist())
    if isinstance(value, float) and (value != value or value in (float("inf"), float("-inf"))):
        return None
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: str | Path, value: Any) -> None:
    """:func:`to_json` written atomically."""
    write_atomic(path, to_json(value))


class OutputDirectoryError(ValueError):
    """An ``--out`` folder cannot be used as asked; the message says why and what to do."""


def prepare_output_dir(path: str | Path, overwrite: bool = False) -> Path:
    """A folder for a command's outputs: created if absent; refused if it is a file, or if it
    holds anything and ``overwrite`` is off (nothing is deleted either way — files the command
    writes are replaced, others are left alone).

    Raises:
        OutputDirectoryError: Naming the folder and the way out.
    """
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise OutputDirectoryError(f"--out {folder} is a file, not a folder; choose another --out")
    if folder.is_dir() and any(folder.iterdir()) and not overwrite:
        raise OutputDirectoryError(
            f"--out {folder} is not empty; choose another --out, or pass --overwrite to replace "
            "the files this command writes there"
        )
    folder.mkdir(parents=True, exist_ok=True)
    return folder
