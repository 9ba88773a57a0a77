"""Per-episode statistics of the left turn, tick by tick: what the VecEnv's ``episode``
summaries, the rollouts of an evaluation and the training constraints' costs count (no
Stable-Baselines3 here: a campaign's worker runs the batched task alone)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.rewards import REWARD_TERMS
from safeswitch.leftturn.task import StepRecord

#: Keys of the ``episode`` summary beyond SB3's ``r``, ``l`` and ``t``.
EPISODE_KEYS: tuple[str, ...] = (
    "collision",
    "lost_control",
    "safety_steps",
    "min_speed",
    "max_speed",
    "speeding_steps",
    "comfort_violation_steps",
    "outcome",
    "time_to_clear",
    "max_lateral_deviation",
    *(f"term_{name}" for name in REWARD_TERMS),
)


def comfort_exceeded(record: StepRecord, config: LeftTurnConfig) -> NDArray[np.bool_]:
    """Per environment ``[B]``: the tick exceeded a comfort limit (|a_lon| or |a_lat| above
    the configuration's comfort limits; the evaluation's ``comfort_violation_steps``)."""
    return (np.abs(record.accel_lon) > config.rewards.comfort_accel_lon) | (
        np.abs(record.accel_lat) > config.rewards.comfort_accel_lat
    )


#: Speeding counts from this much above the tolerated speed [m/s] (0.1 km/h): a controller
#: that holds the tolerated speed itself (the planner) overshoots it by rounding only.
SPEEDING_MARGIN = 0.1 / 3.6


def speeding(record: StepRecord, config: LeftTurnConfig) -> NDArray[np.bool_]:
    """Per environment ``[B]``: the ego was faster than the tolerated speed, the highest at
    which ``R_v`` is at its best (:attr:`~safeswitch.leftturn.config.RewardConfig.
    tolerated_speed`; the oracle's ``v_max``, 30 km/h by default), by more than
    :data:`SPEEDING_MARGIN`."""
    return record.ego_speed > config.rewards.tolerated_speed + SPEEDING_MARGIN


class TickCosts:
    """Per environment, what the ticks of one step held (arrays ``[B]``, counts of ticks):
    what the learning-only costs of :mod:`safeswitch.training.constraints` read.

    Attributes:
        ticks: Ticks the episode was live for in the step (fewer than the decision interval
            at the step that ends it).
        comfort: Of those, ticks that exceeded a comfort limit.
        speeding: Of those, ticks faster than the tolerated speed (:func:`speeding`).
        safety: Ticks on which the safety action was executed (any reason).
        uncleared: Ticks that ended with the ego not yet clear of its conflict zone.
    """

    def __init__(self, batch: int) -> None:
        self.batch = batch
        self.clear()

    def clear(self) -> None:
        """Start a step: fresh arrays (the last step's stay valid where they were handed out,
        e.g. in a VecEnv's lazy infos)."""
        self.ticks = np.zeros(self.batch, dtype=np.int64)
        self.comfort = np.zeros(self.batch, dtype=np.int64)
        self.speeding = np.zeros(self.batch, dtype=np.int64)
        self.safety = np.zeros(self.batch, dtype=np.int64)
        self.uncleared = np.zeros(self.batch, dtype=np.int64)

    def add(self, record: StepRecord, stats: EpisodeStatistics, live: NDArray[np.bool_]) -> None:
        """Add one tick of the episodes ``live`` selects (``stats`` just took the same tick:
        its comfort and speeding flags are reused)."""
        self.ticks += live
        self.comfort += live & stats.tick_comfort
        self.speeding += live & stats.tick_speeding
        self.safety += live & record.safety_active
        self.uncleared += live & ~record.ego_cleared

    def arrays(self) -> dict[str, NDArray[np.int64]]:
        """The step's counts by published name, ``[B]`` each (valid after the next
        :meth:`clear`)."""
        return {name: getattr(self, name) for name in PUBLISHED_COSTS}


def tick_cost_limits(config: LeftTurnConfig) -> tuple[float, float, float]:
    """The comfort limits (longitudinal, lateral) and the speed above which a tick speeds, as
    :func:`comfort_exceeded` and :func:`speeding` read them (for :func:`tick_costs_of`)."""
    r = config.rewards
    return r.comfort_accel_lon, r.comfort_accel_lat, r.tolerated_speed + SPEEDING_MARGIN


def tick_costs_of(
    record: StepRecord, i: int, limits: tuple[float, float, float]
) -> tuple[float, float, float, float]:
    """Environment ``i``'s costs of one tick in the order of :data:`PUBLISHED_COSTS`, from
    Python scalars: the single Env's path (a handful of numpy calls per tick would cost it
    more than a tenth of its step). The same flags as :func:`comfort_exceeded` and
    :func:`speeding` (``tests/leftturn/test_costs.py`` compares them)."""
    lon, lat, fast = limits
    comfort = abs(float(record.accel_lon[i])) > lon or abs(float(record.accel_lat[i])) > lat
    return (
        1.0 if comfort else 0.0,
        1.0 if float(record.ego_speed[i]) > fast else 0.0,
        1.0 if record.safety_active[i] else 0.0,
        0.0 if record.ego_cleared[i] else 1.0,
    )


def published_costs(arrays: dict[str, NDArray[np.int64]], i: int) -> dict[str, float]:
    """Environment ``i``'s ``info["costs"]`` from a step's :meth:`TickCosts.arrays`."""
    return {name: float(counts[i]) for name, counts in arrays.items()}


#: The left turn's named costs in ``info["costs"]``, per step, each a count of the step's
#: ticks: ``comfort`` (over a comfort limit), ``speeding`` (faster than the tolerated speed),
#: ``safety`` (the safety action executed), ``uncleared`` (ended with the ego not yet clear of
#: its conflict zone: summed over an episode, its time to clear in ticks).
PUBLISHED_COSTS = ("comfort", "speeding", "safety", "uncleared")


class EpisodeStatistics:
    """Running per-episode statistics of a batch of environments (arrays ``[B]``).

    A *failure* is a collision or a loss of control (:attr:`failed`)."""

    def __init__(self, batch: int) -> None:
        self.ret = np.zeros(batch)
        self.length = np.zeros(batch, dtype=np.int64)
        self.collision = np.zeros(batch, dtype=bool)
        self.lost_control = np.zeros(batch, dtype=bool)
        self.safety_steps = np.zeros(batch, dtype=np.int64)
        self.min_speed = np.full(batch, np.inf)
        self.max_speed = np.zeros(batch)
        self.speeding_steps = np.zeros(batch, dtype=np.int64)
        #: The last tick's flags (every environment, live or not): over a comfort limit, and
        #: faster than the tolerated speed.
        self.tick_comfort = np.zeros(batch, dtype=bool)
        self.tick_speeding = np.zeros(batch, dtype=bool)
        self.comfort_violation_steps = np.zeros(batch, dtype=np.int64)
        self.time_to_clear = np.full(batch, np.nan)
        self.max_lateral = np.zeros(batch)
        self.terms = {name: np.zeros(batch) for name in REWARD_TERMS}

    @property
    def failed(self) -> NDArray[np.bool_]:
        """Per episode: it ended in a collision or a loss of control."""
        return self.collision | self.lost_control

    def update(
        self, record: StepRecord, config: LeftTurnConfig, live: NDArray[np.bool_] | None = None
    ) -> None:
        """Add one tick; with ``live``, only the episodes it selects (the others have ended and
        keep their figures)."""
        r = record
        on = np.ones(r.reward.shape[0], dtype=bool) if live is None else live
        self.ret += np.where(on, r.reward, 0.0)
        self.length += on
        self.collision |= r.collision & on
        self.lost_control |= r.lost_control & on
        self.safety_steps += r.safety_active & on
        self.min_speed = np.where(on, np.minimum(self.min_speed, r.ego_speed), self.min_speed)
        self.max_speed = np.where(on, np.maximum(self.max_speed, r.ego_speed), self.max_speed)
        self.tick_speeding = speeding(r, config)
        self.tick_comfort = comfort_exceeded(r, config)
        self.speeding_steps += on & self.tick_speeding
        self.comfort_violation_steps += on & self.tick_comfort
        just_cleared = on & r.ego_cleared & np.isnan(self.time_to_clear)
        self.time_to_clear[just_cleared] = self.length[just_cleared] * config.episode.dt
        self.max_lateral = np.where(
            on, np.maximum(self.max_lateral, np.abs(r.lateral)), self.max_lateral
        )
        for name in REWARD_TERMS:
            self.terms[name] += np.where(on, r.terms[name], 0.0)

    def summary(
        self, index: NDArray[np.intp], record: StepRecord, elapsed: float
    ) -> dict[str, NDArray[Any]]:
        """Summaries of the episodes ``index`` (that just ended), arrays ``[len(index)]``."""
        out: dict[str, NDArray[Any]] = {
            "r": self.ret[index].copy(),
            "l": self.length[index].copy(),
            "t": np.full(len(index), round(elapsed, 6)),
            "collision": self.collision[index].copy(),
            "lost_control": self.lost_control[index].copy(),
            "safety_steps": self.safety_steps[index].copy(),
            "min_speed": self.min_speed[index].copy(),
            "max_speed": self.max_speed[index].copy(),
            "speeding_steps": self.speeding_steps[index].copy(),
            "comfort_violation_steps": self.comfort_violation_steps[index].copy(),
            "outcome": record.outcome[index].copy(),
            "time_to_clear": self.time_to_clear[index].copy(),
            "max_lateral_deviation": self.max_lateral[index].copy(),
        }
        for name in REWARD_TERMS:
            out[f"term_{name}"] = self.terms[name][index].copy()
        return out

    def reset_at(self, index: NDArray[np.intp]) -> None:
        self.ret[index] = 0.0
        self.length[index] = 0
        self.collision[index] = False
        self.lost_control[index] = False
        self.safety_steps[index] = 0
        self.min_speed[index] = np.inf
        self.max_speed[index] = 0.0
        self.speeding_steps[index] = 0
        self.comfort_violation_steps[index] = 0
        self.time_to_clear[index] = np.nan
        self.max_lateral[index] = 0.0
        for name in REWARD_TERMS:
            self.terms[name][index] = 0.0
