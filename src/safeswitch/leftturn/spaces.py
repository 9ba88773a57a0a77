"""Observation and action spaces of the left-turn environments (SPEC §4)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from safeswitch.leftturn.task import OBSERVATION_HIGH, OBSERVATION_LOW
from safeswitch.sim.geometry import FloatArray
from safeswitch.sim.params import VehicleParams
from safeswitch.sim.vehicle import steady_state_throttle


def observation_space(task: Any = None) -> spaces.Box:
    """``(x_e, y_e, v_e, x_n, y_n, v_n)`` [m, m, m/s, m, m, m/s], float32 — followed, for a
    task in traffic, by its nearest other vehicles (``task.observation_bounds``)."""
    if task is None:
        return spaces.Box(OBSERVATION_LOW, OBSERVATION_HIGH, dtype=np.float32)
    low, high = task.observation_bounds
    return spaces.Box(low, high, dtype=np.float32)


def action_space() -> spaces.Box:
    """One number in [-1, 1]; throttle = (a + 1) / 2 (the paper's meaning; see
    :meth:`~safeswitch.leftturn.task.LeftTurnTask.learned_pedals` for the others)."""
    return spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)


def speed_tracking_action(
    vehicle: VehicleParams,
    target: FloatArray | float,
    speed: NDArray[Any],
    gain: float,
) -> NDArray[Any]:
    """The action whose throttle tracks ``target`` [m/s]: the throttle that holds it on a level
    road plus ``gain`` per m/s of error, within [0, 1] (how the scripted learned controllers —
    the planner, the adversaries' cruises — drive). A scalar target is used as a Python float,
    so a float32 ``speed`` (an observation) keeps float32 arithmetic."""
    goal: Any = float(target) if np.ndim(target) == 0 else target
    held = steady_state_throttle(vehicle, np.asarray(goal, dtype=np.float64))
    base: Any = float(held) if np.ndim(target) == 0 else held
    throttle = np.clip(base + gain * (goal - speed), 0.0, 1.0)
    return np.asarray(2.0 * throttle - 1.0)


def throttle_driver(controllers: Any, who: str) -> Callable[[FloatArray], FloatArray]:
    """How a scripted driver whose actions are the paper's throttles, ``(a + 1) / 2`` (the
    planners, the refinement's structured drivers, a warm start's teacher; ``who`` names it),
    drives a scene with ``controllers``: the returned function maps its actions to the
    scene's learned action that works the pedals the same way — unchanged for the paper's
    action, ``(a + 1) / 2`` with ``controllers.learned_brake`` (the same throttle; the brake
    never used).

    Raises:
        ValueError: the scene's action is a speed set point
            (``controllers.learned_speed_command_kmh``), which no throttle maps to; the
            message names the setting.
    """
    if controllers.learned_speed_command_kmh is not None:
        raise ValueError(
            f"{who} drives with throttle actions, (a + 1) / 2; this scene's learned action is "
            f"a speed set point (controllers.learned_speed_command_kmh="
            f"{controllers.learned_speed_command_kmh:g})"
        )
    if controllers.learned_brake:
        return _throttle_as_pedals
    return _same_action


def _same_action(actions: FloatArray) -> FloatArray:
    return actions


def _throttle_as_pedals(actions: FloatArray) -> FloatArray:
    """The paper's action as both pedals' (``learned_brake``): throttle ``(a + 1) / 2``."""
    return (np.asarray(actions) + 1.0) / 2.0


def throttle_scene(config: Any) -> Any:
    """``config`` (a :class:`~safeswitch.leftturn.config.LeftTurnConfig`) with the paper's
    learned action: where a scripted driver checks its own throttle drives
    (:func:`throttle_driver`) on a copy of a scene whose learned action works both pedals."""
    if not config.controllers.learned_brake:
        return config
    return replace(config, controllers=replace(config.controllers, learned_brake=False))
