"""A trained actor's deterministic action, computed the same on every CPU (numpy only).

The golden runs (``golden.py``) pin the task's decisions bit for bit, so the learned
controller that drives them must give the same actions on every machine. torch's CPU build
does not: its matrix products go through MKL, whose kernels are chosen by the CPU's
instruction sets and sum in different orders, so the same policy's actions differ in their
last bits between, say, an AVX2 and an AMX machine (seen: 2e-8 relative, every episode
changed). Here every product is a sum of elementwise float64 operations in a fixed order (no
BLAS), and the mean action is rounded to a grid of 2^-20: the float64 results may still differ
by an ulp where numpy's own SIMD tanh differs between CPUs, far too little to move a value
across the grid except with a probability of about 1e-10 per action.

This module imports only numpy so that the recording of ``leftturn_golden_pre_friction.npz``
(``record_pre_friction.py``) runs it beside an older commit's code.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: The grid the mean action is rounded to (a power of two: the rounding is exact).
GRID = 2.0**20


def normalised(obs: NDArray[np.floating], mean: NDArray[np.float64], var: NDArray[np.float64],
               clip: float, epsilon: float) -> NDArray[np.float64]:  # fmt: skip
    """``VecNormalize``'s observation normalisation, in float64 (elementwise: exact IEEE
    operations, the same everywhere)."""
    x = np.asarray(obs, dtype=np.float64)
    return np.clip((x - mean) / np.sqrt(var + epsilon), -clip, clip)


def mean_action(
    layers: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]],
    x: NDArray[np.float64],
    low: float,
    high: float,
) -> NDArray[np.float64]:
    """The actor's mean ``[B]`` for normalised observations ``x`` ``[B, n]``: ``(weight
    [out, in], bias [out])`` per layer, tanh after every layer but the last, the result
    clipped to ``[low, high]`` and rounded to :data:`GRID`."""
    for i, (weight, bias) in enumerate(layers):
        y = np.repeat(bias[None, :], x.shape[0], axis=0)
        for k in range(weight.shape[1]):  # a fixed order of float64 multiply-adds, no BLAS
            y += x[:, k : k + 1] * weight[None, :, k]
        x = np.tanh(y) if i < len(layers) - 1 else y
    mean = np.clip(x[:, 0], low, high)
    return np.rint(mean * GRID) / GRID


def portable_driver(p: Mapping[str, Any]) -> Callable[[Any, Any, int], NDArray[np.float64]]:
    """A rollout policy ``(obs, state, tick) -> actions`` from an actor's float64 arrays:
    ``w0, b0, w1, b1, …`` (weight ``[out, in]`` and bias per layer), the observation
    statistics ``mean``, ``var``, ``clip``, ``epsilon`` and the action bounds ``low``,
    ``high`` (``golden.portable_parameters`` writes them)."""
    count = sum(1 for key in p if key.startswith("w"))
    layers = [(np.asarray(p[f"w{i}"]), np.asarray(p[f"b{i}"])) for i in range(count)]
    mean, var = np.asarray(p["mean"]), np.asarray(p["var"])
    clip, epsilon = float(p["clip"]), float(p["epsilon"])
    low, high = float(p["low"]), float(p["high"])

    def act(obs: Any, state: Any, tick: int) -> NDArray[np.float64]:
        return mean_action(layers, normalised(obs, mean, var, clip, epsilon), low, high)

    return act
