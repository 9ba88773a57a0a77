"""The oracle: the minimum-time crossing, planned with full knowledge of the north car's future.

The efficiency limit against which every controller is measured. The north car does not react
to the ego, so its whole trajectory is known in advance (it is simulated first, on the plant).
The ego is a point mass on its route, ``s'' = a``, with

- speed ``0 <= v <= v_max``: the speed limit plus the tolerated speeding (the highest speed at
  which ``R_v`` is still at its best, 30 km/h by default);
- ``-d <= a <= a_max(v)``: the comfort limit ``|a_lon| <= 5 m/s²``, and no more drive than the
  plant's engine gives at full throttle (power and traction limits) nor more braking than its
  brakes give;
- ``v² |κ(s)| <= 3 m/s²``: the lateral comfort limit on the route's curvature;
- the ego is never in its conflict zone on a tick on which the north car is in its own.

It has no actuator lags, so no controller driving the plant within the same limits can clear the
conflict zone sooner (the tests check this against every controller we have).

The plan is exact for this model: the time-optimal way through the curve from any state is the
classic forward–backward speed profile (accelerate as hard as the limits allow while a
full-comfort braking can still respect every curvature limit ahead). Passing first is possible
iff that profile leaves the zone before the north car enters it. Otherwise the ego must enter
after the north car has left, and the fastest way to do so is bang-bang: brake at ``d`` for a
time ``θ`` (waiting at rest if it stops), then accelerate as above. The smallest ``θ`` that keeps
the ego out of the zone until the north car is gone is found by bisection (the entry tick grows
monotonically with ``θ``). All of it runs batched over scenarios, on the simulator's own ticks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import jit
from safeswitch.evaluation.rollout import RolloutResult
from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.rewards import REWARD_TERMS, reward_terms
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.statistics import SPEEDING_MARGIN
from safeswitch.leftturn.task import ConflictArrays, LeftTurnTask
from safeswitch.sim.collision import rectangle_separation
from safeswitch.sim.geometry import FloatArray
from safeswitch.sim.vehicle import (
    VehicleConstants,
    available_drive_force,
    drive_force,
    driving_resistance,
    resistance,
    vehicle_constants,
)

#: Bisection steps on the braking time θ (resolution horizon / 2**steps, well below a tick).
_BISECTION_STEPS = 16


@dataclass(frozen=True)
class OracleLimits:
    """The limits the oracle plans within.

    Attributes:
        max_speed: ``v_max`` [m/s] (speed limit plus tolerated speeding).
        accel_lon: Longitudinal comfort limit [m/s²].
        accel_lat: Lateral comfort limit [m/s²].
        max_decel: Braking used, ``min(accel_lon, brakes)`` [m/s²].
    """

    max_speed: float
    accel_lon: float
    accel_lat: float
    max_decel: float

    @classmethod
    def from_config(cls, config: LeftTurnConfig) -> OracleLimits:
        """The limits of a task configuration: comfort limits of the reward, ``v_max`` the
        highest speed at which ``R_v`` is at its best."""
        r = config.rewards
        return cls(
            max_speed=r.tolerated_speed,
            accel_lon=r.comfort_accel_lon,
            accel_lat=r.comfort_accel_lat,
            max_decel=min(r.comfort_accel_lon, config.vehicle.max_brake_deceleration),
        )


@dataclass
class OraclePlan:
    """The oracle's crossing of ``B`` scenarios, sampled on the simulator's ticks.

    Attributes:
        progress: Ego arc length along its route [m], ``[B, H + 1]`` (tick 0 is the start).
        speed: Ego speed [m/s], ``[B, H + 1]``.
        accel_lon: Ego acceleration over each tick [m/s²], ``[B, H]``.
        accel_lat: Ego lateral acceleration ``v² κ`` after each tick [m/s²], ``[B, H]``.
        north_progress: North car's arc length [m], ``[B, H + 1]``.
        separation: Gap between the two footprints after each tick [m], ``[B, H]``.
        time_to_clear: Time until the ego left its conflict zone [s] (NaN: not within the
            horizon), ``[B]``.
        outcome: 1 the ego crosses first, 2 after the north car, 0 neither within the horizon.
        brake_time: The bang-bang braking time θ [s] (0 when passing first), ``[B]``.
    """

    progress: FloatArray
    speed: FloatArray
    accel_lon: FloatArray
    accel_lat: FloatArray
    north_progress: FloatArray
    separation: FloatArray
    time_to_clear: FloatArray
    outcome: NDArray[np.int8]
    brake_time: FloatArray


class Oracle:
    """Minimum-time crossings of the left-turn task (see the module docstring).

    Args:
        task: The task; its route, conflict zones, plant, tick and horizon are used. A task on
            another simulator that has an embedded twin (``task.embedded``: SUMO in traffic)
            is planned on the twin — batched, and without restarting the other simulator.
        limits: The limits to plan within (default: :meth:`OracleLimits.from_config`).
    """

    def __init__(self, task: LeftTurnTask, limits: OracleLimits | None = None) -> None:
        task = task.embedded
        self.task = task
        self.limits = limits or OracleLimits.from_config(task.config)
        route = task.world.routes[0]
        self._grid = route.arc_length
        self._curvature = np.abs(route.curvature)
        lim = self.limits
        # V(s)² on the route's grid: the speed cap and the lateral limit, each node taking the
        # sharpest curvature of its two segments, so that v² ≤ V(s)² (interpolated) implies
        # v² κ(s) ≤ a_lat for the linearly interpolated curvature everywhere.
        k = self._curvature
        sharpest = np.maximum(k, np.maximum(np.r_[k[1:], k[-1]], np.r_[k[0], k[:-1]]))
        with np.errstate(divide="ignore"):
            v_curve_sq = np.where(sharpest > 0, lim.accel_lat / sharpest, np.inf)
        self._v_sq = np.minimum(lim.max_speed**2, v_curve_sq)
        # Backward pass: the highest speed² from which braking at d respects V everywhere ahead.
        w_sq = self._v_sq.copy()
        step = 2.0 * lim.max_decel * np.diff(self._grid)
        for i in range(len(w_sq) - 2, -1, -1):
            w_sq[i] = min(w_sq[i], w_sq[i + 1] + step[i])
        self._w_sq = w_sq
        #: The plant's force model (the oracle's engine and resistance).
        self._plant = vehicle_constants(task.config.vehicle, task.config.episode.dt)

    @property
    def grid(self) -> FloatArray:
        """Arc lengths of the ego route's waypoints [m]."""
        return self._grid

    @property
    def brake_profile_sq(self) -> FloatArray:
        """``W(s)²`` on :attr:`grid`: the highest squared speed from which braking at the
        limits' deceleration respects every speed cap ahead [m²/s²]."""
        return self._w_sq

    def speed_cap_sq(self, s: FloatArray) -> FloatArray:
        """``V(s)²``: the squared speed limit at arc lengths ``s`` (linear between waypoints)."""
        return np.interp(s, self._grid, self._v_sq)

    def max_accel(self, speed: FloatArray) -> FloatArray:
        """``a_max(v)``: the engine's full-throttle acceleration net of driving resistance,
        capped at the longitudinal comfort limit [m/s²]."""
        p = self.task.config.vehicle
        engine = (available_drive_force(p, speed) - driving_resistance(p, speed)) / p.mass
        return np.minimum(engine, self.limits.accel_lon)

    def north_trajectory(self, scenarios: Scenarios) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The north car's arc length and speed on every tick, each ``[B, H + 1]`` (simulated
        on the plant; the ego's actions cannot change them), and the ego's start ``(s0, v0)``
        as ``[B, 2]``."""
        others = self.task.without_ego(scenarios)
        return others.north, others.north_speed, others.start

    def _fastest(self, s: FloatArray, v: FloatArray) -> FloatArray:
        """The fastest allowed acceleration: as hard as the engine and comfort allow, lowered
        until the next speed is within W at the next position (a fixed point, reached in a step
        or two), never below ``-d``."""
        dt = self.task.config.episode.dt
        a = self.max_accel(v)
        for _ in range(3):
            s_next = s + v * dt + 0.5 * a * dt * dt
            w = np.sqrt(np.maximum(np.interp(s_next, self._grid, self._w_sq), 0.0))
            a = np.minimum(a, (w - v) / dt)
        return np.maximum(a, -self.limits.max_decel)

    def integrate(
        self,
        start: FloatArray,
        control: Callable[[int, FloatArray, FloatArray], FloatArray],
        ticks: int | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """Point-mass motion ``[B, T + 1]`` (progress, speed) from ``start`` ``[B, 2]`` under
        ``control(tick, s, v) -> a``, integrated exactly over each tick; ``a`` is clipped to
        ``[-d, a_max(v)]`` and the car stops rather than reverses. ``T``: ``ticks``, by default
        the horizon."""
        dt = self.task.config.episode.dt
        d = self.limits.max_decel
        s, v = start[:, 0].copy(), start[:, 1].copy()
        s_out, v_out = [s.copy()], [v.copy()]
        for k in range(self.task.config.episode.horizon_ticks if ticks is None else ticks):
            a = np.clip(control(k, s, v), -d, self.max_accel(v))
            stops = v + a * dt < 0.0  # braking to rest within the tick
            with np.errstate(divide="ignore", invalid="ignore"):
                s = np.where(stops, s + v * v / (2.0 * d), s + v * dt + 0.5 * a * dt * dt)
            v = np.where(stops, 0.0, v + a * dt)
            s_out.append(s.copy())
            v_out.append(v.copy())
        return np.stack(s_out, axis=1), np.stack(v_out, axis=1)

    def _drive(
        self, start: FloatArray, brake_time: FloatArray, ticks: int | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """Brake at ``d`` for ``brake_time``, then as fast as the limits allow."""
        dt = self.task.config.episode.dt
        d = self.limits.max_decel

        def law(k: int, s: FloatArray, v: FloatArray) -> FloatArray:
            return np.where(k * dt < brake_time - 1e-9, -d, self._fastest(s, v))

        return self.integrate(start, law, ticks)

    @property
    def kernel_constants(self) -> OracleConstants:
        """What the compiled planner reads."""
        geo, config, lim = self.task.conflict, self.task.config, self.limits
        return OracleConstants(
            dt=config.episode.dt,
            max_decel=lim.max_decel,
            accel_lon=lim.accel_lon,
            mass=config.vehicle.mass,
            zone_entry=geo.zone_a[0],
            zone_exit=geo.zone_a[1],
            horizon=config.episode.horizon_ticks,
        )

    def plan(
        self, scenarios: Scenarios, north: FloatArray | None = None, full: bool = True
    ) -> OraclePlan:
        """The minimum-time crossing of each scenario. ``north``: the north car's arc length on
        every tick ``[B, H + 1]``, if already simulated (it never reacts to the ego, so any
        rollout of the same scenarios has it); simulated here otherwise. ``full=False`` skips
        the per-tick arrays (progress, speed, accelerations, separation come back empty
        ``[B, 0]``): what an evaluation needs is the time to clear and the outcome."""
        task = self.task
        geo = task.conflict
        horizon = task.config.episode.horizon_ticks
        crossing = task.crossing_zones()  # in traffic: every movement that crosses the ego's
        occupied = None
        if north is None or len(crossing):
            others = task.without_ego(scenarios)
            north, start, occupied = others.north, others.start, others.occupied
        else:
            state = task.initial(scenarios)
            start = np.stack([state.world.progress[:, 0], state.world.vehicles.speed[:, 0]], 1)
        batch = north.shape[0]
        north_in = (north >= geo.zone_b[0]) & (north <= geo.zone_b[1])
        c, k = self.kernel_constants, self._plant
        brake_time = np.empty(batch)
        if len(crossing):
            assert occupied is not None
            # The north car's zone and every crossing movement's: the smallest θ that keeps
            # the ego out of each while it is occupied (grid, then bisection).
            zones = np.concatenate([np.asarray([geo.zone_a], dtype=np.float64), crossing])
            _plan_brake_times_many(
                np.ascontiguousarray(start), np.concatenate([north_in[:, None], occupied], 1),
                zones, c, k, self._grid, self._w_sq, brake_time,
            )  # fmt: skip
        else:
            # Last tick the north car is in its zone (-1: never; horizon + 1: still in at the
            # end). Pass first if the free drive never shares the zone with the north car; else
            # yield: bisection on θ for the first entry after the north car's last tick in its
            # zone (compiled, scenario by scenario; the same arithmetic as :meth:`integrate`).
            north_last = np.max(np.where(north_in, np.arange(horizon + 1), -1), axis=1)
            north_last = np.where(north_in[:, -1], horizon + 1, north_last)
            _plan_brake_times(
                np.ascontiguousarray(start), north_in, north_last.astype(np.int64), c, k,
                self._grid, self._w_sq, brake_time,
            )  # fmt: skip
        if not full:
            ego_clears = np.empty(batch)
            _clear_ticks(start, brake_time, c, k, self._grid, self._w_sq, ego_clears)
            return self._finish(north, None, None, ego_clears, brake_time)
        progress, speed = np.empty((batch, horizon + 1)), np.empty((batch, horizon + 1))
        _drive_batch(start, brake_time, horizon, c, k, self._grid, self._w_sq, progress, speed)
        return self._finish(
            north, progress, speed, _first_tick(progress > geo.zone_a[1], np.inf), brake_time
        )

    def _finish(
        self,
        north: FloatArray,
        progress: FloatArray | None,
        speed: FloatArray | None,
        ego_clears: FloatArray,
        brake_time: FloatArray,
    ) -> OraclePlan:
        """The plan from the ego's drive (``None``: not kept) and its first tick past the zone
        (``inf``: not within the horizon)."""
        geo = self.task.conflict
        dt = self.task.config.episode.dt
        batch = north.shape[0]
        # Who cleared first, coded as the task's outcome (0: the ego not within the horizon).
        north_clears = _first_tick(north > geo.zone_b[1], np.inf)
        outcome = np.where(
            np.isinf(ego_clears), 0, np.where(ego_clears < north_clears, 1, 2)
        ).astype(np.int8)
        time_to_clear = np.where(np.isinf(ego_clears), np.nan, ego_clears * dt)
        if progress is None or speed is None:
            empty = np.empty((batch, 0))
            return OraclePlan(
                empty, empty, empty, empty, north, empty, time_to_clear, outcome, brake_time
            )
        accel_lon = np.diff(speed, axis=1) / dt
        curvature = np.interp(progress[:, 1:], self._grid, self._curvature)
        accel_lat = speed[:, 1:] ** 2 * curvature
        return OraclePlan(
            progress=progress,
            speed=speed,
            accel_lon=accel_lon,
            accel_lat=accel_lat,
            north_progress=north,
            separation=self._separation(progress[:, 1:], north[:, 1:]),
            time_to_clear=time_to_clear,
            outcome=outcome,
            brake_time=brake_time,
        )

    def _separation(self, ego: FloatArray, north: FloatArray) -> FloatArray:
        """Footprint gap of the two cars placed on their centre lines [m]."""
        routes, vehicle = self.task.world.routes, self.task.config.vehicle
        xy_e, yaw_e = routes[0].pose_at(ego)
        xy_n, yaw_n = routes[1].pose_at(north)
        size = (vehicle.length, vehicle.width)
        return rectangle_separation(xy_e, yaw_e, *size, xy_n, yaw_n, *size)

    def as_rollout(self, plan: OraclePlan) -> RolloutResult:
        """The plan in the form of a rollout's per-episode results (for the same metrics and
        CSV as every controller). Its episodes run the whole horizon; the return is Eq. 5
        along the plan, on the centre line, without safety actions."""
        config = self.task.config
        comfort = (np.abs(plan.accel_lon) > config.rewards.comfort_accel_lon + 1e-9) | (
            np.abs(plan.accel_lat) > config.rewards.comfort_accel_lat + 1e-9
        )
        terms = reward_terms(
            config.rewards,
            speed=plan.speed[:, 1:],
            lateral=np.zeros_like(plan.accel_lon),
            accel_lon=plan.accel_lon,
            accel_lat=plan.accel_lat,
            safety_active=np.zeros(plan.accel_lon.shape, dtype=bool),
            adas_enabled=config.adas_penalty,
        )
        totals = {name: terms[name].sum(axis=1) for name in REWARD_TERMS}
        batch, horizon = plan.accel_lon.shape
        min_ttc, min_pet = self.surrogate(plan)
        return RolloutResult(
            collision=np.any(plan.separation <= 0.0, axis=1),
            lost_control=np.zeros(batch, dtype=np.bool_),  # a point mass within the limits
            safety_steps=np.zeros(batch, dtype=np.int64),
            invalid_steps=np.zeros(batch, dtype=np.int64),
            min_speed=plan.speed.min(axis=1),
            max_speed=plan.speed.max(axis=1),
            speeding_steps=(plan.speed[:, 1:] > self.limits.max_speed + SPEEDING_MARGIN).sum(1),
            time_to_clear=plan.time_to_clear,
            outcome=plan.outcome,
            comfort_violation_steps=comfort.sum(axis=1).astype(np.int64),
            ticks=np.full(batch, horizon, dtype=np.int64),
            episode_return=np.sum(list(totals.values()), axis=0),
            min_separation=plan.separation.min(axis=1),
            max_accel_lon=np.abs(plan.accel_lon).max(axis=1),
            max_accel_lat=np.abs(plan.accel_lat).max(axis=1),
            max_lateral=np.zeros(batch),
            terms=totals,
            min_ttc=min_ttc,
            min_pet=min_pet,
        )

    def surrogate(self, plan: OraclePlan) -> tuple[FloatArray, FloatArray]:
        """The plan's smallest TTC and PET per scenario with the north car
        (:mod:`~safeswitch.evaluation.surrogate`; its speed from its arc lengths); NaN in
        traffic, where the plan does not keep the other vehicles' trajectories."""
        from safeswitch.evaluation.surrogate import SurrogateTracker

        geo, dt = self.task.conflict, self.task.config.episode.dt
        batch, ticks = plan.progress.shape[0], plan.progress.shape[1] - 1
        if len(self.task.crossing_zones()):
            return np.full(batch, np.nan), np.full(batch, np.nan)
        north_speed = np.diff(plan.north_progress, axis=1, prepend=plan.north_progress[:, :1]) / dt
        present = np.ones((batch, 1), dtype=np.bool_)
        ego_zone = np.broadcast_to(np.asarray(geo.zone_a, dtype=np.float64), (batch, 1, 2))
        other_zone = np.broadcast_to(np.asarray(geo.zone_b, dtype=np.float64), (batch, 1, 2))

        def at(t: int) -> ConflictArrays:
            return ConflictArrays(
                plan.progress[:, t], plan.speed[:, t], present, ego_zone,
                plan.north_progress[:, t : t + 1], north_speed[:, t : t + 1], other_zone,
            )  # fmt: skip

        tracker = SurrogateTracker(at(0), dt)
        live = np.ones(batch, dtype=np.bool_)
        for t in range(ticks):
            tracker.update(at(t + 1), live, t)
        return tracker.min_ttc, tracker.min_pet


