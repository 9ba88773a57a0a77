"""Per-environment ``info`` dicts built from a batched :class:`StepRecord`, lazily.

Stable-Baselines3 wants a list of dicts from ``VecEnv.step``. Building 4,096 dicts every tick
would cost more than the whole simulation step, so :class:`BatchInfos` is a sequence that builds
(and caches) environment ``i``'s dict only when it is indexed. Vectorised consumers read the
arrays directly from :attr:`BatchInfos.record`.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any, overload

import numpy as np
from numpy.typing import NDArray

from safeswitch.leftturn.rewards import REWARD_TERMS
from safeswitch.leftturn.task import CONTROLLERS, OUTCOMES, StepRecord


def step_info(record: StepRecord, i: int, reasons: tuple[str, ...]) -> dict[str, Any]:
    """The ``info`` of environment ``i`` for one tick.

    Keys: ``collision``, ``safety_active`` (the safety action was executed), ``reward_terms``
    (the five terms of Eq. 5), ``reason`` (why the switching logic chose as it did),
    ``controller`` (``learned``, ``rule`` or ``safety``: who proposed the executed action),
    ``learned_throttle`` (what the learned action asked for), ``safety_brake`` (what ``PID_b``
    computed), ``throttle`` and ``brake`` (executed), ``both_at_intersection``, ``outcome``
    (``cut``, ``yield`` or ``undecided``), ``separation`` [m], ``ego_speed``, ``north_speed``
    [m/s], ``accel_lon``, ``accel_lat`` [m/s²], ``lateral_deviation`` [m].
    """
    r = record
    return {
        "collision": bool(r.collision[i]),
        "safety_active": bool(r.safety_active[i]),
        "reward_terms": {name: float(r.terms[name][i]) for name in REWARD_TERMS},
        "reason": reasons[int(r.reason[i])],
        "controller": CONTROLLERS[int(r.controller[i])],
        "learned_throttle": float(r.learned_throttle[i]),
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


class BatchInfos(Sequence[dict[str, Any]]):
    """The list of info dicts of one ``VecEnv.step``, built on access.

    Args:
        record: The batched record of the tick.
        reasons: Reason names of the switching logic.
        done: Which environments ended this tick ``[B]``.
        terminal_observation: Last observation of each ended environment ``[D, 6]`` (in the
            order of ``np.flatnonzero(done)``).
        episode: Per ended environment, the ``episode`` summary (SB3 Monitor keys ``r``, ``l``,
            ``t`` plus ours), as arrays ``[D]``.
    """

    def __init__(
        self,
        record: StepRecord,
        reasons: tuple[str, ...],
        done: NDArray[np.bool_],
        terminal_observation: NDArray[np.float32],
        episode: dict[str, NDArray[Any]],
    ) -> None:
        self.record = record
        self.reasons = reasons
        self.done = done
        self._done_slot = np.full(done.shape[0], -1, dtype=np.intp)
        self._done_slot[np.flatnonzero(done)] = np.arange(int(done.sum()))
        self._terminal_observation = terminal_observation
        self._episode = episode
        self._cache: dict[int, dict[str, Any]] = {}

    def __len__(self) -> int:
        return int(self.done.shape[0])

    @overload
    def __getitem__(self, index: int) -> dict[str, Any]: ...

    @overload
    def __getitem__(self, index: slice) -> list[dict[str, Any]]: ...

    def __getitem__(self, index: int | slice) -> dict[str, Any] | list[dict[str, Any]]:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"info index {index} out of range for {n} environments")
        index %= n
        cached = self._cache.get(index)
        if cached is None:
            cached = step_info(self.record, index, self.reasons)
            slot = self._done_slot[index]
            if slot >= 0:
                cached["terminal_observation"] = self._terminal_observation[slot]
                cached["TimeLimit.truncated"] = bool(
                    self.record.truncated[index] and not self.record.terminated[index]
                )
                cached["episode"] = {
                    key: _scalar(values[slot]) for key, values in self._episode.items()
                }
            self._cache[index] = cached
        return cached

    def __iter__(self) -> Iterator[dict[str, Any]]:
        for i in range(len(self)):
            yield self[i]


def _scalar(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else value
