"""Per-environment ``info`` dicts built from a batched :class:`StepRecord`, lazily.

Stable-Baselines3 wants a list of dicts from ``VecEnv.step``. Building 4,096 dicts every tick
would cost more than the whole simulation step, so :class:`BatchInfos` is a sequence that builds
(and caches) environment ``i``'s dict only when it is indexed. Vectorised consumers read the
arrays directly from :attr:`BatchInfos.record`.
"""

from __future__ import annotations

from collections.abc import Iterator, MutableMapping, Sequence
from typing import Any, overload

import numpy as np
from numpy.typing import NDArray

from safeswitch.leftturn.rewards import REWARD_TERMS
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.statistics import published_costs
from safeswitch.leftturn.task import CONTROLLERS, OUTCOMES, StepRecord


def scenario_info(scenarios: Scenarios, i: int) -> dict[str, float]:
    """Scenario ``i`` of a batch as plain numbers (what ``reset`` reports under
    ``"scenario"``): the ego's start distance to the conflict point [m] and speed [m/s], the
    north car's speed [m/s] and its arrival offset [s]."""
    s = scenarios
    return {
        "ego_start_distance": float(s.ego_start_distance[i]),
        "ego_speed": float(s.ego_speed[i]),
        "north_speed": float(s.north_speed[i]),
        "arrival_offset": float(s.arrival_offset[i]),
    }


def step_info(record: StepRecord, i: int, reasons: tuple[str, ...]) -> dict[str, Any]:
    """The ``info`` of environment ``i`` for one tick.

    Keys: ``collision``, ``lost_control`` (the ego left its lane: a failure, like a
    collision), ``safety_active`` (the safety action was executed), ``cost`` (1.0 then, else
    0.0: the switch's intervention, as every switched plant has it), ``reward_terms``
    (the five terms of Eq. 5), ``reason`` (why the switching logic chose as it did),
    ``controller`` (``learned``, ``rule`` or ``safety``: who proposed the executed action),
    ``learned_throttle`` and ``learned_brake`` (what the learned action asked for; the brake 0
    but with ``controllers.learned_brake``), ``action_clipped`` (it was outside
    [-1, 1] and was clipped to it), ``safety_brake`` (what ``PID_b``
    computed), ``throttle`` and ``brake`` (executed), ``both_at_intersection``, ``outcome``
    (``cut``, ``yield`` or ``undecided``), ``separation`` [m], ``ego_speed``, ``north_speed``
    [m/s], ``accel_lon``, ``accel_lat`` [m/s²], ``lateral_deviation`` [m]. The environments
    add ``costs``, the plant's named costs of the step
    (:data:`~safeswitch.leftturn.statistics.PUBLISHED_COSTS`).
    """
    r = record
    return {
        "collision": bool(r.collision[i]),
        "lost_control": bool(r.lost_control[i]),
        "safety_active": bool(r.safety_active[i]),
        "cost": 1.0 if r.safety_active[i] else 0.0,
        "reward_terms": {name: float(r.terms[name][i]) for name in REWARD_TERMS},
        "reason": reasons[int(r.reason[i])],
        "controller": CONTROLLERS[int(r.controller[i])],
        "learned_throttle": float(r.learned_throttle[i]),
        "learned_brake": float(r.learned_brake[i]),
        "action_clipped": bool(r.action_clipped[i]),
        "safety_brake": float(r.safety_brake[i]),
        "throttle": float(r.throttle[i]),
        "brake": float(r.brake[i]),
        "both_at_intersection": bool(r.both_at_intersection[i]),
        "outcome": OUTCOMES[int(r.outcome[i])],
        "separation": float(r.separation[i]),
        "ego_speed": float(r.ego_speed[i]),
        "north_speed": float(r.north_speed[i]),
        "accel_lon": float(r.accel_lon[i]),
        "accel_lat": float(r.accel_lat[i]),
        "lateral_deviation": float(r.lateral[i]),
    }


#: Keys SB3 reads from every environment's info on every step; answered without building the
#: full dict.
_BOOKKEEPING = ("episode", "terminal_observation", "TimeLimit.truncated", "is_success")