def _first_tick(mask: NDArray[np.bool_], never: float) -> FloatArray:
    """Index of each row's first true tick of ``mask`` ``[B, T]``, ``never`` if none."""
    return np.where(mask.any(axis=1), np.argmax(mask, axis=1), never)


def efficiency(oracle_time: FloatArray, time: FloatArray, horizon_s: float) -> FloatArray:
    """Per-scenario ``oracle time / controller time`` (1: as fast as the limit). A controller
    that never cleared the zone counts with the whole horizon (an upper bound on its
    efficiency); scenarios the oracle cannot clear within the horizon give NaN."""
    t = np.where(np.isfinite(time), time, horizon_s)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(oracle_time, dtype=np.float64) / np.maximum(t, 1e-9)


class OracleConstants(NamedTuple):
    """The scalars the compiled planner reads.

    Attributes:
        dt: Tick [s].
        max_decel: Braking ``d`` [m/s²].
        accel_lon: Longitudinal comfort limit [m/s²].
        mass: Ego mass [kg].
        zone_entry: Entry of the ego's conflict zone [m].
        zone_exit: Exit of the ego's conflict zone [m].
        horizon: Episode length [ticks].
    """

    dt: float
    max_decel: float
    accel_lon: float
    mass: float
    zone_entry: float
    zone_exit: float
    horizon: int


