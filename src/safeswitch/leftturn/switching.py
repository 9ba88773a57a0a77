"""Switching logics of the left-turn case study.

``paper`` — the emergency-braking ADAS of Algorithm 1, read as the paper's text describes it.
The printed algorithm executes the safety action when ``TTR_n − TTR_e > threshold`` *and*
``d_safe < d_c``: when there *is* time to cut in front and the car is still *far* from the
stopping point — the opposite of what the text says ("applies emergency braking ... when cutting
is not an option", "from where the AV must always switch to the Safe controller ... to ensure
braking ... not further away from the waypoint located right before the conflict one"). We
follow the text (SPEC §2): while both cars are at the intersection and the north car has not
passed, the safety action is executed when

* there is no safe time gap to cut in front: ``TTR_n − TTR_e < threshold`` (Eq. 2 with path
  distances summed over waypoints, speeds guarded against 0), and
* the ego has reached its braking point: ``d_stop ≤ d_safe + v·latency + margin`` with
  ``d_safe = v²/(2·a_max)`` (Eq. 3 with ``v_f = 0``).

``d_stop`` is the path distance to the stopping point. The paper stops "before the waypoint prior
to the conflict one"; for cars with extent that is the first waypoint at which the ego's
footprint could touch the north car's: the entry of the ego's conflict zone, computed from the
geometry (:func:`safeswitch.sim.conflict.conflict_geometry`).

This rule is a heuristic: a learned controller that passes the braking point while the gap looks
large and then slows down inside the conflict zone is not kept out of it (braking there cannot
stop it before the zone). The ``certified`` logic closes that gap.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple, TypeVar

import numpy as np

from safeswitch.core.arrays import jit
from safeswitch.core.registry import LogicContextError, context_name
from safeswitch.core.switching import BoolArray, Decision, FloatArray, Guarded
from safeswitch.leftturn.config import PaperSwitchingConfig

if TYPE_CHECKING:
    from safeswitch.leftturn.task import LeftTurnTask


@dataclass
class ConflictState:
    """What a left-turn switching logic sees of the plant, each field ``[B]``.

    Attributes:
        ego_to_conflict: Ego's path distance to the conflict point ``d_c^e`` [m] (negative past).
        ego_to_stop: Ego's path distance to its stopping point (conflict-zone entry) [m].
        ego_speed: ``v_e`` [m/s].
        north_to_conflict: North car's path distance to the conflict point ``d_c^n`` [m].
        north_speed: ``v_n`` [m/s].
        both_at_intersection: Algorithm 1's While condition: both cars are at the
            intersection and neither has left its conflict zone.
        ego_progress: Ego's arc length along its route [m].
        north_progress: North car's arc length along its route [m].
        ego_throttle: Ego's actual throttle position (after the actuator lag).
        ego_brake: Ego's actual brake position.
    """

    ego_to_conflict: FloatArray
    ego_to_stop: FloatArray
    ego_speed: FloatArray
    north_to_conflict: FloatArray
    north_speed: FloatArray
    both_at_intersection: BoolArray
    ego_progress: FloatArray
    north_progress: FloatArray
    ego_throttle: FloatArray
    ego_brake: FloatArray


#: Arrays or scalars: the Eq. 2 and Eq. 3 helpers serve the numpy code and the compiled loops.
Values = TypeVar("Values", FloatArray, float)


class PaperConstants(NamedTuple):
    """What the compiled Algorithm 1 reads (see :class:`PaperSwitchingConfig`).

    Attributes:
        ttr_threshold_s: Smallest ``TTR_n − TTR_e`` at which cutting in front counts [s].
        min_speed: Speed floor of Eq. 2 [m/s].
        emergency_decel: ``a_max_lon`` of Eq. 3 [m/s²].
        latency_s: Time before full braking takes hold [s].
        stop_margin_m: Distance added to ``d_safe`` [m].
    """

    ttr_threshold_s: float
    min_speed: float
    emergency_decel: float
    latency_s: float
    stop_margin_m: float


@jit
def time_to_reach(distance: Values, speed: Values, min_speed: float) -> Values:
    """``TTR = d_c / v`` (Eq. 2) [s], with ``v`` floored at ``min_speed`` [m/s] (arrays or
    scalars)."""
    return distance / np.maximum(speed, min_speed)


@jit
def braking_distance(speed: Values, deceleration: float) -> Values:
    """``d_safe = (v_f² − v_i²) / (2a)`` with ``v_f = 0`` and ``a = −deceleration`` (Eq. 3) [m]
    (arrays or scalars)."""
    return speed * speed / (2.0 * deceleration)


@jit
def firing_distance(speed: Values, c: PaperConstants) -> Values:
    """``d_safe + v·latency + margin`` [m]: how far before its stopping point Algorithm 1 fires
    at ``speed`` (arrays or scalars)."""
    return braking_distance(speed, c.emergency_decel) + speed * c.latency_s + c.stop_margin_m


@jit
def paper_switches(
    ego_to_conflict: float,
    ego_to_stop: float,
    ego_speed: float,
    north_to_conflict: float,
    north_speed: float,
    both_at_intersection: bool,
    c: PaperConstants,
) -> bool:
    """Algorithm 1 for one episode: both cars at the intersection, ``TTR_n − TTR_e <
    threshold`` (no gap to cut in front) and ``d_stop ≤ d_safe + v·latency + margin`` (the last
    moment to stop before the zone)."""
    if not both_at_intersection:
        return False
    ttr_e = time_to_reach(max(ego_to_conflict, 0.0), ego_speed, c.min_speed)
    ttr_n = time_to_reach(north_to_conflict, north_speed, c.min_speed)
    if not ttr_n - ttr_e < c.ttr_threshold_s:
        return False
    return ego_to_stop <= firing_distance(ego_speed, c)


@jit
def _map_paper_switches(
    ego_to_conflict: FloatArray, ego_to_stop: FloatArray, ego_speed: FloatArray,
    north_to_conflict: FloatArray, north_speed: FloatArray, both: BoolArray, c: PaperConstants,
    out: BoolArray,
) -> None:  # fmt: skip
    for i in range(out.shape[0]):
        out[i] = paper_switches(
            ego_to_conflict[i], ego_to_stop[i], ego_speed[i], north_to_conflict[i],
            north_speed[i], both[i], c,
        )  # fmt: skip


class PaperSwitching:
    """Algorithm 1 as its text describes it (see the module docstring).

    Args:
        config: Threshold, margins and speed guard.
        emergency_decel: ``a_max_lon`` of Eq. 3 [m/s²] (the deceleration ``PID_b`` tracks).
    """

    reasons: tuple[str, ...] = ("learned", "no_gap_at_braking_point")

    def __init__(self, config: PaperSwitchingConfig, emergency_decel: float) -> None:
        self.config = config
        self.emergency_decel = emergency_decel
        c = config
        #: What :func:`paper_switches` reads.
        self.constants = PaperConstants(
            c.ttr_threshold_s, c.min_speed, emergency_decel, c.latency_s, c.stop_margin_m
        )

    def decide(self, state: ConflictState, learned: FloatArray, safe: FloatArray) -> Decision:
        s = state
        use = np.empty(learned.shape[0], dtype=np.bool_)
        _map_paper_switches(
            s.ego_to_conflict, s.ego_to_stop, s.ego_speed, s.north_to_conflict, s.north_speed,
            np.asarray(s.both_at_intersection, dtype=np.bool_), self.constants, use,
        )  # fmt: skip
        return Decision(use, use.astype(np.int8), safe)


def paper_logic(task: LeftTurnTask) -> PaperSwitching:
    """Factory of the ``paper`` logic (registered under that name) for a left-turn task."""
    config = getattr(task, "config", None)
    paper = getattr(config, "paper", None)
    if not isinstance(paper, PaperSwitchingConfig):
        raise LogicContextError(
            f"the 'paper' switching logic supervises the left-turn task, not {context_name(task)}"
        )
    from safeswitch.leftturn.traffic import LeftTurnTrafficTask

    if isinstance(task, LeftTurnTrafficTask):  # in traffic: every conflicting vehicle
        from safeswitch.leftturn.traffic_logics import PaperTrafficSwitching

        return PaperTrafficSwitching(
            paper, task.config.controllers.emergency_decel, task.config.episode.approach_distance_m
        )
    return PaperSwitching(paper, task.config.controllers.emergency_decel)


def guarded_logic(task: LeftTurnTask) -> Guarded:
    """Factory of the ``guarded`` logic (registered under that name; ours): the paper's
    Algorithm 1 in the loop, the ``certified`` filter beneath it judging what it lets through
    (:class:`~safeswitch.core.switching.Guarded`). The certificate's guarantee — no collision
    for any proposed action sequence — covers the pair, so a policy can explore under the
    paper's logic, and be charged ``R_ADAS`` for both, without the paper logic's known gap
    (a car stopped inside the conflict zone) costing a collision. In traffic, both logics'
    traffic versions."""
    from safeswitch.leftturn.certified import certified_logic

    return Guarded(paper_logic(task), certified_logic(task))
