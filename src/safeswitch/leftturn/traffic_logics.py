"""The ``paper`` and ``certified`` switching logics generalised to every conflicting vehicle.

**paper** (ours where the paper is silent: it has one other car). Algorithm 1 is applied to each
vehicle whose route conflicts with the ego's, with that pair's conflict point and zones: the
safety action is executed if for *any* of them both are at the intersection, there is no safe
time gap to cut in front (``TTR_k − TTR_e < threshold``) and the ego has reached its braking
point before the pair's zone. For the other vehicles the conflict point is the middle of the
pair's conflict zone (they may cross or merge; the north car keeps its centre-line crossing).

**certified**. The one-tick-then-backup certificate of
:mod:`~safeswitch.leftturn.certified` with every conflict at once: a state is safe when the
*stop* backup ends before the entry of the first zone whose vehicle has not left, or the
*clear* backup leaves every such zone ``time_margin_s`` before its vehicle can first enter
its own. Assumptions, for every other vehicle: it accelerates at most ``north_max_accel`` and
drives at most ``north_max_speed_kmh`` (the traffic's drivers keep below: IDM's 1.5 m/s² and at
most 40 km/h in the presets), and a vehicle behind the ego follows it without running into it
(its car-following brakes up to 8 m/s², as hard as the ego's backup). A vehicle that merges
ahead of the ego into its exit lane is assumed to drive on; it is not part of the certificate.

Vehicles keep entering the scene, so the certificate also holds against those not there yet:
for every movement that crosses the ego's, a *phantom* vehicle that could appear at the start
of its approach at any moment, at the assumed top speed — it can reach its zone no sooner than
``entry / north_max_speed`` from now. The stop backup therefore ends before every zone the ego
has not passed (whoever may come), and the clear backup must beat the phantoms too. Without
them a vehicle appearing on a crossing route could turn the place where the ego waits into a
conflict zone.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import jit
from safeswitch.core.switching import BoolArray, Decision, FloatArray
from safeswitch.leftturn.certified import (
    CLEAR,
    NO_BACKUP_BRAKE,
    NO_BACKUP_CLEAR,
    STOP,
    CertifiedConstants,
    CertifiedSwitching,
    _clear_time,
    _predict,
    _quick_stop_distance,
    _stop_distance,
)
from safeswitch.leftturn.config import CertifiedConfig, PaperSwitchingConfig
from safeswitch.leftturn.switching import (
    PaperConstants,
    PaperSwitching,
    firing_distance,
    time_to_reach,
)
from safeswitch.sim.vehicle import VehicleConstants, VehicleParams


class PaperTrafficSwitching(PaperSwitching):
    """Algorithm 1 against every conflicting vehicle (see the module docstring).

    Args:
        config: Threshold, margins and speed guard.
        emergency_decel: ``a_max_lon`` of Eq. 3 [m/s²].
        approach_distance: "At the intersection" from this far before a conflict point [m].
    """

    def __init__(
        self, config: PaperSwitchingConfig, emergency_decel: float, approach_distance: float
    ) -> None:
        super().__init__(config, emergency_decel)
        self.approach_distance = approach_distance

    def decide(self, state: Any, learned: FloatArray, safe: FloatArray) -> Decision:
        use = np.empty(learned.shape[0], dtype=np.bool_)
        s = state
        _paper_any(
            s.ego_progress, s.ego_speed, s.present, s.ego_point, s.ego_zone, s.other_progress,
            s.other_point, s.other_zone, s.other_speed, self.approach_distance, self.constants,
            use,
        )  # fmt: skip
        return Decision(use, use.astype(np.int8), safe)


@jit
def _paper_any(
    ego_progress: FloatArray, ego_speed: FloatArray, present: BoolArray, ego_point: FloatArray,
    ego_zone: FloatArray, other_progress: FloatArray, other_point: FloatArray,
    other_zone: FloatArray, other_speed: FloatArray, approach: float, c: PaperConstants,
    out: BoolArray,
) -> None:  # fmt: skip
    for b in range(present.shape[0]):
        s_e, v_e = ego_progress[b], ego_speed[b]
        fire = False
        for k in range(present.shape[1]):
            if not present[b, k]:
                continue
            s_k = other_progress[b, k]
            at = (
                ego_point[b, k] - s_e <= approach
                and s_e <= ego_zone[b, k, 1]
                and other_point[b, k] - s_k <= approach
                and s_k <= other_zone[b, k, 1]
            )
            if not at:
                continue
            ttr_e = time_to_reach(max(ego_point[b, k] - s_e, 0.0), v_e, c.min_speed)
            ttr_k = time_to_reach(other_point[b, k] - s_k, other_speed[b, k], c.min_speed)
            if ttr_k - ttr_e < c.ttr_threshold_s and (
                ego_zone[b, k, 0] - s_e <= firing_distance(v_e, c)
            ):
                fire = True
                break
        out[b] = fire


class CertifiedTrafficSwitching(CertifiedSwitching):
    """The certified filter against every conflicting vehicle (see the module docstring).

    Args:
        config: Assumptions and margins.
        vehicle: The ego's parameters.
        dt: Tick [s].
        north_zones: The north car's and the ego's zones with the certified margin (as for
            :class:`CertifiedSwitching`; its scalar bounds are reused).
    """

    def __init__(
        self,
        config: CertifiedConfig,
        vehicle: VehicleParams,
        dt: float,
        north_zones: tuple[tuple[float, float], tuple[float, float]],
        crossing: tuple[FloatArray, FloatArray],
    ) -> None:
        super().__init__(config, vehicle, dt, north_zones[0], north_zones[1])
        ego_zones, their_entries = crossing
        #: The phantoms: the ego's zone with each crossing movement ``[P, 2]`` and the soonest
        #: a vehicle not yet in the scene can reach its own zone [s] ``[P]``.
        self.phantom_zones = np.ascontiguousarray(ego_zones, dtype=np.float64)
        self.phantom_arrivals = np.asarray(their_entries, dtype=np.float64) / (
            config.north_max_speed_kmh / 3.6
        )

    def margins(self, state: Any) -> tuple[FloatArray, FloatArray]:
        """Per conflict of a logic view ``[B, C]``: the earliest time the vehicle can enter its
        zone within the assumptions [s] (0 inside, ``inf`` once it has left or where there is
        no conflict), and the certificate's slack for it [s]: that time less the margin and
        the clear backup's time to leave the ego's zone from now (negative: full throttle now
        would not clear it in time)."""
        s = state
        arrival = np.full(s.present.shape, np.inf)
        slack = np.full(s.present.shape, np.inf)
        _margins_many(
            s.ego_progress, s.ego_speed, s.ego_throttle, s.ego_brake, s.present,
            np.ascontiguousarray(s.ego_cert_zone), s.other_progress,
            np.ascontiguousarray(s.other_cert_zone), s.other_speed, *self._tables, arrival,
            slack,
        )  # fmt: skip
        return arrival, slack

    def decide(self, state: Any, learned: FloatArray, safe: FloatArray) -> Decision:
        batch = learned.shape[0]
        use = np.zeros(batch, dtype=np.bool_)
        reason = np.zeros(batch, dtype=np.int8)
        action = np.zeros((batch, 2))
        s = state
        _decide_many(
            s.ego_progress, s.ego_speed, s.ego_throttle, s.ego_brake, s.present,
            np.ascontiguousarray(s.ego_cert_zone), s.other_progress,
            np.ascontiguousarray(s.other_cert_zone), s.other_speed, self.phantom_zones,
            self.phantom_arrivals, learned, *self._tables, self._plant, use, reason, action,
        )  # fmt: skip
        return Decision(use, reason, action)


@jit
def _arrival(progress: float, speed: float, enter: float, leave: float, c: CertifiedConstants
             ) -> float:  # fmt: skip
    """Earliest entry of a vehicle into its zone within the assumptions [s] (0 inside, ``inf``
    once it has left)."""
    if progress > leave:
        return math.inf
    a = c.north_accel
    top = max(c.north_top, speed)
    distance = max(enter - progress, 0.0)
    to_top = (top * top - speed * speed) / (2.0 * a)
    if distance <= to_top:
        return (math.sqrt(speed * speed + 2.0 * a * distance) - speed) / a
    return (top - speed) / a + (distance - to_top) / top


@jit
def _margins_many(
    progress: FloatArray, speed: FloatArray, throttle: FloatArray, brake: FloatArray,
    present: NDArray[np.bool_], zones: FloatArray, other_progress: FloatArray,
    other_zones: FloatArray, other_speed: FloatArray, c: CertifiedConstants, rho_t: FloatArray,
    rho_b: FloatArray, arrival: FloatArray, slack: FloatArray,
) -> None:  # fmt: skip
    """Fill :meth:`CertifiedTrafficSwitching.margins` (``inf`` where there is no conflict)."""
    for b in range(present.shape[0]):
        for j in range(present.shape[1]):
            if not present[b, j]:
                continue
            arrive = _arrival(other_progress[b, j], other_speed[b, j], other_zones[b, j, 0],
                              other_zones[b, j, 1], c)  # fmt: skip
            arrival[b, j] = arrive
            if not math.isinf(arrive):
                slack[b, j] = _clear_slack(progress[b], zones[b, j, 1], arrive, speed[b],
                                           throttle[b], brake[b], c, rho_t, rho_b)  # fmt: skip


@jit
def _clear_slack(
    progress: float, leave: float, arrive: float, speed: float, throttle: float, brake: float,
    c: CertifiedConstants, rho_t: FloatArray, rho_b: FloatArray,
) -> float:  # fmt: skip
    """The clear backup's time to spare against a vehicle that can enter its zone ``arrive``
    seconds from now [s]: that time less the margin and the backup's time for the ego at
    ``progress`` to leave its own zone at ``leave`` (negative: the backup fails)."""
    distance = c.progress_factor * max(leave - progress, 0.0)
    return arrive - c.time_margin - _clear_time(distance, speed, throttle, brake, c, rho_t, rho_b)


@jit
def _safe_many(
    low: float, high: float, speed: float, throttle: float, brake: float,
    present: NDArray[np.bool_], zones: FloatArray, arrivals: FloatArray, shift: float,
    phantom_zones: FloatArray, phantom_arrivals: FloatArray,
    c: CertifiedConstants, rho_t: FloatArray, rho_b: FloatArray,
) -> tuple[bool, bool]:  # fmt: skip
    """(stop backup ok, clear backup ok) for the ego's progress known within ``[low, high]``,
    with the vehicles' arrivals brought ``shift`` seconds closer (the phantoms' arrivals are
    the same from any moment on)."""
    first_entry = math.inf
    relevant = False
    clear_ok = True
    for k in range(present.shape[0] + phantom_arrivals.shape[0]):
        if k < present.shape[0]:
            if not present[k] or math.isinf(arrivals[k]) or low > zones[k, 1]:
                continue
            enter, leave, arrive = zones[k, 0], zones[k, 1], arrivals[k] - shift
        else:
            p = k - present.shape[0]
            enter, leave, arrive = phantom_zones[p, 0], phantom_zones[p, 1], phantom_arrivals[p]
            if low > leave:
                continue
        relevant = True
        first_entry = min(first_entry, enter)
        if clear_ok and _clear_slack(low, leave, arrive, speed, throttle, brake, c, rho_t,
                                     rho_b) < 0.0:  # fmt: skip
            clear_ok = False
    if not relevant:
        return True, True
    room = (first_entry - high) / c.progress_factor
    stop_ok = room >= 0.0 and (
        _quick_stop_distance(speed, c) <= room
        or _stop_distance(speed, throttle, brake, c, rho_t, rho_b) <= room
    )
    return stop_ok, clear_ok


@jit
def _decide_many(
    progress: FloatArray, speed: FloatArray, throttle: FloatArray, brake: FloatArray,
    present: NDArray[np.bool_], zones: FloatArray, other_progress: FloatArray,
    other_zones: FloatArray, other_speed: FloatArray, phantom_zones: FloatArray,
    phantom_arrivals: FloatArray, learned: FloatArray, c: CertifiedConstants,
    rho_t: FloatArray, rho_b: FloatArray, k: VehicleConstants,
    use: BoolArray, reason: NDArray[np.int8], pedals: FloatArray,
) -> None:  # fmt: skip
    conflicts = present.shape[1]
    arrivals = np.empty(conflicts)
    for b in range(present.shape[0]):
        for j in range(conflicts):
            arrivals[j] = math.inf
            if present[b, j]:
                arrivals[j] = _arrival(other_progress[b, j], other_speed[b, j],
                                       other_zones[b, j, 0], other_zones[b, j, 1], c)  # fmt: skip
        low, high, v1, th1, br1 = _predict(
            progress[b], speed[b], throttle[b], brake[b], learned[b, 0], learned[b, 1], c, k
        )
        stop1, clear1 = _safe_many(low, high, v1, th1, br1, present[b], zones[b], arrivals,
                                   c.dt, phantom_zones, phantom_arrivals, c, rho_t,
                                   rho_b)  # fmt: skip
        if stop1 or clear1:
            continue
        stop0, clear0 = _safe_many(progress[b], progress[b], speed[b], throttle[b], brake[b],
                                   present[b], zones[b], arrivals, 0.0, phantom_zones,
                                   phantom_arrivals, c, rho_t, rho_b)  # fmt: skip
        use[b] = True
        if stop0:
            reason[b], pedals[b, 0], pedals[b, 1] = STOP, 0.0, 1.0
        elif clear0:
            reason[b], pedals[b, 0], pedals[b, 1] = CLEAR, 1.0, 0.0
        else:
            first = math.inf
            for j in range(conflicts):
                if present[b, j] and not math.isinf(arrivals[j]) and progress[b] <= zones[b, j, 1]:
                    first = min(first, zones[b, j, 0])
            for p in range(phantom_zones.shape[0]):
                if progress[b] <= phantom_zones[p, 1]:
                    first = min(first, phantom_zones[p, 0])
            if progress[b] < first:
                reason[b], pedals[b, 0], pedals[b, 1] = NO_BACKUP_BRAKE, 0.0, 1.0
            else:
                reason[b], pedals[b, 0], pedals[b, 1] = NO_BACKUP_CLEAR, 1.0, 0.0
