"""The ``certified`` switching logic for highway-env: a learned action is executed only if the
Safety controller can still keep the ego out of every other vehicle from where it leads.

``gymnasium.make("safeswitch/Highway-v0", switching="certified")``. The logic predicts the ego
one decision period ahead under the learned action (highway-env's kinematic bicycle, as ``ttc``
does), every other vehicle at its worst within the assumptions below, and accepts the action
only if, from there, the Safety controller (:class:`CertifiedHighwayController`: lane keeping
to the nearest lane centre, braking at up to ``ego_max_brake``) keeps the ego

* on the road, heading within ``max_heading`` of it, and going forward;
* at least ``min_gap`` behind every vehicle ahead whose lateral reach meets its own, when both
  brake to a standstill — the ego at ``ego_max_brake``, the other at the hardest braking it may
  show (the longitudinal distance of responsibility-sensitive safety, Shalev-Shwartz et al.
  2017);
* at least ``min_gap`` ahead of every vehicle behind whose lateral reach meets its own, when the
  ego brakes at ``ego_max_brake`` and that vehicle, after accelerating at up to
  ``follower_max_accel`` for ``follower_reaction`` s, brakes at ``follower_brake`` (the same
  distance, the other way round);
* never alongside a vehicle whose lateral reach meets its own.

The ego's lateral reach is the band its body sweeps from now until the lane keeper has brought
it to the centre of its nearest lane; another vehicle's is the band between its position, its
lane's centre and the centre of the lane it is changing to.

**Assumptions** (about highway-env's other vehicles; ``tests/examples/test_highway_certified.py``
checks each on its code and :mod:`benchmarks.highway_switch` counts what the ego meets):

1. No vehicle accelerates harder than 6 m/s² either way (its IDM clips at ±6; a crashed vehicle,
   which highway-env brings to rest at ``speed`` m/s², is charged with that).
2. A vehicle behind the ego accelerates at no more than 3 m/s² (IDM's free-road term) and brakes
   at ``follower_brake`` within ``follower_reaction`` s when the ego brakes ahead of it.
3. A vehicle shows the lane it is changing to as soon as it decides to (highway-env's
   ``target_lane_index``; a turn signal), and does not decide to change into the ego's lane in
   front of it (MOBIL refuses a change that would make the ego brake harder than 2 m/s²; the
   ego, which has no target speed, always would).

Under them no collision is the ego's doing; a vehicle that breaks them (two other vehicles
colliding beside the ego, say) can still hit it, and the benchmark counts every crash.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from safeswitch.core.arrays import clamp
from safeswitch.core.config import check
from safeswitch.core.registry import LogicContextError, context_name
from safeswitch.core.switching import BoolArray, Decision, FloatArray
from safeswitch.examples.highway import (
    ACCEL_RANGE,
    OTHER_MAX_BRAKE,
    STEER_RANGE,
    TRACKED,
    VEHICLE_COLUMNS,
    VEHICLE_LENGTH,
    VEHICLE_WIDTH,
    _lanes,
    highway_rules,
    is_highway,
    safety_command,
    stopping_margin,
)

_FIELDS = len(VEHICLE_COLUMNS)


@dataclass(frozen=True)
class CertifiedRules:
    """The numbers behind the ``certified`` logic and its Safety controller.

    Attributes:
        decision_period: Time between two decisions [s] (``1 / policy_frequency``).
        ego_max_brake: Braking the Safety controller commands [m/s²] (highway-env's full
            ``a = -1``).
        follower_max_accel: Hardest acceleration of a vehicle behind before it reacts [m/s²].
        follower_reaction: Time a vehicle behind takes to start braking [s] (one simulation
            frame of highway-env).
        follower_brake: Braking a vehicle behind applies once it reacts [m/s²].
        min_gap: Gap that must remain when both have braked to a stop [m].
        side_margin: Lateral clearance kept between the ego's reach and another's [m].
        pass_speed: Fastest the ego may pass a vehicle one lane beside its reach [m/s] (MOBIL
            may move a vehicle into the ego's lane right behind it, even alongside, when the
            ego is faster by more than about 13 m/s: its IDM then wants almost no gap).
        lane_width: How far a vehicle beside the ego may move towards it in one lane change
            [m] (highway-env's lanes are 4 m wide).
        max_heading: Largest heading relative to the road the learned action may reach [rad].
        lateral_gain: Steering of the lane keeper per metre of offset [rad/m].
        heading_gain: Steering per radian of heading error.
    """

    decision_period: float = 0.2
    ego_max_brake: float = 5.0
    follower_max_accel: float = 3.0
    follower_reaction: float = 0.2
    follower_brake: float = 5.0
    min_gap: float = 3.0
    side_margin: float = 0.5
    pass_speed: float = 10.0
    lane_width: float = 4.0
    max_heading: float = 0.3
    lateral_gain: float = 0.08
    heading_gain: float = 0.8

    def __post_init__(self) -> None:
        for name in ("decision_period", "ego_max_brake", "follower_brake", "max_heading"):
            value = getattr(self, name)
            check(math.isfinite(value) and value > 0, "certified", name, value, "must be > 0")
        for name in (
            "follower_max_accel", "follower_reaction", "min_gap", "side_margin", "pass_speed",
            "lane_width",
        ):  # fmt: skip
            value = getattr(self, name)
            check(math.isfinite(value) and value >= 0, "certified", name, value, "must be >= 0")


def _vehicles(state: FloatArray) -> dict[str, FloatArray]:
    """The tracked vehicles' :data:`VEHICLE_COLUMNS`, each ``[B, TRACKED]``."""
    block = state[:, state.shape[1] - TRACKED * _FIELDS :].reshape(state.shape[0], TRACKED, _FIELDS)
    return {name: block[..., k] for k, name in enumerate(VEHICLE_COLUMNS)}


def _nearest_centre(state: FloatArray, y: FloatArray) -> FloatArray:
    """The centre of the lane nearest ``y`` ``[B]``."""
    centres, _, _ = _lanes(state)
    return centres[np.arange(len(y)), np.abs(centres - y[:, None]).argmin(axis=1)]


def _half_width(heading: FloatArray) -> FloatArray:
    """Half the lateral extent of a car's body at ``heading`` from the road [m]."""
    h = np.abs(heading)
    return 0.5 * (VEHICLE_LENGTH * np.sin(h) + VEHICLE_WIDTH * np.cos(h))


def _meets(
    low: FloatArray,
    high: FloatArray,
    half: FloatArray,
    others: dict[str, FloatArray],
    margin: float,
) -> BoolArray:
    """``[B, K]``: present vehicles whose lateral reach comes within ``margin`` of the band the
    ego's centre sweeps, ``[low, high]`` ``[B]``, with a body ``half`` wide ``[B]``."""
    reach = half[:, None] + VEHICLE_WIDTH / 2 + margin
    return (
        (others["present"] > 0)
        & (others["y_low"] < high[:, None] + reach)
        & (others["y_high"] > low[:, None] - reach)
    )


def _follower_margin(
    gap: FloatArray, speed: FloatArray, follower: FloatArray, r: CertifiedRules
) -> FloatArray:
    """``[B, K]``: the gap left [m] when the ego (``speed`` ``[B]``) brakes to a standstill and
    the vehicle behind reacts (:class:`CertifiedRules`) and does too."""
    rho, accel = r.follower_reaction, r.follower_max_accel
    reacting = follower * rho + 0.5 * accel * rho * rho
    top = follower + accel * rho
    return (
        gap
        + (speed * speed / (2 * r.ego_max_brake))[:, None]
        - reacting
        - top * top / (2 * r.follower_brake)
    )


def _pass_margin(
    dx: FloatArray, speed: FloatArray, other: FloatArray, r: CertifiedRules
) -> FloatArray:
    """``[B, K]``: the distance [m] the ego has left, braking at ``ego_max_brake`` behind a
    vehicle that holds its speed, before it comes alongside it faster than ``pass_speed``
    (``inf`` where it is not that much faster; negative once alongside too fast)."""
    excess = speed[:, None] - other
    shed = (excess * excess - r.pass_speed * r.pass_speed) / (2 * r.ego_max_brake)
    return np.where(excess > r.pass_speed, dx - (VEHICLE_LENGTH + r.min_gap) - shed, np.inf)


class CertifiedHighwayController:
    """The Safety controller ``certified`` reasons about: keep the nearest lane's centre (a PD
    law on the offset and heading error, as :class:`~safeswitch.examples.highway.
    HighwaySafetyController`), brake at ``ego_max_brake`` (never below standstill) when the
    braking envelope to a vehicle ahead whose reach meets the ego's is short, or when it would
    otherwise come alongside a vehicle one lane beside it faster than ``pass_speed``; hold the
    speed otherwise.

    Args:
        rules: Gains and limits.
    """

    def __init__(self, rules: CertifiedRules | None = None) -> None:
        self.rules = rules or CertifiedRules()

    def __call__(self, state: FloatArray) -> FloatArray:
        r = self.rules
        speed, heading, lateral, y = state[:, 0], state[:, 1], state[:, 2], state[:, 3]
        centre = _nearest_centre(state, y)
        others = _vehicles(state)
        low, high = np.minimum(y, centre), np.maximum(y, centre)
        meets = _meets(low, high, _half_width(heading), others, r.side_margin)
        ahead = meets & (others["dx"] > 0)
        margin = stopping_margin(
            others["dx"] - VEHICLE_LENGTH,
            speed[:, None],
            others["speed"],
            _brakes(others),
            r.ego_max_brake,
        )
        short = (ahead & (margin < (2 * r.min_gap + speed * r.decision_period)[:, None])).any(1)
        beside = _meets(low, high, _half_width(heading), others, r.side_margin + r.lane_width)
        passing = _pass_margin(others["dx"], speed, others["speed"], r)
        closing = (speed[:, None] - others["speed"]) * r.decision_period
        short |= (beside & (others["dx"] > 0) & (passing < r.min_gap + closing)).any(1)
        return safety_command(speed, heading, lateral, np.asarray(short), r)


def _brakes(others: dict[str, FloatArray]) -> FloatArray:
    """Each vehicle's hardest braking [m/s²] (empty slots: the IDM bound, to stay finite)."""
    return np.where(others["present"] > 0, others["max_brake"], OTHER_MAX_BRAKE)


class CertifiedHighwayLogic:
    """The ``certified`` switching logic for highway-env (see the module docstring).

    Args:
        rules: Assumptions, margins and the decision period.
    """

    reasons: tuple[str, ...] = (
        "learned",
        "leader",
        "follower",
        "alongside",
        "off_road",
        "reversing",
        "passing",
    )

    def __init__(self, rules: CertifiedRules | None = None) -> None:
        self.rules = rules or CertifiedRules()

    def decide(self, state: FloatArray, learned: FloatArray, safe: FloatArray) -> Decision:
        r, dt = self.rules, self.rules.decision_period
        speed, heading, y = state[:, 0], state[:, 1], state[:, 3]
        # the ego one period ahead on highway-env's bicycle: position and heading move with the
        # current speed, then the speed with the acceleration
        accel = clamp(learned[:, 0], -1.0, 1.0) * ACCEL_RANGE
        slip = np.arctan(0.5 * np.tan(clamp(learned[:, 1], -1.0, 1.0) * STEER_RANGE))
        travelled = speed * np.cos(heading + slip) * dt
        y1 = y + speed * np.sin(heading + slip) * dt
        heading1 = heading + speed * np.sin(slip) / (0.5 * VEHICLE_LENGTH) * dt
        speed1 = speed + accel * dt
        reversing = speed1 < 0
        speed1 = np.maximum(speed1, 0.0)
        # the band the lane keeper may sweep from there: two more periods of lateral drift and
        # the centre of the lane it returns to
        drift = 2 * speed1 * np.sin(heading1) * dt
        centre1 = _nearest_centre(state, y1)
        low = np.minimum.reduce([y, y1 + np.minimum(drift, 0.0), centre1])
        high = np.maximum.reduce([y, y1 + np.maximum(drift, 0.0), centre1])
        off_road = (low < state[:, 4]) | (high > state[:, 5]) | (np.abs(heading1) > r.max_heading)
        others = _vehicles(state)
        half = _half_width(np.maximum(np.abs(heading), np.abs(heading1)))
        meets = _meets(low, high, half, others, r.side_margin)
        dx, other_speed = others["dx"], others["speed"]
        # a vehicle ahead at its hardest braking over the period, one behind at its hardest
        # acceleration
        brakes = _brakes(others)
        lead1 = np.maximum(other_speed - brakes * dt, 0.0)
        lead_gap1 = dx - VEHICLE_LENGTH + 0.5 * (other_speed + lead1) * dt - travelled[:, None]
        follower1 = other_speed + r.follower_max_accel * dt
        follow_gap1 = (
            -dx - VEHICLE_LENGTH - (other_speed + 0.5 * r.follower_max_accel * dt) * dt
        ) + travelled[:, None]
        ahead = meets & (dx >= VEHICLE_LENGTH)
        behind = meets & (dx <= -VEHICLE_LENGTH)
        leader = ahead & (
            (lead_gap1 < r.min_gap)
            | (
                stopping_margin(lead_gap1, speed1[:, None], lead1, brakes, r.ego_max_brake)
                < r.min_gap
            )
        )
        follower = behind & (
            (follow_gap1 < 0.0) | (_follower_margin(follow_gap1, speed1, follower1, r) < r.min_gap)
        )
        alongside = meets & ~ahead & ~behind
        # a vehicle one lane beside the ego's reach may move in right behind it (MOBIL) when
        # the ego passes it much faster: never come alongside one that way
        beside = _meets(low, high, half, others, r.side_margin + r.lane_width)
        held = dx + other_speed * dt - travelled[:, None]  # the other holding its speed
        passing = beside & (held > -(VEHICLE_LENGTH + r.min_gap))
        passing &= _pass_margin(held, speed1, other_speed, r) < 0
        reason = np.select(
            [reversing, alongside.any(1), leader.any(1), follower.any(1), passing.any(1),
             off_road],
            [5, 3, 1, 2, 6, 4],
            0,
        ).astype(np.int8)  # fmt: skip
        return Decision(reason > 0, reason, safe)


def certified_rules(env: object) -> CertifiedRules:
    """The rules for a highway-env environment: its decision period."""
    return CertifiedRules(decision_period=highway_rules(env).decision_period)


def certified_highway_logic(context: object) -> CertifiedHighwayLogic:
    """Factory of the ``certified`` logic for highway-env plants."""
    if not is_highway(context):
        raise LogicContextError(
            f"the highway 'certified' logic supervises highway-env plants, not "
            f"{context_name(context)}"
        )
    return CertifiedHighwayLogic(certified_rules(context))


__all__ = [
    "CertifiedHighwayController",
    "CertifiedHighwayLogic",
    "CertifiedRules",
    "certified_highway_logic",
    "certified_rules",
]
