"""The gap planner: a rule-based, throttle-only controller for the left turn in traffic that
plans around the certified switching logic.

The traffic counterpart of :mod:`~safeswitch.evaluation.planner` (which sees only the north
car) and the teacher of a warm start in traffic. It drives with the learned controller's single
action (throttle, no brake pedal), uses the full task state and the plant's model, and replans
every ``recheck_ticks`` ticks:

- **Go** if the fast drive from the current state — the speed limit plus the tolerated speeding
  on the straight, the lateral comfort limit in the turn — gets the ego past every conflict zone
  without the certified filter ever acting and without a collision. It checks this by
  simulating that very drive on a copy of the task under ``certified``, every other vehicle
  driving as it would (their reactions to the ego included). A gap the filter accepts is one
  that is safe against the worst case of every vehicle the filter allows for, so the check is
  the filter's own gap acceptance, not a guess about the drivers.
- **Otherwise wait**: roll towards the first conflict zone of any crossing movement and stop
  ``stop_extra_m`` before it, never faster than a closed throttle (``coast_decel``) can still
  stop from and with the throttle closed for the last ``coast_band_m``, so that the filter's
  stop backup stays available and never has to act. With ``approach: brake`` (a scene with a
  learned brake) the wait brakes instead, at ``coast_decel``, to its stop and holds it there.
- **Once in a conflict zone** the car drives fast: slowing down there can only make things
  worse (for a cloned policy that hesitated: labels of states the planner itself never
  reaches).

It is a reference and a teacher, not a deployable controller: it sees the future of the other
vehicles through the simulation. Its actions are throttles, the brake released, except where a
braked approach brakes. The certified filter still runs around it, so it is collision-free by
the filter's guarantee whatever it does; what it adds is that the filter (nearly) never needs
to act.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from safeswitch.evaluation.planner import FastDrive, drive_passes
from safeswitch.evaluation.planner_config import GapPlannerConfig
from safeswitch.leftturn.spaces import throttle_scene
from safeswitch.leftturn.task import LeftTurnTask, TaskState
from safeswitch.leftturn.traffic import LeftTurnTrafficTask, TrafficTaskState

FloatArray = NDArray[np.float64]

#: A braked approach's brake per m/s above its target speed [m/s² per m/s], on top of the
#: approach's deceleration (the action may be held for several ticks).
APPROACH_BRAKE_GAIN = 1.0

#: Below this target speed [m/s] a braked approach is at its stop, and holds the car there
#: with at least ``STOP_BRAKE`` of the pedal.
STOP_SPEED = 0.05
STOP_BRAKE = 0.2


class GapPlanner:
    """The gap planner as a rollout :data:`~safeswitch.evaluation.rollout.Policy` (see the
    module docstring).

    Args:
        task: A task in traffic (:class:`~safeswitch.leftturn.traffic.LeftTurnTrafficTask`);
            its road, plant and traffic are used, and the check always runs the certified
            logic, whatever logic ``task`` itself runs.
        config: Its tuning.
    """

    def __init__(self, task: LeftTurnTask, config: GapPlannerConfig | None = None) -> None:
        if not isinstance(task, LeftTurnTrafficTask):
            raise ValueError(
                f"the gap planner needs a task in traffic (evaluate --traffic PRESET), got "
                f"{type(task).__name__}; the single-car scene has the planner"
            )
        self.config = c = config or GapPlannerConfig()
        tc = task.config
        c.check_scene(tc.controllers.learned_brake)
        #: The deceleration of a full brake on a level road [m/s²] (a braked approach's scale).
        self._full_brake = tc.vehicle.max_brake_force / tc.vehicle.mass
        self._drive = FastDrive(
            task, c.top_speed_kmh, c.accel_lat, c.curve_decel, c.preview_s, c.speed_gain
        )
        zones = task.phantoms().ego_zone
        #: Where the first crossing movement's zone begins and the last one ends on the ego's
        #: route [m].
        self.first_entry = float(zones[:, 0].min())
        self.last_exit = float(zones[:, 1].max())
        self._horizon = tc.episode.horizon_ticks
        self._dt = tc.episode.dt
        self._check_task = LeftTurnTrafficTask(
            dataclasses.replace(throttle_scene(tc), switching="certified"), task.traffic
        )
        self._decision: NDArray[np.bool_] | None = None

    def __call__(self, obs: NDArray[np.float32], state: TaskState, tick: int) -> FloatArray:
        """Its actions in [-1, 1] for every episode of ``state``: throttles, as the scene's
        learned action (:attr:`~safeswitch.evaluation.planner.FastDrive.to_scene`), and with
        ``approach: brake`` the scene's brake (``-brake``) where its wait brakes."""
        speed = state.world.vehicles.speed[:, 0]
        target, closed, waiting = self.plan(state, tick)
        actions = self._drive.to_scene(np.where(closed, -1.0, self._drive.track(target, speed)))
        if self.config.approach == "coast":
            return actions
        stopped = target <= STOP_SPEED
        demand = self.config.coast_decel + APPROACH_BRAKE_GAIN * (speed - target)
        brake = np.clip(demand / self._full_brake, np.where(stopped, STOP_BRAKE, 0.0), 1.0)
        return np.where(waiting & ((speed > target) | stopped), -brake, actions)

    def plan(
        self, state: TaskState, tick: int
    ) -> tuple[FloatArray, NDArray[np.bool_], NDArray[np.bool_]]:
        """The speed the planner steers for [m/s], where it closes the throttle instead
        (waiting within ``coast_band_m`` of its stop, or at it; a braked approach only at it)
        and where it waits, each ``[B]``."""
        c = self.config
        s, v = state.world.progress[:, 0], state.world.vehicles.speed[:, 0]
        fast = self._drive.speed(s, v)
        if self._decision is None or self._decision.shape != s.shape or tick % c.recheck_ticks == 0:
            self._decision = self.goes(state, self._decision if tick > 0 else None)
        waiting = ~(self._decision | (s > self.first_entry))
        room = np.maximum(self.first_entry - c.stop_extra_m - s, 0.0)
        wait = np.minimum(fast, np.sqrt(2.0 * c.coast_decel * room))
        # the throttle that holds a low speed would creep on: closed near and at the stop
        band = c.coast_band_m if c.approach == "coast" else 0.0
        closed = waiting & ((room < band) | (wait <= 0.0))
        return np.where(waiting, wait, fast), closed, waiting

    def goes(self, state: TaskState, going: NDArray[np.bool_] | None = None) -> NDArray[np.bool_]:
        """Whether the fast drive from ``state`` gets past the last conflict zone with no
        collision and without the certified filter acting. With ``go_margin_s`` an episode
        not already ``going`` starts only if the drive would also pass when begun that much
        later (the throttle closed until then); one that is going keeps going while the
        drive from where it is passes."""
        ok = self.passes(state, 0)
        margin = round(self.config.go_margin_s / self._dt)
        if margin > 0:
            starting = ok & (state.world.progress[:, 0] <= self.first_entry)
            if going is not None and going.shape == ok.shape:
                starting &= ~going
            rows = np.flatnonzero(starting)
            ok[rows] &= self.passes(state.take(rows), margin)
        return ok

    def passes(self, state: TaskState, delay: int = 0) -> NDArray[np.bool_]:
        """Whether the fast drive from ``state``, begun after ``delay`` ticks of a closed
        throttle, gets past the last conflict zone with no collision and without the filter
        acting — :meth:`goes` without its margin, and what a learned go predictor learns
        (``experiments/go_predictor.py``). Only episodes before their first zone are
        simulated; the others are true."""

        def act(now: TaskState, tick: int) -> FloatArray:
            closed = np.full(now.batch_size, -1.0)
            return self._drive.action(now, tick) if tick >= delay else closed

        rows = np.flatnonzero(state.world.progress[:, 0] <= self.first_entry)
        if self.config.foresight == "observed":
            state = _as_observed(state.take(np.arange(state.batch_size)))
        return drive_passes(self._check_task, state, rows, self.last_exit, self._horizon, act)


def _as_observed(state: TaskState) -> TaskState:
    """``state`` (a copy, changed in place) as an onboard controller knows it: no vehicle still
    to come, and every driver on the approaches one who never yields."""
    if not isinstance(state, TrafficTaskState):
        raise TypeError("the gap planner checks states in traffic")
    traffic = state.traffic
    traffic.yields[:] = False
    traffic.schedule.time[:] = np.inf
    traffic.next_arrival[:] = np.inf
    return state


class UnboundGapPlanner:
    """The gap planner before its task is known (``safeswitch evaluate --controller
    gap_planner``: the task in traffic is built after the controller is chosen);
    :meth:`bind` makes the planner."""

    def __init__(self, config: GapPlannerConfig | None = None) -> None:
        self.config = config

    def bind(self, task: LeftTurnTask) -> GapPlanner:
        """The gap planner of ``task``."""
        return GapPlanner(task, self.config)

    def __call__(self, obs: NDArray[np.float32], state: TaskState, tick: int) -> FloatArray:
        raise RuntimeError("the gap planner drives only once bound to its task (bind(task))")
