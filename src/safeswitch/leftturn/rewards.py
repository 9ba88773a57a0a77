"""The reward of Eq. 5: ``r = R_ADAS + R_lka + R_v + R_a_lon + R_a_lat``, batched."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import broadcast_flat, jit
from safeswitch.leftturn.config import RewardConfig
from safeswitch.sim.geometry import FloatArray

#: Names of the five terms, in the order of Eq. 5.
REWARD_TERMS: tuple[str, ...] = ("adas", "lka", "speed", "accel_lon", "accel_lat")


@jit
def interpolate(x: float, points: FloatArray, values: FloatArray) -> float:
    """Linear interpolation through ``(points, values)``, constant beyond the ends: ``np.interp``
    for one value, with its arithmetic (the same bits)."""
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
    return _term(config, "speed", speed=speed)


def lane_keeping_reward(config: RewardConfig, lateral: FloatArray) -> FloatArray:
    """``R_lka`` of the signed lateral deviation from the route [m]."""
    return _term(config, "lka", lateral=lateral)


def accel_lon_reward(config: RewardConfig, accel: FloatArray) -> FloatArray:
    """``R_a_lon`` of the longitudinal acceleration [m/s²]."""
    return _term(config, "accel_lon", accel_lon=accel)


def accel_lat_reward(config: RewardConfig, accel: FloatArray) -> FloatArray:
    """``R_a_lat`` of the lateral acceleration [m/s²]."""
    return _term(config, "accel_lat", accel_lat=accel)


def adas_reward(
    config: RewardConfig, safety_active: NDArray[np.bool_], enabled: bool = True
) -> FloatArray:
    """``R_ADAS`` (Eq. 4): the penalty on ticks where the safety action was executed."""
    return _term(config, "adas", safety_active=safety_active, adas_enabled=enabled)


def _term(config: RewardConfig, name: str, **given: Any) -> FloatArray:
    """One term of :func:`reward_terms` (its other inputs at zero)."""
    inputs: dict[str, Any] = {
        "speed": 0.0,
        "lateral": 0.0,
        "accel_lon": 0.0,
        "accel_lat": 0.0,
        "safety_active": False,
        "adas_enabled": True,
    }
    return reward_terms(config, **(inputs | given))[name]


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
    shape, (lat, v, lon, alat, _) = broadcast_flat(
        lateral, speed, accel_lon, accel_lat, np.zeros(np.shape(safety_active))
    )
    active = np.ascontiguousarray(np.broadcast_to(safety_active, shape), dtype=np.bool_)
    out = tuple(np.empty(shape) for _ in REWARD_TERMS)
    _map_terms(
        reward_tables(config),
        config.adas_penalty if adas_enabled else 0.0,
        active.reshape(-1), lat, v, lon, alat,
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