@jit
def _interp(x: float, points: FloatArray, values: FloatArray) -> float:
    """``np.interp`` for one value on a sorted grid, with its arithmetic (binary search)."""
    last = points.shape[0] - 1
    if x <= points[0]:
        return values[0]
    if x >= points[last]:
        return values[last]
    j = np.searchsorted(points, x, side="right") - 1
    slope = (values[j + 1] - values[j]) / (points[j + 1] - points[j])
    return slope * (x - points[j]) + values[j]


@jit
def _max_accel(v: float, c: OracleConstants, k: VehicleConstants) -> float:
    """:meth:`Oracle.max_accel` for one speed."""
    return min((drive_force(v, k) - resistance(v, k)) / c.mass, c.accel_lon)


@jit
def _fastest_one(
    s: float, v: float, c: OracleConstants, k: VehicleConstants, grid: FloatArray,
    w_sq: FloatArray,
) -> float:  # fmt: skip
    """:meth:`Oracle._fastest` for one state."""
    dt = c.dt
    a = _max_accel(v, c, k)
    for _ in range(3):
        s_next = s + v * dt + 0.5 * a * dt * dt
        w = math.sqrt(max(_interp(s_next, grid, w_sq), 0.0))
        a = min(a, (w - v) / dt)
    return max(a, -c.max_decel)


