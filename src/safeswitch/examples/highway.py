"""The framework on a plant nobody here wrote: highway-env's multi-lane highway.

``gymnasium.make("safeswitch/Highway-v0", switching="ttc")`` is highway-env's
``highway-fast-v0`` (Leurent, *An Environment for Autonomous Driving Decision-Making*, 2018)
with continuous acceleration and steering, wrapped in :class:`~safeswitch.core.wrappers.SafeSwitch`:

* **Learned controller** — the agent's action ``(a, δ) ∈ [-1, 1]²``: acceleration ``5·a`` m/s²
  and front-wheel angle ``δ·π/4`` (highway-env's ``ContinuousAction``).
* **Safety controller** (:class:`HighwaySafetyController`, rule-based) — brakes at
  ``ego_max_brake`` (not below standstill) when the braking envelope to the vehicle ahead is
  short, else holds its speed; steers back to the centre of the nearest lane (a PD law on the
  lateral offset and heading error).
* **Switching logic** ``ttc`` (:class:`TimeToCollisionLogic`, registered by name) — executes the
  learned action unless, after one decision period of it (predicted on highway-env's own
  kinematic bicycle), the ego would (a) close on the vehicle ahead in any lane it may occupy so
  that full braking could no longer stop it ``min_gap`` behind a leader braking at
  ``lead_max_brake`` (the responsibility-sensitive-safety distance of Shalev-Shwartz et al.,
  2017), or come within ``min_ttc`` seconds of it at the current closing speed; (b) leave the
  road or turn more than ``max_heading`` from it; (c) come within 0.5 m of a vehicle alongside;
  or (d) roll backwards (highway-env's vehicle reverses when braked below standstill).

Other vehicles follow IDM and change lanes with MOBIL (highway-env's defaults); they may cut in
closer than the envelope, which no rule on the ego can prevent: the benchmark
``benchmarks/highway_switch.py`` measures what the switch achieves, it does not assume it.

Highway-env is imported only when an environment is made.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import gymnasium as gym
import numpy as np

from safeswitch.core.arrays import clamp
from safeswitch.core.config import check
from safeswitch.core.registry import LogicContextError, LogicPlugin, context_name
from safeswitch.core.switching import BoolArray, Decision, FloatArray

#: The Gymnasium id this module registers (in :mod:`safeswitch`).
ENV_ID = "safeswitch/Highway-v0"

ACCEL_RANGE = 5.0  # [m/s²] highway-env's ContinuousAction maps a ∈ [-1, 1] to ±5 m/s²
STEER_RANGE = math.pi / 4  # [rad] and δ ∈ [-1, 1] to ±45°
VEHICLE_LENGTH = 5.0  # [m] highway-env's Vehicle.LENGTH
VEHICLE_WIDTH = 2.0  # [m] highway-env's Vehicle.WIDTH
ALONGSIDE = 3.0  # [m] longitudinal margin within which a vehicle in another lane is alongside
SIDE_MARGIN = 0.5  # [m] lateral clearance the learned action must leave to a vehicle alongside
OTHER_MAX_BRAKE = 6.0  # [m/s²] highway-env's IDM clips its vehicles' acceleration at ±6 m/s²

#: highway-env configuration of ``safeswitch/Highway-v0`` (on top of ``highway-fast-v0``).
HIGHWAY_CONFIG: dict[str, Any] = {
    "action": {"type": "ContinuousAction", "longitudinal": True, "lateral": True},
    "observation": {
        "type": "Kinematics",
        "vehicles_count": 5,
        "features": ["presence", "x", "y", "vx", "vy", "cos_h", "sin_h"],
        "absolute": False,
        "normalize": True,
    },
    "simulation_frequency": 5,  # [Hz] one simulation frame per decision
    "policy_frequency": 5,  # [Hz]
    "lanes_count": 3,
    "vehicles_count": 15,
    "duration": 30,  # [s]
    "offroad_terminal": True,
}

#: The state the Safety controller and the logic read, ``[B, 8 + 3·lanes + 7·TRACKED]``: these
#: columns, then per lane (lowest ``y`` first) its centre [m], the bumper-to-bumper gap to the
#: nearest vehicle ahead that overlaps the lane [m] (1,000 if none) and that vehicle's speed
#: [m/s], then the :data:`TRACKED` nearest other vehicles (:data:`VEHICLE_COLUMNS` each).
STATE_COLUMNS = (
    "speed",  # ego speed [m/s]
    "heading",  # ego heading relative to the road [rad]
    "lateral",  # ego offset from the centre of its nearest lane [m]
    "y",  # ego lateral position on the road [m]
    "road_low",  # lowest lateral position the ego's centre may take on the road [m]
    "road_high",  # highest [m]
    "room_left",  # lateral clearance to the nearest vehicle alongside, towards +y [m]
    "room_right",  # towards -y [m]
)
_LANES = len(STATE_COLUMNS)  # first per-lane column

#: Per tracked vehicle (nearest first, by distance along the road; absent slots are all zero).
VEHICLE_COLUMNS = (
    "present",  # 1 for a vehicle, 0 for an empty slot
    "dx",  # its centre's position along the road less the ego's [m]
    "y",  # its centre's lateral position [m]
    "speed",  # its speed along the road [m/s]
    "y_low",  # lowest lateral position its centre may take until its manoeuvre ends [m]
    "y_high",  # highest [m]
    "max_brake",  # the hardest braking it may show [m/s²] (a crashed car stops faster)
)
#: How many of the other vehicles the state carries (highway-fast-v0 has 15 on its road).
TRACKED = 16


@dataclass(frozen=True)
class HighwayRules:
    """The numbers behind the Safety controller and the ``ttc`` logic.

    Attributes:
        decision_period: Time between two decisions [s] (``1 / policy_frequency``).
        ego_max_brake: Braking the Safety controller commands [m/s²] (highway-env's full
            ``a = -1``).
        lead_max_brake: Assumed hardest braking of a leader [m/s²] (highway-env's IDM caps
            its acceleration at ±6 m/s²).
        min_gap: Gap that must remain when both have braked to a stop [m].
        min_ttc: Smallest time to collision at the current closing speed [s].
        max_heading: Largest heading relative to the road the learned action may reach [rad]
            (beyond it the lane keeper needs several decisions to turn the car back).
        lateral_gain: Steering of the lane keeper per metre of offset [rad/m].
        heading_gain: Steering per radian of heading error.
    """

    decision_period: float = 0.2
    ego_max_brake: float = 5.0
    lead_max_brake: float = OTHER_MAX_BRAKE
    min_gap: float = 3.0
    min_ttc: float = 1.5
    max_heading: float = 0.3
    lateral_gain: float = 0.08
    heading_gain: float = 0.8


def highway_state(env: gym.Env[Any, Any]) -> FloatArray:
    """What the Safety controller and the logic see of a highway-env environment (see
    :data:`STATE_COLUMNS`), ``[1, 8 + 3·lanes]``, read from its road: the straight road runs
    along ``x``; a vehicle overlaps a lane when its centre is within half a lane plus half a
    car of the lane's centre line."""
    road = env.unwrapped.road  # type: ignore[attr-defined]
    ego = env.unwrapped.vehicle  # type: ignore[attr-defined]
    x, y = float(ego.position[0]), float(ego.position[1])
    lane = road.network.get_lane(ego.lane_index)
    _, lateral = lane.local_coordinates(ego.position)
    heading = float(ego.heading - lane.heading_at(0.0))
    heading = (heading + math.pi) % (2 * math.pi) - math.pi
    lanes = sorted(
        (float(lane_.start[1]), float(lane_.width_at(0.0))) for lane_ in road.network.lanes_list()
    )
    low = lanes[0][0] - lanes[0][1] / 2 + VEHICLE_WIDTH / 2
    high = lanes[-1][0] + lanes[-1][1] / 2 - VEHICLE_WIDTH / 2
    gaps = [1e3] * len(lanes)
    speeds = [float(ego.speed)] * len(lanes)
    left, right = 1e3, 1e3
    for other in road.vehicles:
        if other is ego:
            continue
        ox, oy = float(other.position[0]), float(other.position[1])
        dx, dy = ox - x, oy - y
        if abs(dx) < VEHICLE_LENGTH + ALONGSIDE and abs(dy) >= VEHICLE_WIDTH:
            if dy > 0:
                left = min(left, dy - VEHICLE_WIDTH)
            else:
                right = min(right, -dy - VEHICLE_WIDTH)
        if dx <= 0:
            continue
        for k, (centre, width) in enumerate(lanes):
            if abs(oy - centre) < (width + VEHICLE_WIDTH) / 2 and dx - VEHICLE_LENGTH < gaps[k]:
                gaps[k], speeds[k] = dx - VEHICLE_LENGTH, float(other.speed)
    row = [float(ego.speed), heading, float(lateral), y, low, high, left, right]
    for (centre, _), gap, speed in zip(lanes, gaps, speeds, strict=True):
        row += [centre, gap, speed]
    return np.array([row + _tracked(road, ego)])


