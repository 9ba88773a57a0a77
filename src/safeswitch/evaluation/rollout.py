"""Batched episodes of the left-turn task under any controller, with per-episode summaries."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from safeswitch.evaluation.surrogate import SurrogateTracker
from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.statistics import EpisodeStatistics
from safeswitch.leftturn.task import LeftTurnTask, StepRecord, TaskState

#: A controller for the rollouts: (observation ``[B, 6]``, task state, tick) → actions ``[B]``
#: in [-1, 1]. Adversaries may read the task state; a learned policy uses the observation only.
Policy = Callable[[NDArray[np.float32], TaskState, int], NDArray[np.float64]]


@dataclass
class RolloutResult:
    """Per-episode results of a batch, each array ``[B]``.

    Attributes:
        collision: The episode ended in a collision.
        lost_control: The episode ended with the ego off its lane (its tyres slid).
        safety_steps: Ticks on which a safety action was executed.
        invalid_steps: Ticks on which the learned action was NaN or infinite.
        min_speed: Lowest ego speed [m/s].
        max_speed: Highest ego speed [m/s].
        speeding_steps: Ticks faster than the tolerated speed (``R_v``'s best, 30 km/h by
            default; :func:`~safeswitch.leftturn.statistics.speeding`).
        time_to_clear: Time until the ego left its conflict zone [s] (NaN if it never did).
        outcome: Who crossed first: 0 never cleared, 1 cut (cleared before the north car left its
            zone), 2 yield (after).
        comfort_violation_steps: Ticks beyond a comfort limit.
        ticks: Episode length in ticks.
        episode_return: Sum of rewards.
        min_separation: Smallest gap between the two footprints [m].
        max_accel_lon: Largest ``|a_lon|`` [m/s²].
        max_accel_lat: Largest ``|a_lat|`` [m/s²].
        max_lateral: Largest ``|lateral deviation|`` from the route [m].
        terms: Each reward term of Eq. 5 summed over the episode, keyed by ``REWARD_TERMS``.
        min_ttc: Smallest time to collision at a conflict zone [s] (``inf``: never on a
            collision course; :mod:`~safeswitch.evaluation.surrogate`).
        min_pet: Smallest post-encroachment time [s] (NaN: no encroachment).
    """

    collision: NDArray[np.bool_]
    lost_control: NDArray[np.bool_]
    safety_steps: NDArray[np.int64]
    invalid_steps: NDArray[np.int64]
    min_speed: NDArray[np.float64]
    max_speed: NDArray[np.float64]
    speeding_steps: NDArray[np.int64]
    time_to_clear: NDArray[np.float64]
    outcome: NDArray[np.int8]
    comfort_violation_steps: NDArray[np.int64]
    ticks: NDArray[np.int64]
    episode_return: NDArray[np.float64]
    min_separation: NDArray[np.float64]
    max_accel_lon: NDArray[np.float64]
    max_accel_lat: NDArray[np.float64]
    max_lateral: NDArray[np.float64]
    terms: dict[str, NDArray[np.float64]]
    min_ttc: NDArray[np.float64]
    min_pet: NDArray[np.float64]


def rollout(
    task: LeftTurnTask,
    scenarios: Scenarios,
    policy: Policy,
    on_tick: Callable[[TaskState, StepRecord, int], None] | None = None,
) -> RolloutResult:
    """Play one episode per scenario, all in one batch, until every episode has ended.

    Args:
        task: The task (its configuration sets the switching logic and the horizon).
        scenarios: One scenario per episode ``[B]``.
        policy: The learned controller (or adversary).
        on_tick: Called after every tick with the new state, the record and the tick index
            (e.g. to break an assumption mid-episode, or to log); the record's observation is
            there only on the tick before a decision (``None`` on the others).
    """
    config: LeftTurnConfig = task.config
    state = task.initial(scenarios)
    batch = state.batch_size
    stats = EpisodeStatistics(batch)
    live = np.ones(batch, dtype=bool)
    invalid = np.zeros(batch, dtype=np.int64)
    min_separation = np.full(batch, np.inf)
    max_lon, max_lat = np.zeros(batch), np.zeros(batch)
    ended_outcome = np.zeros(batch, dtype=np.int8)
    observation = task.observe(state)
    surrogate = SurrogateTracker(task.conflicts(state), config.episode.dt)
    invalid_code = task.reasons.index("invalid_learned_action")
    interval = config.episode.decision_interval
    actions = np.zeros(batch)
    for tick in range(config.episode.horizon_ticks):
        if tick % interval == 0:  # the learned controller decides every decision_interval ticks
            actions = policy(observation, state, tick)
        # The observation only before a decision (in traffic most of a tick's cost).
        state, record = task.step(state, actions, observe=(tick + 1) % interval == 0)
        # Ended episodes keep stepping (no reset) but no longer count.
        stats.update(record, config, live)
        invalid += live & (record.reason == invalid_code)
        min_separation = np.where(
            live, np.minimum(min_separation, record.separation), min_separation
        )
        ended_outcome = np.where(live, record.outcome, ended_outcome)
        max_lon = np.where(live, np.maximum(max_lon, np.abs(record.accel_lon)), max_lon)
        max_lat = np.where(live, np.maximum(max_lat, np.abs(record.accel_lat)), max_lat)
        surrogate.update(task.conflicts(state), live, tick)
        if on_tick is not None:
            on_tick(state, record, tick)
        live &= ~(record.terminated | record.truncated)
        if record.observation is not None:
            observation = record.observation
        if not live.any():
            break
    return RolloutResult(
        collision=stats.collision,
        lost_control=stats.lost_control,
        safety_steps=stats.safety_steps,
        invalid_steps=invalid,
        min_speed=stats.min_speed,
        max_speed=stats.max_speed,
        speeding_steps=stats.speeding_steps,
        time_to_clear=stats.time_to_clear,
        outcome=ended_outcome,
        comfort_violation_steps=stats.comfort_violation_steps,
        ticks=stats.length,
        episode_return=stats.ret,
        min_separation=min_separation,
        max_accel_lon=max_lon,
        max_accel_lat=max_lat,
        max_lateral=stats.max_lateral,
        terms=stats.terms,
        min_ttc=surrogate.min_ttc,
        min_pet=surrogate.min_pet,
    )