@jit
def _drive_one(
    s: float, v: float, brake_time: float, ticks: int, c: OracleConstants, k: VehicleConstants,
    grid: FloatArray, w_sq: FloatArray, s_out: FloatArray, v_out: FloatArray,
) -> None:  # fmt: skip
    """:meth:`Oracle._drive` for one scenario: ``ticks + 1`` states into ``s_out``, ``v_out``."""
    s_out[0], v_out[0] = s, v
    for tick in range(ticks):
        s, v = _advance(s, v, tick, brake_time, c, k, grid, w_sq)
        s_out[tick + 1], v_out[tick + 1] = s, v


@jit
def _advance(
    s: float, v: float, tick: int, brake_time: float, c: OracleConstants, k: VehicleConstants,
    grid: FloatArray, w_sq: FloatArray,
) -> tuple[float, float]:  # fmt: skip
    """One tick of :meth:`Oracle._drive`: the state after tick ``tick``."""
    dt, d = c.dt, c.max_decel
    law = -d if tick * dt < brake_time - 1e-9 else _fastest_one(s, v, c, k, grid, w_sq)
    a = min(max(law, -d), _max_accel(v, c, k))
    if v + a * dt < 0.0:  # braking to rest within the tick
        return s + v * v / (2.0 * d), 0.0
    return s + v * dt + 0.5 * a * dt * dt, v + a * dt