def _tracked(road: Any, ego: Any) -> list[float]:
    """The :data:`VEHICLE_COLUMNS` of the :data:`TRACKED` vehicles nearest the ego along the
    road, flattened. A vehicle's lateral reach spans its position, its lane's centre and the
    centre of the lane it is changing to (highway-env's ``target_lane_index``: the intent a
    turn signal shows); a crashed vehicle is brought to rest at ``speed`` m/s² (highway-env),
    which stops it within ``speed`` · 1 s, as braking at ``speed / 2`` would."""
    x = float(ego.position[0])
    network = road.network
    rows = []
    for other in road.vehicles:
        if other is ego:
            continue
        oy = float(other.position[1])
        centres = [oy, float(network.get_lane(other.lane_index).start[1])]
        target = getattr(other, "target_lane_index", None)
        if target is not None:
            centres.append(float(network.get_lane(target).start[1]))
        speed = float(other.speed)
        brake = max(OTHER_MAX_BRAKE, speed / 2) if other.crashed else OTHER_MAX_BRAKE
        dx = float(other.position[0]) - x
        rows.append((abs(dx), [1.0, dx, oy, speed * math.cos(other.heading), min(centres),
                               max(centres), brake]))  # fmt: skip
    rows.sort(key=lambda row: row[0])
    flat = [value for _, columns in rows[:TRACKED] for value in columns]
    return flat + [0.0] * (TRACKED * len(VEHICLE_COLUMNS) - len(flat))


