"""The reward of Eq. 5: ``r = R_ADAS + R_lka + R_v + R_a_lon + R_a_lat``, batched."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import flat, jit
from safeswitch.core.switching import intervention_penalty
from safeswitch.leftturn.config import RewardConfig
from safeswitch.sim.geometry import FloatArray

#: Names of the five terms, in the order of Eq. 5.
REWARD_TERMS: tuple[str, ...] = ("adas", "lka", "speed", "accel_lon", "accel_lat")


def piecewise_linear(
    x: FloatArray, points: tuple[float, ...], values: tuple[float, ...]
) -> FloatArray:
    """Linear interpolation through ``(points, values)``, constant beyond the ends."""
    x = np.asarray(x, dtype=np.float64)
    out = np.empty(x.shape)
    _map_interpolate(
        np.ascontiguousarray(x).reshape(-1),
        np.asarray(points, dtype=np.float64),
        np.asarray(values, dtype=np.float64),
        out.reshape(-1),
    )
    return out


@jit
def interpolate(x: float, points: FloatArray, values: FloatArray) -> float:
    """:func:`piecewise_linear` of one value, with ``np.interp``'s arithmetic (the same bits)."""
    last = points.shape[0] - 1
    if x <= points[0]:
        return values[0]
    if x >= points[last]:
        return values[last]
    j = 0
    while points[j + 1] <= x:
        j += 1
    slope = (values[j + 1] - values[j]) / (points[j + 1] - points[j])
    return slope * (x - points[j]) + values[j]


@jit
def _map_interpolate(
    x: FloatArray, points: FloatArray, values: FloatArray, out: FloatArray
) -> None:
    for i in range(x.shape[0]):
        out[i] = interpolate(x[i], points, values)


def reward_tables(config: RewardConfig) -> tuple[FloatArray, ...]:
    """The breakpoints and values of R_lka, R_v, R_a_lon and R_a_lat as arrays (what the
    compiled tick reads): ``(points, values)`` of each, in that order."""
    c = config
    pairs = (
        (c.lateral_points_m, c.lateral_values),
        (c.speed_points_kmh, c.speed_values),
        (c.accel_lon_points, c.accel_lon_values),
        (c.accel_lat_points, c.accel_lat_values),
    )
    return tuple(np.asarray(a, dtype=np.float64) for pair in pairs for a in pair)


def speed_reward(config: RewardConfig, speed: FloatArray) -> FloatArray:
    """``R_v`` of a speed [m/s] (breakpoints in km/h)."""
    return piecewise_linear(np.asarray(speed) * 3.6, config.speed_points_kmh, config.speed_values)


def lane_keeping_reward(config: RewardConfig, lateral: FloatArray) -> FloatArray:
    """``R_lka`` of the signed lateral deviation from the route [m]."""
    return piecewise_linear(np.abs(lateral), config.lateral_points_m, config.lateral_values)


def accel_lon_reward(config: RewardConfig, accel: FloatArray) -> FloatArray:
    """``R_a_lon`` of the longitudinal acceleration [m/s²]."""
    return piecewise_linear(np.abs(accel), config.accel_lon_points, config.accel_lon_values)


def accel_lat_reward(config: RewardConfig, accel: FloatArray) -> FloatArray:
    """``R_a_lat`` of the lateral acceleration [m/s²]."""
    return piecewise_linear(np.abs(accel), config.accel_lat_points, config.accel_lat_values)


def adas_reward(
    config: RewardConfig, safety_active: NDArray[np.bool_], enabled: bool = True
) -> FloatArray:
    """``R_ADAS`` (Eq. 4): the penalty on ticks where the safety action was executed."""
    return intervention_penalty(safety_active, config.adas_penalty if enabled else 0.0)


def reward_terms(
    config: RewardConfig,
    *,
    speed: FloatArray,
    lateral: FloatArray,
    accel_lon: FloatArray,
    accel_lat: FloatArray,
    safety_active: NDArray[np.bool_],
    adas_enabled: bool,
) -> dict[str, FloatArray]:
    """All five terms of Eq. 5, each of shape ``[B]``, keyed by :data:`REWARD_TERMS`."""
    values = (lateral, speed, accel_lon, accel_lat, safety_active)
    shape = np.broadcast_shapes(*(np.shape(a) for a in values))
    f = [flat(a, shape) for a in values[:4]]
    active = np.ascontiguousarray(np.broadcast_to(safety_active, shape), dtype=np.bool_)
    out = tuple(np.empty(shape) for _ in REWARD_TERMS)
    _map_terms(
        reward_tables(config),
        config.adas_penalty if adas_enabled else 0.0,
        active.reshape(-1), f[0], f[1], f[2], f[3],
        tuple(a.reshape(-1) for a in out),
    )  # fmt: skip
    return dict(zip(REWARD_TERMS, out, strict=True))


@jit
def tick_terms(
    tables: tuple[FloatArray, ...],
    adas_penalty: float,
    safety_active: bool,
    lateral: float,
    speed: float,
    accel_lon: float,
    accel_lat: float,
) -> tuple[float, float, float, float, float]:
    """The five terms of one tick, in :data:`REWARD_TERMS` order; ``tables`` from
    :func:`reward_tables`, ``adas_penalty`` 0 when R_ADAS is switched off."""
    return (
        adas_penalty if safety_active else 0.0,
        interpolate(abs(lateral), tables[0], tables[1]),
        interpolate(speed * 3.6, tables[2], tables[3]),
        interpolate(abs(accel_lon), tables[4], tables[5]),
        interpolate(abs(accel_lat), tables[6], tables[7]),
    )


@jit
def _map_terms(
    tables: tuple[FloatArray, ...], adas_penalty: float, safety_active: NDArray[np.bool_],
    lateral: FloatArray, speed: FloatArray, accel_lon: FloatArray, accel_lat: FloatArray,
    out: tuple[FloatArray, ...],
) -> None:  # fmt: skip
    for i in range(lateral.shape[0]):
        out[0][i], out[1][i], out[2][i], out[3][i], out[4][i] = tick_terms(
            tables, adas_penalty, safety_active[i], lateral[i], speed[i], accel_lon[i], accel_lat[i]
        )
