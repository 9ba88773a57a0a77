"""The logic-aware limit: the fastest crossing that never triggers the paper switching logic.

The oracle (:mod:`safeswitch.evaluation.oracle`) is the efficiency limit of the task; it ignores
the switching logic, which fires on most of its plans (``benchmarks/planner_gap.py``). This is
the limit for a controller that must also *never* trigger Algorithm 1, within the oracle's
limits and with the same full knowledge of the north car's future: a lower bound on the time to
clear of every such controller, computed scenario by scenario.

It is computed on the oracle's point-mass model (``s'' = a`` on the route, speed cap ``v_max``
and ``v² κ ≤ a_lat``, ``-d(v) ≤ a ≤ a_max(v)``, checked on the simulator's ticks) by a
forward reachable-set computation: on every tick, for each speed on a grid of step ``dv``, the
interval of positions from which the car can be there. A tick moves every (speed, interval) to
every speed the acceleration limits allow, and removes the positions at which

- the speed exceeds the lateral comfort cap of the route's curvature,
- the ego would be in its conflict zone while the north car is in its own, or
- Algorithm 1 would fire: both cars at the intersection, ``TTR_n − TTR_e < threshold`` and
  ``d_stop ≤ d_safe + v·latency + margin`` (the task's own constants).

In traffic (:class:`~safeswitch.leftturn.traffic.LeftTurnTrafficTask`) the same holds against
every conflict at once, as the paper logic sees them (:mod:`~safeswitch.leftturn.logics.paper`,
written over any number of conflicts): the ego is out of each conflict zone while its
vehicle is in its own (the union of the occupied intervals), and no conflict's Algorithm 1 fires.
Like the multi-conflict oracle it plans against the others' world *without* the ego
(:meth:`~safeswitch.leftturn.task.LeftTurnTask.conflict_timeline`): in the episode
itself drivers who give way to the ego or follow it react to it, which the bound does not know.

The result is a *relaxation*, so the times are lower bounds (up to float rounding): grid speeds
are rounded up (positions then run ahead of the true ones by at most ``dv·dt`` per tick, and
every constraint only removes a position if it rules out the whole box of true states it may
stand for); each speed keeps the hull of its intervals; there are no actuator lags. It knows
nothing of comfort beyond the oracle's limits, so a controller that exceeds them may be faster.
In traffic a tick counts as the time to clear only if some state past the north car's zone can
go on past every later zone (or to the horizon) within the constraints — clearing into a zone
that is about to be occupied does not count. Where the true plan clears on the very tick a
vehicle enters, the grid's rounding may still let the bound pass first, so there it can lie
well below the multi-conflict oracle (``benchmarks/traffic_limit.py`` measures how often). It
stays a lower bound.

Two braking models: ``"comfort"`` brakes at the oracle's deceleration (any controller that can
brake), ``"throttle"`` only as hard as a closed throttle slows the plant (engine braking plus
driving resistance: the learned controller's means, which has no brake pedal).
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import jit
from safeswitch.core.config import check
from safeswitch.evaluation.oracle import Oracle, OracleLimits
from safeswitch.leftturn.logics.paper import (
    PaperConstants,
    PaperSwitching,
    firing_distance,
    time_to_reach,
)
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.task import ConflictTimeline, LeftTurnTask
from safeswitch.sim.geometry import FloatArray
from safeswitch.sim.vehicle import closed_throttle_drag, driving_resistance

Braking = Literal["comfort", "throttle"]


class LimitLayout(NamedTuple):
    """The scalars the compiled reachability kernel reads (the paper logic's own constants
    travel separately, as :attr:`PaperSwitching.constants`; the conflicts, tick by tick, as a
    :class:`~safeswitch.leftturn.task.ConflictTimeline`).

    Attributes:
        dt: Tick [s].
        clear_at: Where the ego has cleared: the exit of its zone with the north car [m].
        approach_distance: Algorithm 1's "at the intersection" distance [m].
        speed_step: Step of the speed grid [m/s].
        logic: Whether the paper logic's constraint applies.
    """

    dt: float
    clear_at: float
    approach_distance: float
    speed_step: float
    logic: bool


class PaperLogicLimit:
    """Lower bounds on the time to clear of controllers that never trigger the paper logic.

    Args:
        task: The task (its route, conflict zones, plant, tick, horizon and paper switching
            constants are used, whatever logic it runs itself).
        limits: The limits (default: the oracle's, :meth:`OracleLimits.from_config`).
        braking: ``"comfort"`` or ``"throttle"`` (see the module docstring).
        speed_step: Step of the speed grid [m/s]; smaller is tighter and slower.
        logic: ``False`` drops the switching-logic constraint (then, in the paper's scene, the
            bound is the oracle's time up to the grid's rounding: a check of the computation;
            in traffic a bound on the oracle's, see the module docstring).

    Attributes:
        top_speed: The highest speed the bound admits [m/s]: ``v_max`` rounded up to the grid.
    """

    def __init__(
        self,
        task: LeftTurnTask,
        limits: OracleLimits | None = None,
        braking: Braking = "comfort",
        speed_step: float = 0.01,
        logic: bool = True,
    ) -> None:
        check(braking in ("comfort", "throttle"), "limit", "braking", braking,
              "must be 'comfort' or 'throttle'")  # fmt: skip
        check(
            math.isfinite(speed_step) and 0 < speed_step <= 0.5,
            "limit",
            "speed_step",
            speed_step,
            "must be in (0, 0.5] m/s",
        )
        self.oracle = Oracle(task, limits)
        self.task = self.oracle.task  # an embedded twin, if ``task`` has one
        self.braking = braking
        lim = self.oracle.limits
        config = task.config
        bins = math.ceil(lim.max_speed / speed_step - 1e-9) + 1
        speeds = np.arange(bins, dtype=np.float64) * speed_step
        # Acceleration bounds at the slower neighbour of each grid speed: a grid speed stands
        # for true speeds up to one step below it, and the engine's reach falls with speed.
        slower = np.maximum(speeds - speed_step, 0.0)
        self.top_speed = float(speeds[-1])
        if braking == "comfort":
            decel = np.full(bins, lim.max_decel)
        else:
            p = config.vehicle
            drag = closed_throttle_drag(p, speeds) + driving_resistance(p, speeds)
            decel = np.minimum(drag / p.mass, lim.accel_lon)
        self._envelope = SpeedEnvelope(
            self.oracle.max_accel(slower), decel, self._curvature_bands(speeds - speed_step)
        )
        geo, paper = task.conflict, config.paper
        self._constants = LimitLayout(
            config.episode.dt, geo.zone_a[1], config.episode.approach_distance_m, speed_step,
            bool(logic),
        )  # fmt: skip
        self._paper = PaperSwitching(paper, config.controllers.emergency_decel).constants

    def _curvature_bands(self, speeds: FloatArray) -> FloatArray:
        """``[bins, R, 2]``: for each speed, the arc-length intervals on which even that speed
        exceeds the lateral cap (``V(s)² < v²``, ``V`` interpolated linearly between the route's
        nodes as in the oracle); unused rows are empty (lo > hi)."""
        grid, cap = self.oracle.grid, self.oracle.speed_cap_sq(self.oracle.grid)
        bands: list[list[tuple[float, float]]] = []
        for v in speeds:
            target = max(v, 0.0) ** 2
            below = cap < target
            runs: list[tuple[float, float]] = []
            i = 0
            while i < len(grid):
                if not below[i]:
                    i += 1
                    continue
                j = i
                while j + 1 < len(grid) and below[j + 1]:
                    j += 1
                runs.append(
                    (_crossing(grid, cap, i - 1, i, target), _crossing(grid, cap, j, j + 1, target))
                )
                i = j + 1
            bands.append(runs)
        rows = max(1, max(len(r) for r in bands))
        out = np.empty((len(speeds), rows, 2))
        out[..., 0], out[..., 1] = np.inf, -np.inf
        for b, runs in enumerate(bands):
            for r, (lo, hi) in enumerate(runs):
                out[b, r] = lo, hi
        return out

    def times(self, scenarios: Scenarios, chunk: int = 64) -> FloatArray:
        """Lower bounds on the time to clear [s] ``[B]`` (NaN: not possible within the
        horizon without triggering the logic). In traffic the scenarios are taken ``chunk``
        at a time (the conflict timeline holds every conflict on every tick)."""
        batch = len(scenarios.ego_speed)
        if not len(self.task.crossing_zones()):
            chunk = max(batch, 1)  # the paper's scene: one conflict, the whole batch at once
        rows = [np.arange(i, min(i + chunk, batch)) for i in range(0, batch, chunk)]
        parts = (self.task.conflict_timeline(scenarios.take(r)) for r in rows)
        out = np.empty(batch)
        for r, t in zip(rows, parts, strict=True):
            out[r] = self.bound(t)
        return out

    def bound(self, timeline: ConflictTimeline) -> FloatArray:
        """:meth:`times` against conflicts given tick by tick (``[B, H + 1, C]``, e.g. from
        the task's ``conflict_timeline``)."""
        ticks = _reachable(timeline, self._envelope, self._constants, self._paper)
        return np.where(ticks >= 0, ticks * self.task.config.episode.dt, np.nan)


def _crossing(grid: FloatArray, cap: FloatArray, i: int, j: int, target: float) -> float:
    """Where the linear interpolation of ``cap`` between nodes ``i`` and ``j`` crosses
    ``target`` (the end of the route if a node is missing)."""
    if i < 0:
        return -np.inf
    if j >= len(grid):
        return np.inf
    t = (cap[i] - target) / (cap[i] - cap[j])
    return float(grid[i] + t * (grid[j] - grid[i]))


@jit
def _remove(lo: NDArray[np.float64], hi: NDArray[np.float64], n: int, cut_lo: float,
            cut_hi: float) -> int:  # fmt: skip
    """Remove the open interval ``(cut_lo, cut_hi)`` from the ``n`` intervals ``[lo, hi]`` in
    place (there is room for ``n + 1``); returns the new count."""
    if cut_lo >= cut_hi:
        return n
    m = n
    for i in range(n):
        a, b = lo[i], hi[i]
        if b <= cut_lo or a >= cut_hi:
            continue
        if a < cut_lo and b > cut_hi:  # split in two
            hi[i] = cut_lo
            lo[m], hi[m] = cut_hi, b
            m += 1
        elif a < cut_lo:
            hi[i] = cut_lo
        elif b > cut_hi:
            lo[i] = cut_hi
        else:
            lo[i], hi[i] = np.inf, -np.inf
    k = 0
    for i in range(m):
        if lo[i] <= hi[i]:
            lo[k], hi[k] = lo[i], hi[i]
            k += 1
    return k


class SpeedEnvelope(NamedTuple):
    """What the ego can do from each grid speed ``[S]`` (``curve`` ``[S, K, 2]``).

    Attributes:
        accel: Its largest acceleration [m/s²].
        decel: Its largest deceleration [m/s²].
        curve: The stretches of its route it may not be in at that speed (the lateral limit),
            ``(from, to)`` [m].
    """

    accel: FloatArray
    decel: FloatArray
    curve: FloatArray


class Reach(NamedTuple):
    """A reachable set: the interval of positions ``[lo, hi]`` per grid speed ``[S]`` (empty
    where ``lo > hi``)."""

    lo: FloatArray
    hi: FloatArray


class Scratch(NamedTuple):
    """:func:`_tick`'s working arrays (allocated once per scene)."""

    new: Reach
    piece_lo: FloatArray
    piece_hi: FloatArray
    occupied: NDArray[np.int64]
    firing: NDArray[np.int64]
    gaps: FloatArray


@jit
def _tick(t: int, reachable: Reach, w: Scratch, timeline: ConflictTimeline, env: SpeedEnvelope,
          c: LimitLayout, paper: PaperConstants) -> bool:  # fmt: skip
    """Move the reachable set (per grid speed) from tick ``t - 1`` to ``t`` in
    place, removing what the constraints of tick ``t`` rule out; whether anything is left."""
    # The tuples' arrays taken out once (see jit).
    lo, hi, new_lo, new_hi = reachable.lo, reachable.hi, w.new.lo, w.new.hi
    piece_lo, piece_hi, occupied, firing, gaps = (
        w.piece_lo, w.piece_hi, w.occupied, w.firing, w.gaps,
    )  # fmt: skip
    present, ego_entry, ego_exit, ego_point = (
        timeline.present, timeline.ego_entry, timeline.ego_exit, timeline.ego_point,
    )  # fmt: skip
    other_distance, other_inside, other_window, other_speed = (
        timeline.other_distance, timeline.other_inside, timeline.other_window,
        timeline.other_speed,
    )  # fmt: skip
    accel, decel, curve = env.accel, env.decel, env.curve
    dt, dv = c.dt, c.speed_step
    bins, conflicts = accel.shape[0], present.shape[1]
    tol = t * dv * dt  # how far grid positions may run ahead of the true ones
    n_occ, n_fire = 0, 0
    for q in range(conflicts):
        if not present[t, q]:
            continue
        if other_inside[t, q]:
            occupied[n_occ] = q
            n_occ += 1
        if c.logic and other_window[t, q]:
            firing[n_fire] = q
            gaps[n_fire] = (
                time_to_reach(other_distance[t, q], other_speed[t, q], paper.min_speed)
                - paper.ttr_threshold_s
            )
            n_fire += 1
    new_lo[:] = np.inf
    new_hi[:] = -np.inf
    for j in range(bins):
        if lo[j] > hi[j]:
            continue
        v = j * dv
        j_min = max(math.floor((v - decel[j] * dt) / dv) - 1, 0)
        j_max = min(math.floor((v + accel[j] * dt) / dv) + 1, bins - 1)
        for j2 in range(j_min, j_max + 1):
            v2 = j2 * dv
            ds = 0.5 * (v + v2) * dt
            piece_lo[0], piece_hi[0] = lo[j] + ds, hi[j] + ds
            n = 1
            for r in range(curve.shape[1]):
                n = _remove(piece_lo, piece_hi, n, curve[j2, r, 0] + tol, curve[j2, r, 1])
            for i in range(n_occ):
                q = occupied[i]
                n = _remove(piece_lo, piece_hi, n, ego_entry[t, q] + tol, ego_exit[t, q])
            if n_fire and n > 0:
                # Fires for every true speed in (v2 - dv, v2] from the slowest one's braking
                # point on, up to where the fastest one's TTR would leave a gap.
                reach = firing_distance(max(v2 - dv, 0.0), paper)
                for i in range(n_fire):
                    q = firing[i]
                    point = ego_point[t, q]
                    fire_lo = max(ego_entry[t, q] - reach, point - c.approach_distance)
                    fire_hi = ego_exit[t, q]
                    if gaps[i] >= 0:
                        fire_hi = min(fire_hi, point - gaps[i] * max(v2, paper.min_speed))
                    n = _remove(piece_lo, piece_hi, n, fire_lo + tol, fire_hi)
            for i in range(n):
                new_lo[j2] = min(new_lo[j2], piece_lo[i])
                new_hi[j2] = max(new_hi[j2], piece_hi[i])
    lo[:] = new_lo
    hi[:] = new_hi
    alive = False
    for j in range(bins):
        if lo[j] <= hi[j]:
            alive = True
            break
    return alive


@jit
def _clear_tick(timeline: ConflictTimeline, env: SpeedEnvelope, c: LimitLayout,
                paper: PaperConstants) -> int:  # fmt: skip
    """First tick on which the ego can be past its conflict zone with the north car and still
    get past every later zone without breaking a constraint, or -1 (see the class; the
    timeline of one scene: ``start`` ``[2]``, the conflicts ``[H + 1, C]``)."""
    present, ego_exit, curve = timeline.present, timeline.ego_exit, env.curve
    bins, conflicts, ticks = env.accel.shape[0], present.shape[1], present.shape[0]
    s0, v0 = timeline.start[0], timeline.start[1]
    lo = np.full(bins, np.inf)
    hi = np.full(bins, -np.inf)
    j0 = min(math.ceil(v0 / c.speed_step - 1e-12), bins - 1)
    lo[j0], hi[j0] = s0, s0
    go_lo, go_hi = np.empty(bins), np.empty(bins)  # the continuation from a clearing tick
    room = 2 + curve.shape[1] + 2 * conflicts + 4
    scratch = Scratch(
        Reach(np.empty(bins), np.empty(bins)), np.empty(room), np.empty(room),
        np.empty(conflicts, dtype=np.int64), np.empty(conflicts, dtype=np.int64),
        np.empty(conflicts),
    )  # fmt: skip
    reach, go = Reach(lo, hi), Reach(go_lo, go_hi)
    last = c.clear_at  # past this, no zone is left ahead of the ego
    for t in range(ticks):
        for q in range(conflicts):
            if present[t, q]:
                last = max(last, ego_exit[t, q])
    for t in range(1, ticks):
        if not _tick(t, reach, scratch, timeline, env, c, paper):
            return -1
        cleared = False
        for j in range(bins):
            if lo[j] <= hi[j] and hi[j] > c.clear_at:
                cleared = True
                go_lo[j], go_hi[j] = max(lo[j], c.clear_at), hi[j]
            else:
                go_lo[j], go_hi[j] = np.inf, -np.inf
        if not cleared:
            continue
        # Viable: some state past the zone can go on past every zone still ahead (or to the
        # horizon) without breaking a constraint; in the paper's scene there is none ahead.
        viable, t2 = True, t
        while viable and t2 + 1 < ticks:
            far = False
            for j in range(bins):
                if go_lo[j] <= go_hi[j] and go_hi[j] > last:
                    far = True
                    break
            if far:
                break
            t2 += 1
            viable = _tick(t2, go, scratch, timeline, env, c, paper)
        if viable:
            return t
    return -1


@numba.njit(cache=True, parallel=True)
def _reachable(timeline: ConflictTimeline, env: SpeedEnvelope, c: LimitLayout,
               paper: PaperConstants) -> NDArray[np.int64]:  # fmt: skip
    t = timeline
    out = np.empty(t.start.shape[0], dtype=np.int64)
    for b in numba.prange(t.start.shape[0]):
        scene = ConflictTimeline(
            t.start[b], t.present[b], t.ego_entry[b], t.ego_exit[b], t.ego_point[b],
            t.other_distance[b], t.other_inside[b], t.other_window[b], t.other_speed[b],
        )  # fmt: skip
        out[b] = _clear_tick(scene, env, c, paper)
    return out