def _lanes(state: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per lane ``[B, L]``: centre, gap to the vehicle ahead, its speed."""
    end = state.shape[1] - TRACKED * len(VEHICLE_COLUMNS)
    per_lane = state[:, _LANES:end].reshape(state.shape[0], -1, 3)
    return per_lane[..., 0], per_lane[..., 1], per_lane[..., 2]


def _overlapping(centres: FloatArray, low: FloatArray, high: FloatArray) -> BoolArray:
    """Lanes ``[B, L]`` the ego overlaps while its centre is anywhere in ``[low, high]``
    (4 m lanes)."""
    half = 2.0 + VEHICLE_WIDTH / 2
    return (centres > low[:, None] - half) & (centres < high[:, None] + half)


def stopping_margin(
    gap: FloatArray, speed: FloatArray, lead: FloatArray, lead_brake: Any, ego_brake: float
) -> FloatArray:
    """Gap left [m] when the ego (``speed`` ``[B, 1]``) brakes at ``ego_brake`` and the
    vehicle ahead (``lead``) at ``lead_brake`` from now on, both until standstill."""
    return gap + lead * lead / (2 * lead_brake) - speed * speed / (2 * ego_brake)


def safety_command(
    speed: FloatArray,
    heading: FloatArray,
    lateral: FloatArray,
    brake_now: BoolArray,
    rules: Any,
) -> FloatArray:
    """A Safety controller's action ``[B, 2]``: brake at ``rules.ego_max_brake`` where
    ``brake_now`` (never more than stops the car within one decision period, and never in
    reverse: highway-env's vehicle would roll backwards, and one that does is brought to rest),
    hold the speed elsewhere; steer back to the nearest lane's centre (a PD law on the offset
    and heading error, ``rules.lateral_gain`` and ``rules.heading_gain``)."""
    brake = np.minimum(rules.ego_max_brake, np.abs(speed) / rules.decision_period)
    steer = -rules.lateral_gain * lateral - rules.heading_gain * heading
    out = np.empty((speed.shape[0], 2))
    out[:, 0] = np.where(brake_now | (speed < 0), -np.sign(speed) * brake / ACCEL_RANGE, 0.0)
    out[:, 1] = clamp(steer / STEER_RANGE, -1.0, 1.0)
    return out


class HighwaySafetyController:
    """Brake when the braking envelope is short, hold speed otherwise; keep the lane.

    Args:
        rules: Gains and limits.
    """

    def __init__(self, rules: HighwayRules | None = None) -> None:
        self.rules = rules or HighwayRules()

    def __call__(self, state: FloatArray) -> FloatArray:
        r = self.rules
        speed, heading, lateral, y = state[:, 0], state[:, 1], state[:, 2], state[:, 3]
        centres, gaps, leads = _lanes(state)
        margin = stopping_margin(gaps, speed[:, None], leads, r.lead_max_brake, r.ego_max_brake)
        short = np.where(_overlapping(centres, y, y), margin, np.inf).min(axis=1)
        short = short < 2 * r.min_gap + speed * r.decision_period
        return safety_command(speed, heading, lateral, short, r)


class TimeToCollisionLogic:
    """The ``ttc`` switching logic (see the module docstring).

    Args:
        rules: Thresholds and the decision period.
    """

    reasons: tuple[str, ...] = (
        "learned",
        "braking_envelope",
        "time_to_collision",
        "off_road",
        "vehicle_alongside",
        "reversing",
    )

    def __init__(self, rules: HighwayRules | None = None) -> None:
        self.rules = rules or HighwayRules()

    def predict(self, state: FloatArray, action: FloatArray) -> tuple[FloatArray, ...]:
        """The ego one decision period ahead under ``action`` ``[B, 2]``, on highway-env's
        kinematic bicycle (position and heading with the current speed, then the speed): its
        gap to the leader of every lane ``[B, L]`` (each leader may brake hard meanwhile), its
        speed, the leaders' speeds ``[B, L]``, its lateral position and its heading."""
        r, dt = self.rules, self.rules.decision_period
        speed, heading, y = state[:, 0], state[:, 1], state[:, 3]
        _, gaps, leads = _lanes(state)
        accel = action[:, 0] * ACCEL_RANGE
        slip = np.arctan(0.5 * np.tan(action[:, 1] * STEER_RANGE))
        travelled = speed * np.cos(heading + slip) * dt
        leads_next = np.maximum(leads - r.lead_max_brake * dt, 0.0)
        leads_travelled = 0.5 * (leads + leads_next) * dt
        return (
            gaps - travelled[:, None] + leads_travelled,
            speed + accel * dt,
            leads_next,
            y + speed * np.sin(heading + slip) * dt,
            heading + speed * np.sin(slip) / (0.5 * VEHICLE_LENGTH) * dt,
        )

    def decide(self, state: FloatArray, learned: FloatArray, safe: FloatArray) -> Decision:
        r = self.rules
        gaps1, speed1, leads1, y1, heading1 = self.predict(state, learned)
        # highway-env's vehicle reverses when braked below standstill; the lane keeper (and
        # the road) assume it goes forward
        reversing = speed1 < 0
        speed1 = np.maximum(speed1, 0.0)
        # where the car can get to while the lane keeper turns it back: two more periods of
        # its lateral drift
        drift = 2 * speed1 * np.sin(heading1) * r.decision_period
        reach_high, reach_low = y1 + np.maximum(drift, 0.0), y1 + np.minimum(drift, 0.0)
        y = state[:, 3]
        centres, _, _ = _lanes(state)
        relevant = _overlapping(centres, np.minimum(reach_low, y), np.maximum(reach_high, y))
        margin = stopping_margin(gaps1, speed1[:, None], leads1, r.lead_max_brake, r.ego_max_brake)
        envelope = (relevant & (margin < r.min_gap)).any(axis=1)
        closing = speed1[:, None] - leads1
        ttc = np.where(closing > 0, gaps1 / np.maximum(closing, 1e-9), np.inf)
        too_soon = (relevant & (ttc < r.min_ttc)).any(axis=1)
        off_road = (
            (reach_low < state[:, 4])
            | (reach_high > state[:, 5])
            | (np.abs(heading1) > r.max_heading)
        )
        alongside = (reach_high - y > state[:, 6] - SIDE_MARGIN) | (
            y - reach_low > state[:, 7] - SIDE_MARGIN
        )
        reason = np.select([reversing, envelope, too_soon, off_road, alongside], [5, 1, 2, 3, 4], 0)
        reason = reason.astype(np.int8)
        return Decision(reason > 0, reason, safe)


@dataclass(frozen=True)
class TTCParams:
    """The ``ttc`` logic's thresholds, configurable from a file (``logic_params:``); the
    decision period comes from the environment.

    Attributes:
        lead_max_brake: Assumed hardest braking of a leader [m/s²].
        min_gap: Gap that must remain when both have braked to a stop [m].
        min_ttc: Smallest time to collision at the current closing speed [s].
        max_heading: Largest heading relative to the road the learned action may reach [rad].
    """

    lead_max_brake: float = HighwayRules.lead_max_brake
    min_gap: float = HighwayRules.min_gap
    min_ttc: float = HighwayRules.min_ttc
    max_heading: float = HighwayRules.max_heading

    def __post_init__(self) -> None:
        for name in ("lead_max_brake", "min_gap", "min_ttc", "max_heading"):
            value = getattr(self, name)
            check(math.isfinite(value) and value > 0, "ttc", name, value, "must be > 0")


def is_highway(context: object) -> bool:
    """Whether ``context`` is a highway-env environment (it has a road)."""
    return getattr(getattr(context, "unwrapped", None), "road", None) is not None


def ttc_logic(context: object, params: TTCParams | None = None) -> TimeToCollisionLogic:
    """Factory of the ``ttc`` logic (registered under that name, with :class:`TTCParams`)
    for highway-env plants."""
    if not is_highway(context):
        raise LogicContextError(
            f"the 'ttc' switching logic supervises highway-env plants, not {context_name(context)}"
        )
    rules = highway_rules(context)
    return TimeToCollisionLogic(replace(rules, **asdict(params or TTCParams())))


#: ``ttc`` as its entry point declares it: the factory and the class of its parameters.
TTC = LogicPlugin(ttc_logic, config=TTCParams)


def highway_rules(env: object) -> HighwayRules:
    """The ``ttc`` rules for a highway-env environment: its decision period."""
    config = getattr(getattr(env, "unwrapped", None), "config", {})
    return HighwayRules(decision_period=1.0 / float(config.get("policy_frequency", 5)))


def collided(info: dict[str, Any]) -> bool:
    """Whether a highway-env step ended in a crash."""
    return bool(info.get("crashed", False))


__all__ = [
    "ENV_ID",
    "HIGHWAY_CONFIG",
    "HighwayRules",
    "HighwaySafetyController",
    "TimeToCollisionLogic",
    "collided",
    "highway_rules",
    "highway_state",
    "safety_command",
    "stopping_margin",
    "ttc_logic",
]
