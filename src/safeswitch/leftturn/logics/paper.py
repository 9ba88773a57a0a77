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

In traffic (ours where the paper is silent: it has one other car) the rule is applied to each
vehicle whose route conflicts with the ego's, with that pair's conflict point and zones: the
safety action is executed if it fires for *any* of them. For the other vehicles the conflict
point is the middle of the pair's conflict zone (they may cross or merge; the north car keeps
its centre-line crossing). One kernel serves both scenes: the paper's is the case of one
conflict (:class:`~safeswitch.leftturn.views.ConflictView`).

This rule is a heuristic: a learned controller that passes the braking point while the gap looks
large and then slows down inside the conflict zone is not kept out of it (braking there cannot
stop it before the zone). The ``certified`` logic closes that gap.
"""

from __future__ import annotations

from typing import NamedTuple, TypeVar

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import jit
from safeswitch.core.registry import LogicContextError, context_name
from safeswitch.core.switching import Decision, FloatArray, Guarded
from safeswitch.leftturn.config import PaperSwitchingConfig
from safeswitch.leftturn.views import ConflictView, LogicScene

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
def _decide(v: ConflictView, c: PaperConstants, out: NDArray[np.bool_]) -> None:
    """Algorithm 1 for every episode of a view: the safety action fires if, for some conflict,
    both vehicles are at the intersection, ``TTR_k − TTR_e < threshold`` (no gap to cut in
    front) and ``d_stop ≤ d_safe + v·latency + margin`` (the last moment to stop before the
    pair's zone)."""
    # The view's arrays are taken out of the tuple once: numba would otherwise fetch each
    # array, and count a reference to it, on every access inside the loop (10 times slower).
    ego_progress, ego_speed, present, window = v.ego_progress, v.ego_speed, v.present, v.window
    ego_point, ego_zone = v.ego_point, v.ego_zone
    other_progress, other_point, other_speed = v.other_progress, v.other_point, v.other_speed
    for b in range(out.shape[0]):
        s_e, v_e = ego_progress[b], ego_speed[b]
        fire = False
        for k in range(present.shape[1]):
            if not (present[b, k] and window[b, k]):
                continue
            ttr_e = time_to_reach(max(ego_point[b, k] - s_e, 0.0), v_e, c.min_speed)
            ttr_k = time_to_reach(other_point[b, k] - other_progress[b, k], other_speed[b, k],
                                  c.min_speed)  # fmt: skip
            if ttr_k - ttr_e < c.ttr_threshold_s and (
                ego_zone[b, k, 0] - s_e <= firing_distance(v_e, c)
            ):
                fire = True
                break
        out[b] = fire


class PaperSwitching:
    """Algorithm 1 as its text describes it, against every conflict of the view (see the
    module docstring).

    Args:
        config: Threshold, margins and speed guard.
        emergency_decel: ``a_max_lon`` of Eq. 3 [m/s²] (the deceleration ``PID_b`` tracks).
    """

    reasons: tuple[str, ...] = ("learned", "no_gap_at_braking_point")

    def __init__(self, config: PaperSwitchingConfig, emergency_decel: float) -> None:
        self.config = config
        self.emergency_decel = emergency_decel
        c = config
        #: What :func:`fires` reads.
        self.constants = PaperConstants(
            c.ttr_threshold_s, c.min_speed, emergency_decel, c.latency_s, c.stop_margin_m
        )

    def decide(self, state: ConflictView, learned: FloatArray, safe: FloatArray) -> Decision:
        use = np.empty(learned.shape[0], dtype=np.bool_)
        _decide(state, self.constants, use)
        return Decision(use, use.astype(np.int8), safe)


def paper_logic(scene: LogicScene) -> PaperSwitching:
    """Factory of the ``paper`` logic (registered under that name) for a left-turn scene."""
    if not isinstance(scene, LogicScene):
        raise LogicContextError(
            f"the 'paper' switching logic supervises the left-turn task, not {context_name(scene)}"
        )
    c = scene.config
    return PaperSwitching(c.paper, c.controllers.emergency_decel)


def guarded_logic(scene: LogicScene) -> Guarded:
    """Factory of the ``guarded`` logic (registered under that name; ours): the paper's
    Algorithm 1 in the loop, the ``certified`` filter beneath it judging what it lets through
    (:class:`~safeswitch.core.switching.Guarded`). The certificate's guarantee — no collision
    for any proposed action sequence — covers the pair, so a policy can explore under the
    paper's logic, and be charged ``R_ADAS`` for both, without the paper logic's known gap
    (a car stopped inside the conflict zone) costing a collision."""
    from safeswitch.leftturn.logics.certified import certified_logic

    return Guarded(paper_logic(scene), certified_logic(scene))
