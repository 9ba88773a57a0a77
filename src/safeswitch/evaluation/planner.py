"""The planner: a rule-based, throttle-only controller that plans around the paper switching logic.

A baseline the paper did not have, and the answer to "how fast can a controller with the
learned controller's means go without ever needing the Safety controller?". It drives with the
learned controller's single action (throttle, no brake pedal), sees the same things plus the
plant's model, and replans on every tick:

- **Pass first** if a fast drive from the current state — the speed limit plus the tolerated
  speeding on the straight, the lateral comfort limit (with a margin) in the turn — leaves the
  conflict zone without the paper switching logic ever firing. It checks this by simulating that
  drive on a copy of the plant with the switching logic in the loop (its TTR threshold raised
  by ``ttr_margin_s``) and the north car's own controller, every ``recheck_ticks`` ticks.
- **Otherwise yield**: reach the point where the switching logic would fire (``d_safe`` plus
  latency and margin before the zone) at ``yield_speed``, ``yield_margin_s`` after the north
  car has left its conflict zone (a constant-acceleration profile to that point, never faster
  than a closed throttle can still slow down from). Arriving slower lets the car wait closer
  to the zone, because the firing distance shrinks with ``v²``: from 4 m/s the fast drive
  clears the zone ~0.4 s sooner than from the 6.8 m/s the turn would allow (point-mass
  estimate; over the README's scenarios 0.15 s on average).
- **Once in its conflict zone** (or once the north car has left its own) the car drives fast:
  slowing down there can only make things worse. This never binds for the planner itself, but
  labels the states a cloned policy reaches after a hesitation (``training.warm_start``).

Speed targets are tracked with the steady-state throttle plus a proportional term. The planner
uses the full task state (the north car's position and speed, as the observation does, and the
plant model for its check); it is a reference for what a learned policy could reach under the
paper logic, not a deployable controller.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from safeswitch.evaluation.oracle import Oracle, OracleLimits
from safeswitch.evaluation.planner_config import PlannerConfig
from safeswitch.leftturn.logics.paper import PaperSwitching, firing_distance
from safeswitch.leftturn.spaces import speed_tracking_action, throttle_driver, throttle_scene
from safeswitch.leftturn.task import LeftTurnTask, TaskState

FloatArray = NDArray[np.float64]


class Planner:
    """The planner as a rollout :data:`~safeswitch.evaluation.rollout.Policy` (see the module
    docstring).

    Args:
        task: The task it drives (its road, plant and paper switching parameters are used; the
            check always runs the paper logic, whatever logic ``task`` itself runs).
        config: Its tuning.
    """

    def __init__(self, task: LeftTurnTask, config: PlannerConfig | None = None) -> None:
        self.config = c = config or PlannerConfig()
        tc = task.config
        self._drive = FastDrive(
            task, c.top_speed_kmh, c.accel_lat, c.curve_decel, c.preview_s, c.speed_gain
        )
        geo = task.conflict
        self._zone_entry, self._zone_exit = geo.zone_a[0], geo.zone_a[1]
        self._north_exit = geo.zone_b[1]
        paper = tc.paper
        yield_paper = dataclasses.replace(paper, stop_margin_m=paper.stop_margin_m + c.stop_extra_m)
        self._yield_constants = PaperSwitching(
            yield_paper, tc.controllers.emergency_decel
        ).constants
        self._horizon = tc.episode.horizon_ticks
        check_paper = dataclasses.replace(
            paper, ttr_threshold_s=paper.ttr_threshold_s + c.ttr_margin_s
        )
        self._check_task = LeftTurnTask(
            dataclasses.replace(
                throttle_scene(tc), switching="paper", paper=check_paper, scenario=None
            )
        )
        self._decision: NDArray[np.bool_] | None = None

    def __call__(self, obs: NDArray[np.float32], state: TaskState, tick: int) -> FloatArray:
        """Its actions in [-1, 1] for every episode of ``state`` (throttles, as the scene's
        learned action: :attr:`FastDrive.to_scene`)."""
        speed = state.world.vehicles.speed[:, 0]
        return self._drive.to_scene(self._track(self.target_speed(state, tick), speed))

    def target_speed(self, state: TaskState, tick: int) -> FloatArray:
        """The speed the planner steers for [m/s] ``[B]``."""
        w = state.world
        s, s_n = w.progress[:, 0], w.progress[:, 1]
        v, v_n = w.vehicles.speed[:, 0], w.vehicles.speed[:, 1]
        fast = self._fast(s, v)
        if (
            self._decision is None
            or self._decision.shape != s.shape
            or tick % self.config.recheck_ticks == 0
        ):
            self._decision = self.passes_first(state)
        # Once in its conflict zone the ego can only make things worse by slowing down.
        go = self._decision | (s_n > self._north_exit) | (s > self._zone_entry)
        return np.where(go, fast, self._yield(s, v_n, s_n, fast))

    def passes_first(self, state: TaskState) -> NDArray[np.bool_]:
        """Whether the fast drive from ``state`` leaves the ego's conflict zone with no
        collision and without the (margin-raised) paper switching logic ever firing.

        Only episodes whose decision matters are simulated (the ego not yet in its zone, the
        north car not yet out of its own; the others drive fast anyway and get True), and the
        batch shrinks as their drives leave the zone."""
        s, s_n = state.world.progress[:, 0], state.world.progress[:, 1]
        rows = np.flatnonzero((s <= self._zone_entry) & (s_n <= self._north_exit))
        return drive_passes(
            self._check_task, state, rows, self._zone_exit, self._horizon, self._drive.action
        )

    def _fast(self, s: FloatArray, v: FloatArray) -> FloatArray:
        return self._drive.speed(s, v)

    def _firing_distance(self, v: FloatArray) -> FloatArray:
        """How far before the zone the paper logic fires at speed ``v`` (Eq. 3 + latency +
        margin, plus ``stop_extra_m``)."""
        return firing_distance(v, self._yield_constants)

    def _yield(
        self, s: FloatArray, v_n: FloatArray, s_n: FloatArray, fast: FloatArray
    ) -> FloatArray:
        c = self.config
        left = np.maximum(self._north_exit - s_n, 0.0) / np.maximum(v_n, 0.1) + c.yield_margin_s
        arrive = np.minimum(c.yield_speed, fast)
        distance = self._zone_entry - s - self._firing_distance(arrive)
        # the constant acceleration that covers `distance` in `left` and ends at `arrive`
        start = 2.0 * distance / left - arrive
        coast = np.sqrt(arrive * arrive + 2.0 * c.coast_decel * np.maximum(distance, 0.0))
        target = np.minimum(np.maximum(start, c.creep * distance / left), coast)
        return np.clip(target, 0.0, fast)

    def _track(self, target: FloatArray, speed: FloatArray) -> FloatArray:
        return self._drive.track(target, speed)


class FastDrive:
    """The planners' fast drive: the speed limit plus the tolerated speeding on the straight,
    the lateral limit in the turn, slowing for it at ``curve_decel`` (the oracle's braking
    profile with these limits, read ``preview_s`` ahead), tracked with the learned
    controller's throttle.

    Args:
        task: The task (its route, plant and limits).
        top_speed_kmh: Speed on the straight [km/h].
        accel_lat: Lateral acceleration the turn is planned for [m/s²].
        curve_decel: Deceleration the speed target assumes when slowing for the turn [m/s²].
        preview_s: The speed target is read this far ahead along the route [s].
        speed_gain: Throttle per m/s of speed error.
    """

    def __init__(
        self, task: LeftTurnTask, top_speed_kmh: float, accel_lat: float, curve_decel: float,
        preview_s: float, speed_gain: float,
    ) -> None:  # fmt: skip
        #: Its throttle actions as the scene's learned action (the planners work in throttles
        #: and check their drives on :func:`throttle_scene`'s copy of the scene).
        self.to_scene = throttle_driver(task.config.controllers, "the planner's drive")
        limits = dataclasses.replace(
            OracleLimits.from_config(task.config),
            max_speed=top_speed_kmh / 3.6,
            accel_lat=accel_lat,
            max_decel=curve_decel,
        )
        oracle = Oracle(task, limits)
        self._grid, self._cap_sq = oracle.grid, oracle.brake_profile_sq
        self._vehicle = task.config.vehicle
        self._preview, self._gain = preview_s, speed_gain

    def speed(self, s: FloatArray, v: FloatArray) -> FloatArray:
        """The fast drive's speed target at arc length ``s`` and speed ``v`` [m/s]."""
        ahead = s + v * self._preview
        return np.sqrt(np.maximum(np.interp(ahead, self._grid, self._cap_sq), 0.0))

    def track(self, target: FloatArray, speed: FloatArray) -> FloatArray:
        """The throttle action that tracks ``target``."""
        return speed_tracking_action(self._vehicle, target, speed, self._gain)

    def action(self, state: TaskState, tick: int) -> FloatArray:
        """The fast drive's action in ``state`` (``tick`` unused: a rollout policy's shape)."""
        s, v = state.world.progress[:, 0], state.world.vehicles.speed[:, 0]
        return self.track(self.speed(s, v), v)


def drive_passes(
    task: LeftTurnTask, state: TaskState, rows: NDArray[np.int64], exit_at: float,
    horizon: int, act: Callable[[TaskState, int], FloatArray],
) -> NDArray[np.bool_]:  # fmt: skip
    """The planners' check: whether driving ``act`` on ``task`` from the episodes ``rows`` of
    ``state`` takes the ego past ``exit_at`` [m] with no collision and no safety action on the
    way (the other episodes, and those still short of it after ``horizon`` ticks, get True).
    The simulated batch shrinks as drives fail or get past (every tenth tick)."""
    ok = np.ones(state.batch_size, dtype=bool)
    state = state.take(rows)
    for tick in range(horizon):
        if rows.size == 0:
            break
        inside = state.world.progress[:, 0] <= exit_at
        state, record = task.step(state, act(state, tick), observe=False)
        ok[rows[inside & (record.safety_active | record.collision)]] = False
        going = ok[rows] & (state.world.progress[:, 0] <= exit_at)
        if not going.all() and (tick % 10 == 9 or not going.any()):
            keep = np.flatnonzero(going)
            rows, state = rows[keep], state.take(keep)
    return ok
