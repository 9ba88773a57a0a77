"""Surrogate safety measures: how close an episode came to a collision, not only whether it
had one — the standard measures of traffic-conflict studies, per episode, at the conflict zones
of the ego with every other vehicle (:meth:`~safeswitch.leftturn.task.LeftTurnTask.conflicts`).

**Time to collision** (TTC; Hayward, *Near-miss determination through use of a scale of
danger*, Highway Research Record 384, 1972): the time until two road users would collide if
both kept their speed and path. For a crossing or merging pair, as in the FHWA's Surrogate
Safety Assessment Model (Gettman & Head, *Surrogate Safety Measures from Traffic Simulation
Models*, FHWA-RD-03-050, 2003): at constant speeds each vehicle occupies its conflict zone over
a time interval; if the two intervals overlap, they are on a collision course and TTC is the
moment both are inside (0 while both are); otherwise there is none. An episode's figure is its
smallest TTC over every tick and vehicle (``inf``: never on a collision course). SSAM counts a
*conflict* at TTC ≤ 1.5 s (:data:`TTC_CONFLICT_S`).

**Post-encroachment time** (PET; Allen, Shin & Cooper, *Analysis of traffic conflicts and
collisions*, Transportation Research Record 667, 1978): the time from the first road user
leaving the conflict zone to the second one entering it. An episode's figure is its smallest
PET over every vehicle that crossed a zone of the ego's path after or before the ego (NaN: no
such encroachment within the episode).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import jit
from safeswitch.leftturn.task import ConflictArrays
from safeswitch.sim.geometry import FloatArray

#: SSAM's threshold for a traffic conflict [s].
TTC_CONFLICT_S = 1.5


class SurrogateTracker:
    """Per-episode smallest TTC and PET of a batch, updated tick by tick (:meth:`update`).

    Args:
        start: The conflicts at the start of the episodes.
        dt: Tick [s].
    """

    def __init__(self, start: ConflictArrays, dt: float) -> None:
        batch, conflicts = start.present.shape
        self.dt = dt
        #: Smallest TTC so far per episode [s] (``inf``: never on a collision course).
        self.min_ttc = np.full(batch, np.inf)
        #: Smallest PET so far per episode [s] (NaN: no encroachment yet).
        self.min_pet = np.full(batch, np.nan)
        self._prev = start
        self._ego_left = np.full((batch, conflicts), np.nan)  # when the ego left zone c [s]
        self._other_left = np.full((batch, conflicts), np.nan)  # when vehicle c left its own
        self._ttc(start, np.ones(batch, dtype=np.bool_))

    def update(self, now: ConflictArrays, live: NDArray[np.bool_], tick: int) -> None:
        """Account for the state ``now`` after tick ``tick`` (0-based) of the ``live``
        episodes."""
        p = self._prev
        _pet(
            (tick + 1) * self.dt, p.ego_progress, now.ego_progress, now.present, now.ego_zone,
            p.other_progress, now.other_progress, now.other_zone, live, self._ego_left,
            self._other_left, self.min_pet,
        )  # fmt: skip
        self._ttc(now, live)
        self._prev = now

    def _ttc(self, now: ConflictArrays, live: NDArray[np.bool_]) -> None:
        _ttc(now.ego_progress, now.ego_speed, now.present, now.ego_zone, now.other_progress,
             now.other_speed, now.other_zone, live, self.min_ttc)  # fmt: skip


@jit
def _occupancy(s: float, v: float, enter: float, leave: float) -> tuple[float, float]:
    """The time interval over which a vehicle at ``s`` driving on at ``v`` is in
    ``[enter, leave]`` (``(inf, inf)``: never)."""
    if s > leave:
        return math.inf, math.inf
    if s >= enter:
        return 0.0, (leave - s) / v if v > 1e-6 else math.inf
    if v <= 1e-6:
        return math.inf, math.inf
    return (enter - s) / v, (leave - s) / v


@jit
def _ttc(
    ego_s: FloatArray, ego_v: FloatArray, present: NDArray[np.bool_], ego_zone: FloatArray,
    other_s: FloatArray, other_v: FloatArray, other_zone: FloatArray,
    live: NDArray[np.bool_], out: FloatArray,
) -> None:  # fmt: skip
    for b in range(present.shape[0]):
        if not live[b]:
            continue
        for c in range(present.shape[1]):
            if not present[b, c]:
                continue
            e_in, e_out = _occupancy(ego_s[b], ego_v[b], ego_zone[b, c, 0], ego_zone[b, c, 1])
            o_in, o_out = _occupancy(other_s[b, c], other_v[b, c], other_zone[b, c, 0],
                                     other_zone[b, c, 1])  # fmt: skip
            if math.isinf(e_in) or math.isinf(o_in):
                continue
            if e_in <= o_out and o_in <= e_out:
                out[b] = min(out[b], max(e_in, o_in))


@jit
def _pet(
    now: float, ego_before: FloatArray, ego_s: FloatArray, present: NDArray[np.bool_],
    ego_zone: FloatArray, other_before: FloatArray, other_s: FloatArray,
    other_zone: FloatArray, live: NDArray[np.bool_], ego_left: FloatArray,
    other_left: FloatArray, out: FloatArray,
) -> None:  # fmt: skip
    for b in range(present.shape[0]):
        if not live[b]:
            continue
        for c in range(present.shape[1]):
            if not present[b, c]:
                continue
            if other_s[b, c] < other_before[b, c] - 1.0:  # a new vehicle in this slot
                other_left[b, c] = math.nan
                ego_left[b, c] = math.nan
                continue
            e_in, e_out = ego_zone[b, c, 0], ego_zone[b, c, 1]
            o_in, o_out = other_zone[b, c, 0], other_zone[b, c, 1]
            # who entered this tick, after the other had left
            if ego_before[b] < e_in <= ego_s[b] and not math.isnan(other_left[b, c]):
                pet = now - other_left[b, c]
                if math.isnan(out[b]) or pet < out[b]:
                    out[b] = pet
            if other_before[b, c] < o_in <= other_s[b, c] and not math.isnan(ego_left[b, c]):
                pet = now - ego_left[b, c]
                if math.isnan(out[b]) or pet < out[b]:
                    out[b] = pet
            if ego_before[b] <= e_out < ego_s[b]:
                ego_left[b, c] = now
            if other_before[b, c] <= o_out < other_s[b, c]:
                other_left[b, c] = now
