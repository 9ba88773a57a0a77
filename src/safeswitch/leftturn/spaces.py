"""Observation and action spaces of the left-turn environments (SPEC §4)."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from safeswitch.leftturn.task import OBSERVATION_HIGH, OBSERVATION_LOW


def observation_space() -> spaces.Box:
    """``(x_e, y_e, v_e, x_n, y_n, v_n)`` [m, m, m/s, m, m, m/s], float32."""
    return spaces.Box(OBSERVATION_LOW, OBSERVATION_HIGH, dtype=np.float32)


def action_space() -> spaces.Box:
    """One number in [-1, 1]; throttle = (a + 1) / 2."""
    return spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
