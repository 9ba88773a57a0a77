"""Learned controllers chosen to break a switching logic: random, reckless, sly and broken.

Each factory returns a :data:`~safeswitch.evaluation.rollout.Policy`. Randomness comes from a
generator seeded by the caller, so every run is reproducible.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from safeswitch.evaluation.rollout import Policy
from safeswitch.leftturn.spaces import speed_tracking_action
from safeswitch.leftturn.task import LeftTurnTask, TaskState

FloatArray = NDArray[np.float64]


def uniform(rng: np.random.Generator) -> Policy:
    """A fresh uniform action in [-1, 1] every tick."""

    def policy(obs: NDArray[np.float32], state: TaskState, tick: int) -> FloatArray:
        return np.asarray(rng.uniform(-1.0, 1.0, int(obs.shape[0])), dtype=np.float64)

    return policy


def bang_bang(rng: np.random.Generator, mean_hold_s: float = 0.5, dt: float = 0.02) -> Policy:
    """Full throttle or none, switching at random times (exponential holds, mean 0.5 s)."""
    memory: dict[str, FloatArray] = {}

    def policy(obs: NDArray[np.float32], state: TaskState, tick: int) -> FloatArray:
        n = obs.shape[0]
        if tick == 0 or "level" not in memory:
            memory["level"] = rng.choice([-1.0, 1.0], n)
        flip = rng.random(n) < dt / mean_hold_s
        memory["level"] = np.where(flip, -memory["level"], memory["level"])
        return memory["level"].copy()

    return policy


def constant(value: float) -> Policy:
    """The same action every tick (+1: full throttle, -1: zero throttle)."""
    return lambda obs, state, tick: np.full(obs.shape[0], value)


def enter_then_stop(task: LeftTurnTask, depth: FloatArray) -> Policy:
    """Full throttle until the ego is ``depth`` metres past its conflict-zone entry (negative:
    before it), then zero throttle: it slows down inside the zone (the paper logic's blind
    spot). ``depth`` is per episode ``[B]`` — a sweep of timings."""
    entry = task.conflict.zone_a[0]

    def policy(obs: NDArray[np.float32], state: TaskState, tick: int) -> FloatArray:
        return np.where(state.world.progress[:, 0] < entry + depth, 1.0, -1.0)

    return policy


def creep(task: LeftTurnTask, target_speed: float = 1.5, from_m: float = 15.0) -> Policy:
    """Cruises at the speed limit until ``from_m`` metres before the conflict zone, then creeps
    into and through it at walking pace (P control around the throttle that holds each speed)."""
    limit = task.config.controllers.speed_limit
    entry = task.conflict.zone_a[0]

    def policy(obs: NDArray[np.float32], state: TaskState, tick: int) -> FloatArray:
        near = state.world.progress[:, 0] > entry - from_m
        target = np.where(near, target_speed, limit)
        return speed_tracking_action(task.config.vehicle, target, obs[:, 2], 0.5)

    return policy


def broken(rng: np.random.Generator, p_invalid: float = 0.3) -> Policy:
    """Outputs NaN, +inf or -inf on a random 30 % of ticks, uniform actions otherwise."""

    def policy(obs: NDArray[np.float32], state: TaskState, tick: int) -> FloatArray:
        n = int(obs.shape[0])
        action = np.asarray(rng.uniform(-1.0, 1.0, n), dtype=np.float64)
        bad = np.asarray(rng.random(n) < p_invalid)
        action[bad] = rng.choice([np.nan, np.inf, -np.inf], int(bad.sum()))
        return action

    return policy


def with_invalid(policy: Policy, rng: np.random.Generator, p_invalid: float = 0.3) -> Policy:
    """``policy`` with NaN in place of its action on a random ``p_invalid`` of ticks (a broken
    network or sensor pipeline); the rest of its behaviour unchanged."""

    def broken_policy(obs: NDArray[np.float32], state: TaskState, tick: int) -> FloatArray:
        action = np.array(policy(obs, state, tick), dtype=np.float64)
        action[rng.random(action.shape[0]) < p_invalid] = np.nan
        return action

    return broken_policy


def noisy_cruise(task: LeftTurnTask, rng: np.random.Generator, sigma: float = 0.5) -> Policy:
    """A sensible driver (P control to the speed limit) with Gaussian action noise."""
    target = task.config.controllers.speed_limit

    def policy(obs: NDArray[np.float32], state: TaskState, tick: int) -> FloatArray:
        action = speed_tracking_action(task.config.vehicle, target, obs[:, 2], 0.5)
        noise = rng.normal(0.0, sigma, obs.shape[0]) if sigma > 0 else 0.0
        return np.clip(action + noise, -1.0, 1.0)

    return policy


def noisy_trained(
    act: Callable[[NDArray[np.float32]], FloatArray], rng: np.random.Generator, sigma: float = 0.5
) -> Policy:
    """A trained policy (``act``: observations ``[B, 6]`` → actions ``[B]``) with large
    Gaussian noise on every action."""

    def policy(obs: NDArray[np.float32], state: TaskState, tick: int) -> FloatArray:
        noise = rng.normal(0.0, sigma, obs.shape[0])
        return np.clip(act(obs) + noise, -1.0, 1.0)

    return policy


def catalogue(
    task: LeftTurnTask,
    batch: int,
    seed: int,
    trained: Callable[[NDArray[np.float32]], FloatArray] | None = None,
) -> dict[str, Callable[[], Policy]]:
    """Every adversary, by name, as a zero-argument factory (fresh state and generator);
    ``noisy_trained`` only when a trained policy's ``act`` is given."""
    depth = np.linspace(-3.0, 10.0, batch)  # the sweep of "stop inside" timings
    found: dict[str, Callable[[], Policy]] = {
        "uniform": lambda: uniform(np.random.default_rng(seed)),
        "bang_bang": lambda: bang_bang(np.random.default_rng(seed + 1), dt=task.config.episode.dt),
        "full_throttle": lambda: constant(1.0),
        "zero_throttle": lambda: constant(-1.0),
        "enter_then_stop": lambda: enter_then_stop(task, depth),
        "creep": lambda: creep(task),
        "nan_inf": lambda: broken(np.random.default_rng(seed + 2)),
        "noisy_cruise": lambda: noisy_cruise(task, np.random.default_rng(seed + 3)),
    }
    if trained is not None:
        found["noisy_trained"] = lambda: noisy_trained(trained, np.random.default_rng(seed + 4))
    return found
