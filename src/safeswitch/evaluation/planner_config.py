"""The planners' tunings: plain configuration, no runtime code (the planners themselves are
:mod:`safeswitch.evaluation.planner` and :mod:`safeswitch.evaluation.traffic_planner`), so a
training configuration can name them without importing the task."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from safeswitch.core.config import Bounds, check, check_bounds

Positive = Bounds(0, low_open=True)
NonNegative = Bounds(0)

#: What the gap planner's go check may know of the other vehicles (:class:`GapPlannerConfig`).
FORESIGHTS = ("full", "observed")

#: How the gap planner's wait slows for its stop (:class:`GapPlannerConfig`).
APPROACHES = ("coast", "brake")


@dataclass(frozen=True)
class FastDriveConfig:
    """The fast drive both planners plan with: the speed limit (and the tolerated speeding) on
    the straight, the lateral comfort limit in the turn.

    Attributes:
        top_speed_kmh: Speed on the straight [km/h].
        accel_lat: Lateral acceleration the turn is planned for [m/s²].
        curve_decel: Deceleration the speed target assumes when slowing for the turn [m/s²].
        preview_s: The speed target is read this far ahead along the route [s].
        speed_gain: Throttle per m/s of speed error.
        recheck_ticks: Ticks between two checks (the decision holds in between).
    """

    top_speed_kmh: Annotated[float, Positive] = 30.0
    accel_lat: Annotated[float, Positive] = 2.8
    curve_decel: Annotated[float, Positive] = 1.7
    preview_s: Annotated[float, NonNegative] = 0.1
    speed_gain: Annotated[float, Positive] = 0.6
    recheck_ticks: Annotated[int, Bounds(1)] = 5


@dataclass(frozen=True)
class PlannerConfig(FastDriveConfig):
    """Tuning of the planner (all ours; measured on 1,000 random scenarios, see the README).

    Attributes:
        top_speed_kmh: Speed on the straight when passing first [km/h] (the end of ``R_v``'s
            tolerated speeding).
        accel_lat: Lateral acceleration the turn is planned for [m/s²] (the plant's measured
            lateral acceleration runs ~5 % above ``v² κ`` with ``PID_lka`` steering; 2.85
            already exceeds the 3 m/s² comfort limit on 4 % of ticks).
        curve_decel: Deceleration the speed target assumes when slowing for the turn [m/s²]
            (a closed throttle gives 1.2–1.6). Slowing early costs: at 1.0 the pass-first
            drive reached the zone's far end too late in 44 of the README's 1,000 scenarios,
            and the planner yielded where it could have passed (8.03 s on average instead of
            7.84 s, with ``ttr_margin_s`` 0.05 and ``preview_s`` 0.3). Much more than
            1.7 comes into the turn faster than the oracle's point-mass model allows: the
            plant's lateral acceleration lags the route's curvature, so the car stays within
            3 m/s², but it then beats the oracle (at 2.5, in 8 % of the scenarios), which
            would no longer be a limit.
        preview_s: The speed target is read this far ahead along the route [s].
        speed_gain: Throttle per m/s of speed error.
        ttr_margin_s: Added to the switching logic's TTR threshold in the pass-first check (the
            check simulates the very drive the planner then makes, north car included, so none
            is needed: 0 safety actions on 3,000 scenarios without one).
        stop_extra_m: Added to the switching logic's stop margin when yielding [m].
        yield_margin_s: Arrive at the firing point this long after the north car left its zone.
        yield_speed: Speed at which a yield arrives at the firing point [m/s] (3.5–4 is the
            fastest on the README's scenarios; 5.0 costs 0.05 s, the 6.8 of an arrival at the
            turn's speed 0.15 s).
        coast_decel: The deceleration a yield may count on to slow down to ``yield_speed``
            [m/s²] (a closed throttle gives 1.2–1.6; at 1.5 the switching logic fires in 5 %
            of the scenarios).
        creep: While waiting, never slower than this fraction of the constant speed that would
            arrive on time (keeps the car rolling instead of stopping early).
        recheck_ticks: Ticks between two pass-first checks (the decision holds in between).
    """

    ttr_margin_s: Annotated[float, NonNegative] = 0.0
    stop_extra_m: Annotated[float, NonNegative] = 0.3
    yield_margin_s: Annotated[float, NonNegative] = 0.1
    yield_speed: Annotated[float, Positive] = 4.0
    coast_decel: Annotated[float, Positive] = 1.0
    creep: Annotated[float, NonNegative] = 0.5

    def __post_init__(self) -> None:
        check_bounds(self, "planner")


@dataclass(frozen=True)
class GapPlannerConfig(FastDriveConfig):
    """Tuning of the gap planner (all ours).

    Attributes:
        top_speed_kmh: Speed on the straight [km/h] (the end of ``R_v``'s tolerated speeding).
        accel_lat: Lateral acceleration the turn is planned for [m/s²] (as the planner's).
        curve_decel: Deceleration the speed target assumes when slowing for the turn [m/s²].
        preview_s: The speed target is read this far ahead along the route [s].
        speed_gain: Throttle per m/s of speed error.
        stop_extra_m: Where a wait aims to stop, before the first crossing movement's conflict
            zone (the certified margin already included) [m].
        coast_decel: The deceleration a wait may count on to stop there [m/s²]. A closed
            throttle gives 1.2–1.6 above walking pace but little below it: aimed at 1 m before
            the zone at 1.0 m/s², the car crept the last metre and the filter's stop backup
            held it at the zone in 159 of 200 ``test`` scenes; at 3 m and 0.6 m/s², in none.
            With ``approach: brake``, the deceleration the wait brakes at.
        coast_band_m: Within this distance of where it would stop, a wait closes the throttle
            instead of tracking its ever slower target (the throttle of a walking pace is
            above the one that holds the car still, and a clone of it creeps on into the
            filter's stop). Not used by ``approach: brake``, which brakes to its stop.
        go_margin_s: Go only if the fast drive would also pass when begun this much later
            [s] (a clone of the planner, which cannot see everything the check does, goes a
            little late or a little slowly; a gap that would just pass labels it wrong).
        recheck_ticks: Ticks between two go checks (the decision holds in between).
        foresight: What the go check knows of the other vehicles. ``full``: everything the
            simulation holds, their drivers' yielding and the vehicles still to come included
            (a reference no onboard controller could be). ``observed``: only what a car could
            see, the vehicles on the approaches now, each assumed never to yield (the
            certified filter's own assumption); a teacher whose decisions a policy observing
            the traffic can learn.
        approach: How a wait slows for its stop. ``coast``: the throttle alone, the wait's
            speed no more than a closed throttle stops from (a throttle-only driver).
            ``brake``: in a scene with a learned brake (``controllers.learned_brake``), the
            wait holds ``sqrt(2 coast_decel room)`` — ``room`` the distance to its stop — with
            the brake wherever the car is faster, and the brake holds the car at the stop. In
            the ``traffic-certified`` recipe's scene, each action held 0.3 s, a braked approach
            at 2 m/s² to 4 m before the zone clears 227 of 1,000 ``test`` scenes at 0.3837 of
            the oracle, the coast 223 at 0.3781 (``experiments/probe_traffic_approach.py``).
    """

    stop_extra_m: Annotated[float, NonNegative] = 4.0
    coast_decel: Annotated[float, Positive] = 0.6
    coast_band_m: Annotated[float, NonNegative] = 10.0
    go_margin_s: Annotated[float, NonNegative] = 0.0
    foresight: Literal["full", "observed"] = "full"
    approach: Literal["coast", "brake"] = "coast"

    def __post_init__(self) -> None:
        check_bounds(self, "gap_planner")
        check(self.foresight in FORESIGHTS, "gap_planner", "foresight", self.foresight,
              f"must be one of {', '.join(FORESIGHTS)}")  # fmt: skip
        check(self.approach in APPROACHES, "gap_planner", "approach", self.approach,
              f"must be one of {', '.join(APPROACHES)}")  # fmt: skip

    def check_scene(self, learned_brake: bool, owner: str = "gap_planner") -> None:
        """Refuse a braked approach in a scene without the learned brake (``owner`` names
        this section where the message says so).

        Raises:
            ConfigError: ``approach`` is ``brake`` and ``learned_brake`` is false.
        """
        check(self.approach == "coast" or learned_brake, owner, "approach", self.approach,
              "brakes with the learned controller's brake: needs "
              "env.controllers.learned_brake=true")  # fmt: skip
