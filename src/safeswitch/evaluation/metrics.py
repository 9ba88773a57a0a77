"""Summary figures of a batch of episodes (the fields of ``safeswitch evaluate --json``).

Fields:
    episodes: Episodes evaluated.
    collisions: Episodes that ended in a collision.
    safety_activation_episodes: Episodes in which a safety action was executed at least once.
    safety_activation_steps: Ticks, over all episodes, on which a safety action was executed.
    mean_time_to_clear_s: Mean time until the ego left its conflict zone [s] (episodes where
        it did).
    comfort_violation_steps: Ticks beyond a comfort limit (|a_lon| > 5 or |a_lat| > 3 m/s²).
    comfort_violation_fraction: The same as a share of all ticks.
    stops: Episodes in which the ego came to a full stop (speed below 0.1 m/s).
    cut_episodes / yield_episodes: Episodes in which the ego crossed before / after the north car.
    mean_return: Mean episode return.
    mean_terms: Each reward term of Eq. 5, summed per episode, mean over episodes.
    mean_min_speed_kmh: Mean over episodes of the lowest ego speed [km/h].
    max_accel_lon / max_accel_lat: Largest |a_lon| and |a_lat| of any episode [m/s²].
    max_lateral_deviation_m: Largest distance from the route's centre line [m].
    ticks: Ticks simulated (all episodes).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from safeswitch.evaluation.rollout import RolloutResult

#: Speed below which the ego counts as stopped [m/s].
STOP_SPEED = 0.1


def summarize(result: RolloutResult) -> dict[str, Any]:
    """The documented summary of a :class:`RolloutResult`."""
    cleared = result.time_to_clear[np.isfinite(result.time_to_clear)]
    ticks = int(result.ticks.sum())
    return {
        "episodes": int(result.collision.size),
        "collisions": int(result.collision.sum()),
        "safety_activation_episodes": int((result.safety_steps > 0).sum()),
        "safety_activation_steps": int(result.safety_steps.sum()),
        "mean_time_to_clear_s": float(cleared.mean()) if cleared.size else float("nan"),
        "comfort_violation_steps": int(result.comfort_violation_steps.sum()),
        "comfort_violation_fraction": result.comfort_violation_steps.sum() / max(ticks, 1),
        "stops": int((result.min_speed < STOP_SPEED).sum()),
        "cut_episodes": int((result.outcome == 1).sum()),
        "yield_episodes": int((result.outcome == 2).sum()),
        "mean_return": float(result.episode_return.mean()),
        "mean_terms": {name: float(v.mean()) for name, v in result.terms.items()},
        "mean_min_speed_kmh": float(result.min_speed.mean() * 3.6),
        "max_accel_lon": float(result.max_accel_lon.max()),
        "max_accel_lat": float(result.max_accel_lat.max()),
        "max_lateral_deviation_m": float(result.max_lateral.max()),
        "ticks": ticks,
    }
