"""The reward of Eq. 5: ``r = R_ADAS + R_lka + R_v + R_a_lon + R_a_lat``, batched."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.switching import intervention_penalty
from safeswitch.leftturn.config import RewardConfig
from safeswitch.sim.geometry import FloatArray

#: Names of the five terms, in the order of Eq. 5.
REWARD_TERMS: tuple[str, ...] = ("adas", "lka", "speed", "accel_lon", "accel_lat")


def piecewise_linear(
    x: FloatArray, points: tuple[float, ...], values: tuple[float, ...]
) -> FloatArray:
    """Linear interpolation through ``(points, values)``, constant beyond the ends."""
    return np.interp(x, points, values)


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
    return {
        "adas": adas_reward(config, safety_active, adas_enabled),
        "lka": lane_keeping_reward(config, lateral),
        "speed": speed_reward(config, speed),
        "accel_lon": accel_lon_reward(config, accel_lon),
        "accel_lat": accel_lat_reward(config, accel_lat),
    }
