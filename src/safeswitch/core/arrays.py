"""Small array helpers for hot paths, where numpy's general-purpose functions cost more in
call overhead than the arithmetic they do (``np.clip`` is several times slower than
``np.minimum(np.maximum(...))``, and ``np.stack`` than filling a preallocated array), and the
decorator that compiles scalar per-element code."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import fields
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

A = TypeVar("A", bound=np.generic)
F = TypeVar("F", bound=Callable[..., Any])


def jit(fn: F) -> F:
    """Compile ``fn`` with numba (nopython, machine code cached on disk); typed as ``fn``.

    A kernel that takes a ``NamedTuple`` of arrays takes its arrays out once, before its loop:
    read through the tuple inside the loop (or handed to a helper per element), each array is
    fetched and reference-counted on every access, about ten times slower."""
    return cast(F, numba.njit(cache=True, nogil=True)(fn))


def plain(value: Any) -> Any:
    """A tree of named tuples as plain tuples, for a kernel's compiled entry point.

    numba's dispatcher types a ``NamedTuple`` argument by spelling the name of every field on
    every call (about 0.1 µs a field: 7 µs for the left turn's controller constants, a tenth
    of a single environment's tick), a plain tuple by its values alone. A kernel called on
    every tick takes plain tuples at its entry and names them again inside (``Cls(*values)``
    costs nothing in compiled code)."""
    if isinstance(value, tuple):
        return tuple(plain(v) for v in value)
    return value


def _uncached(fn: F) -> F:
    """Compile ``fn`` with numba without a disk cache: for the loops that take a compiled
    function as an argument. numba keys a cached specialisation on the argument's *type*, and
    a function's type names the function's object, not its code: in a later process another
    function can take its place in the key, and the cache hands back the first one's machine
    code (measured: a campaign of 600 episodes counted 239,758 ticks instead of 359,758). The
    loops themselves compile in a fraction of a second."""
    return cast(F, numba.njit(nogil=True)(fn))


@_uncached
def _each1(fn: Any, k: Any, a: Any, out: Any) -> None:
    for i in range(out.shape[0]):
        out[i] = fn(a[i], k)


@_uncached
def _each2(fn: Any, k: Any, a: Any, b: Any, out: Any) -> None:
    for i in range(out.shape[0]):
        out[i] = fn(a[i], b[i], k)


@_uncached
def _each3(fn: Any, k: Any, a: Any, b: Any, c: Any, out: Any) -> None:
    for i in range(out.shape[0]):
        out[i] = fn(a[i], b[i], c[i], k)


@_uncached
def _each4(fn: Any, k: Any, a: Any, b: Any, c: Any, d: Any, out: Any) -> None:
    for i in range(out.shape[0]):
        out[i] = fn(a[i], b[i], c[i], d[i], k)


_EACH: dict[int, Callable[..., None]] = {1: _each1, 2: _each2, 3: _each3, 4: _each4}


def each(fn: Callable[..., float], constants: Any, *values: ArrayLike) -> NDArray[np.float64]:
    """``fn(v1[i], …, vn[i], constants)`` for every element of the ``values`` broadcast
    together (one to four of them), ``fn`` a compiled scalar function (:func:`jit`): the
    numpy-facing form of the kernels' scalar code, in one compiled loop."""
    shape, flats = broadcast_flat(*values)
    out = np.empty(math.prod(shape))
    _EACH[len(flats)](fn, constants, *flats, out)
    return out.reshape(shape)


def clamp(x: NDArray[A], low: ArrayLike, high: ArrayLike) -> NDArray[A]:
    """Elementwise ``min(max(x, low), high)`` (what ``np.clip`` does, with less overhead)."""
    return np.minimum(np.maximum(x, low), high)


def columns(*arrays: NDArray[Any]) -> NDArray[np.float64]:
    """Stack 1-D arrays of equal length as the columns of a ``[B, k]`` float64 array."""
    out = np.empty((arrays[0].shape[0], len(arrays)))
    for j, a in enumerate(arrays):
        out[:, j] = a
    return out


def broadcast_flat(*values: ArrayLike) -> tuple[tuple[int, ...], list[NDArray[np.float64]]]:
    """The common broadcast shape of ``values`` and each of them :func:`flat` to it."""
    shape = np.broadcast_shapes(*(np.shape(v) for v in values))
    return shape, [flat(v, shape) for v in values]


def flat(values: ArrayLike, shape: tuple[int, ...]) -> NDArray[np.float64]:
    """``values`` broadcast to ``shape`` as a flat, contiguous float64 vector (a view when
    possible): what the compiled per-element loops take."""
    array = np.asarray(values, dtype=np.float64)
    if array.shape == shape:
        return array.reshape(-1)  # a view when contiguous, else a copy
    if array.ndim == 0:
        return np.full(math.prod(shape), array)
    return np.ascontiguousarray(np.broadcast_to(array, shape)).reshape(-1)


def concat_rows(batches: list[Any]) -> Any:
    """Batch dataclasses of one type stacked along their first axis (recursing into dataclass
    fields): the inverse of :func:`take_rows`."""
    first = batches[0]
    values: dict[str, Any] = {}
    for f in fields(first):
        parts = [getattr(b, f.name) for b in batches]
        if parts[0] is None:  # an optional part the batches do not have
            values[f.name] = None
            continue
        values[f.name] = (
            np.concatenate(parts) if isinstance(parts[0], np.ndarray) else concat_rows(parts)
        )
    return type(first)(**values)


def take_rows(batch: Any, rows: NDArray[Any]) -> Any:
    """A copy of a batch dataclass with every array field ``f[rows]`` (indices or a mask;
    repeats allowed), recursing into dataclass fields."""
    values: dict[str, Any] = {}
    for f in fields(batch):
        value = getattr(batch, f.name)
        if value is None:  # an optional part the batch does not have
            values[f.name] = None
            continue
        array = isinstance(value, np.ndarray)
        values[f.name] = value[rows] if array else take_rows(value, rows)
    return type(batch)(**values)


def put_rows(batch: Any, rows: NDArray[Any], source: Any) -> None:
    """``batch.f[rows] = source.f`` for every array field, in place, recursing into dataclass
    fields (optional parts ``batch`` does not have are skipped): the in-place inverse of
    :func:`take_rows`."""
    for f in fields(batch):
        mine, theirs = getattr(batch, f.name), getattr(source, f.name)
        if isinstance(mine, np.ndarray):
            mine[rows] = theirs
        elif mine is not None:
            put_rows(mine, rows, theirs)
