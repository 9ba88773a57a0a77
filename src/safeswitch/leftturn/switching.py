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

import numpy as np

from safeswitch.core.switching import BoolArray, Decision, FloatArray
from safeswitch.leftturn.config import PaperSwitchingConfig


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


def time_to_reach(distance: FloatArray, speed: FloatArray, min_speed: float) -> FloatArray:
    """``TTR = d_c / v`` (Eq. 2) [s], with ``v`` floored at ``min_speed`` [m/s]."""
    return distance / np.maximum(speed, min_speed)


def braking_distance(speed: FloatArray, deceleration: float) -> FloatArray:
    """``d_safe = (v_f² − v_i²) / (2a)`` with ``v_f = 0`` and ``a = −deceleration`` (Eq. 3) [m]."""
    return speed * speed / (2.0 * deceleration)


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

    def no_gap(self, s: ConflictState) -> BoolArray:
        """``TTR_n − TTR_e < threshold``: cutting in front is not an option."""
        c = self.config
        ttr_e = time_to_reach(np.maximum(s.ego_to_conflict, 0.0), s.ego_speed, c.min_speed)
        ttr_n = time_to_reach(s.north_to_conflict, s.north_speed, c.min_speed)
        return ttr_n - ttr_e < c.ttr_threshold_s

    def at_braking_point(self, s: ConflictState) -> BoolArray:
        """``d_stop ≤ d_safe + v·latency + margin``: the last moment to stop before the zone."""
        c = self.config
        reach = (
            braking_distance(s.ego_speed, self.emergency_decel)
            + s.ego_speed * c.latency_s
            + c.stop_margin_m
        )
        return s.ego_to_stop <= reach

    def decide(self, state: ConflictState, learned: FloatArray, safe: FloatArray) -> Decision:
        use = state.both_at_intersection & self.no_gap(state) & self.at_braking_point(state)
        return Decision(use, use.astype(np.int8), safe)