class LazyInfo(MutableMapping[str, Any]):
    """One environment's info: SB3's bookkeeping keys are answered at once, the full
    :func:`step_info` dict is built on the first access to any other key."""

    __slots__ = ("_extra", "_full", "_index", "_owner")

    def __init__(self, owner: BatchInfos, index: int, extra: dict[str, Any]) -> None:
        self._owner, self._index, self._extra = owner, index, extra
        self._full: dict[str, Any] | None = None

    def _materialise(self) -> dict[str, Any]:
        if self._full is None:
            owner = self._owner
            full = step_info(owner.record, self._index, owner.reasons)
            if owner.costs is not None:
                full["costs"] = published_costs(owner.costs, self._index)
            full.update(self._extra)
            self._full, self._extra = full, full
        return self._full

    def __getitem__(self, key: str) -> Any:
        if self._full is None and key in _BOOKKEEPING:
            return self._extra[key]
        return self._materialise()[key]

    def get(self, key: str, default: Any = None) -> Any:
        if self._full is None and key in _BOOKKEEPING:
            return self._extra.get(key, default)
        return self._materialise().get(key, default)

    def __contains__(self, key: object) -> bool:
        if self._full is None and key in _BOOKKEEPING:
            return key in self._extra
        return key in self._materialise()

    def __setitem__(self, key: str, value: Any) -> None:
        if self._full is None:
            self._extra[key] = value
        else:
            self._full[key] = value

    def __delitem__(self, key: str) -> None:
        del self._materialise()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._materialise())

    def __len__(self) -> int:
        return len(self._materialise())

    def __repr__(self) -> str:
        return repr(self._materialise())


class BatchInfos(Sequence[MutableMapping[str, Any]]):
    """The list of info dicts of one ``VecEnv.step``, built on access.

    Args:
        record: The batched record of the tick.
        reasons: Reason names of the switching logic.
        done: Which environments ended this tick ``[B]``.
        terminal_observation: Last observation of each ended environment ``[D, 6]`` (in the
            order of ``np.flatnonzero(done)``).
        episode: Per ended environment, the ``episode`` summary (SB3 Monitor keys ``r``, ``l``,
            ``t`` plus ours), as arrays ``[D]``.
        costs: The step's named costs (:meth:`~safeswitch.leftturn.statistics.TickCosts.
            arrays`), each environment's ``info["costs"]``; ``None``: not counted.
    """

    def __init__(
        self,
        record: StepRecord,
        reasons: tuple[str, ...],
        done: NDArray[np.bool_],
        terminal_observation: NDArray[np.float32],
        episode: dict[str, NDArray[Any]],
        costs: dict[str, NDArray[np.int64]] | None = None,
    ) -> None:
        self.record = record
        self.costs = costs
        self.reasons = reasons
        self.done = done
        self._done_slot = np.full(done.shape[0], -1, dtype=np.intp)
        self._done_slot[np.flatnonzero(done)] = np.arange(int(done.sum()))
        self._terminal_observation = terminal_observation
        self._episode = episode
        self._cache: dict[int, LazyInfo] = {}

    def __len__(self) -> int:
        return int(self.done.shape[0])

    @overload
    def __getitem__(self, index: int) -> MutableMapping[str, Any]: ...

    @overload
    def __getitem__(self, index: slice) -> list[MutableMapping[str, Any]]: ...

    def __getitem__(
        self, index: int | slice
    ) -> MutableMapping[str, Any] | list[MutableMapping[str, Any]]:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"info index {index} out of range for {n} environments")
        index %= n
        cached = self._cache.get(index)
        if cached is None:
            extra: dict[str, Any] = {}
            slot = self._done_slot[index]
            if slot >= 0:
                extra["terminal_observation"] = self._terminal_observation[slot]
                extra["TimeLimit.truncated"] = bool(
                    self.record.truncated[index] and not self.record.terminated[index]
                )
                extra["episode"] = {
                    key: _scalar(values[slot]) for key, values in self._episode.items()
                }
            cached = self._cache[index] = LazyInfo(self, index, extra)
        return cached

    def __iter__(self) -> Iterator[MutableMapping[str, Any]]:
        for i in range(len(self)):
            yield self[i]


def _scalar(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else value
