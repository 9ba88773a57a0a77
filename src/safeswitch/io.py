"""Writing run outputs so that a reader never sees half a file (no torch, no SB3 here)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any


def write_atomic(path: str | Path, text: str) -> None:
    """Write a text file so that readers see either nothing or all of it (a temporary file
    beside it, then an atomic rename)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """:func:`write_atomic` for binary content."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


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