@jit
def _drive_batch(
    start: FloatArray, brake_time: FloatArray, ticks: int, c: OracleConstants,
    k: VehicleConstants, grid: FloatArray, w_sq: FloatArray, s_out: FloatArray,
    v_out: FloatArray,
) -> None:  # fmt: skip
    for b in range(start.shape[0]):
        _drive_one(
            start[b, 0], start[b, 1], brake_time[b], ticks, c, k, grid, w_sq, s_out[b], v_out[b]
        )


@jit
def _plan_brake_times(
    start: FloatArray, north_in: NDArray[np.bool_], north_last: NDArray[np.int64],
    c: OracleConstants, k: VehicleConstants, grid: FloatArray, w_sq: FloatArray,
    out: FloatArray,
) -> None:  # fmt: skip
    """The bang-bang braking time θ of each scenario (0 when passing first is possible)."""
    horizon = c.horizon
    s_buf, v_buf = np.empty(horizon + 1), np.empty(horizon + 1)
    for b in range(start.shape[0]):
        _drive_one(start[b, 0], start[b, 1], 0.0, horizon, c, k, grid, w_sq, s_buf, v_buf)
        shares = False
        for t in range(horizon + 1):
            if north_in[b, t] and c.zone_entry <= s_buf[t] <= c.zone_exit:
                shares = True
                break
        if not shares:
            out[b] = 0.0
            continue
        low, high = 0.0, horizon * c.dt
        needed = min(max(north_last[b] + 1, 1), horizon)  # ticks that decide the entry
        for _ in range(_BISECTION_STEPS):
            mid = 0.5 * (low + high)
            _drive_one(start[b, 0], start[b, 1], mid, needed, c, k, grid, w_sq, s_buf, v_buf)
            first = horizon + 1
            for t in range(needed + 1):
                if s_buf[t] >= c.zone_entry:
                    first = t
                    break
            if first > north_last[b]:
                high = mid
            else:
                low = mid
        out[b] = high


@jit
def _clear_ticks(
    start: FloatArray, brake_time: FloatArray, c: OracleConstants, k: VehicleConstants,
    grid: FloatArray, w_sq: FloatArray, out: FloatArray,
) -> None:  # fmt: skip
    """First tick of each planned drive past the zone (``inf``: not within the horizon)."""
    horizon = c.horizon
    s_buf, v_buf = np.empty(horizon + 1), np.empty(horizon + 1)
    for b in range(start.shape[0]):
        _drive_one(start[b, 0], start[b, 1], brake_time[b], horizon, c, k, grid, w_sq, s_buf,
                   v_buf)  # fmt: skip
        out[b] = math.inf
        for t in range(horizon + 1):
            if s_buf[t] > c.zone_exit:
                out[b] = t
                break


#: Grid step of the braking time θ before bisection, with several conflicts [s].
_THETA_STEP = 0.1


@jit
def _free_of(
    s: float, v: float, brake_time: float, occupied: NDArray[np.bool_], zones: FloatArray,
    c: OracleConstants, k: VehicleConstants, grid: FloatArray, w_sq: FloatArray,
) -> bool:  # fmt: skip
    """Whether the drive braking for ``brake_time`` keeps the ego out of every zone
    ``zones[j]`` on the ticks ``occupied[j]`` marks, until it has passed them all."""
    last = -math.inf
    for j in range(zones.shape[0]):
        if not math.isnan(zones[j, 1]):
            last = max(last, zones[j, 1])
    for tick in range(c.horizon + 1):
        if tick:
            s, v = _advance(s, v, tick - 1, brake_time, c, k, grid, w_sq)
        if s > last:
            return True
        for j in range(zones.shape[0]):
            if occupied[j, tick] and zones[j, 0] <= s <= zones[j, 1]:
                return False
    return True


@jit
def _plan_brake_times_many(
    start: FloatArray, occupied: NDArray[np.bool_], zones: FloatArray, c: OracleConstants,
    k: VehicleConstants, grid: FloatArray, w_sq: FloatArray, out: FloatArray,
) -> None:  # fmt: skip
    """The smallest braking time θ of each scenario that keeps the ego out of every occupied
    zone (``occupied`` ``[B, C, H + 1]``): the first on a grid of :data:`_THETA_STEP`, then
    bisection down to the last infeasible grid point (``inf``: none within the horizon)."""
    longest = c.horizon * c.dt
    for b in range(start.shape[0]):
        s0, v0 = start[b, 0], start[b, 1]
        low, high = -1.0, math.inf
        theta = 0.0
        while theta <= longest + 1e-9:
            if _free_of(s0, v0, theta, occupied[b], zones, c, k, grid, w_sq):
                high = theta
                break
            low = theta
            theta += _THETA_STEP
        if low >= 0.0 and not math.isinf(high):
            for _ in range(_BISECTION_STEPS // 2):
                mid = 0.5 * (low + high)
                if _free_of(s0, v0, mid, occupied[b], zones, c, k, grid, w_sq):
                    high = mid
                else:
                    low = mid
        out[b] = high
