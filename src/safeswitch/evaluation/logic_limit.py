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

The result is a *relaxation*, so the times are lower bounds (up to float rounding): grid speeds
are rounded up (positions then run ahead of the true ones by at most ``dv·dt`` per tick, and
every constraint only removes a position if it rules out the whole box of true states it may
stand for); each speed keeps the hull of its intervals; there are no actuator lags. It knows
nothing of comfort beyond the oracle's limits, so a controller that exceeds them may be faster.

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
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.switching import (
    PaperConstants,
    PaperSwitching,
    firing_distance,
    time_to_reach,
)
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.sim.geometry import FloatArray
from safeswitch.sim.vehicle import closed_throttle_drag, driving_resistance

Braking = Literal["comfort", "throttle"]


class LimitLayout(NamedTuple):
    """The scalars the compiled reachability kernel reads (the paper logic's own constants
    travel separately, as :attr:`PaperSwitching.constants`).

    Attributes:
        dt: Tick [s].
        ego_zone_entry: Ego's conflict-zone entry on its route [m].
        ego_zone_exit: Ego's conflict-zone exit [m].
        north_zone_entry: North car's conflict-zone entry on its route [m].
        north_zone_exit: North car's conflict-zone exit [m].
        ego_conflict_point: Conflict point on the ego's route [m].
        north_conflict_point: Conflict point on the north car's route [m].
        approach_distance: Algorithm 1's "at the intersection" distance [m].
        speed_step: Step of the speed grid [m/s].
        logic: Whether the paper logic's constraint applies.
    """

    dt: float
    ego_zone_entry: float
    ego_zone_exit: float
    north_zone_entry: float
    north_zone_exit: float
    ego_conflict_point: float
    north_conflict_point: float
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
        logic: ``False`` drops the switching-logic constraint (then the bound is the oracle's
            time up to the grid's rounding: a check of the computation).

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
        self.task = task
        self.oracle = Oracle(task, limits)
        self.braking = braking
        lim = self.oracle.limits
        config = task.config
        bins = math.ceil(lim.max_speed / speed_step - 1e-9) + 1
        speeds = np.arange(bins, dtype=np.float64) * speed_step
        # Acceleration bounds at the slower neighbour of each grid speed: a grid speed stands
        # for true speeds up to one step below it, and the engine's reach falls with speed.
        slower = np.maximum(speeds - speed_step, 0.0)
        self._accel = self.oracle.max_accel(slower)
        self.top_speed = float(speeds[-1])
        if braking == "comfort":
            self._decel = np.full(bins, lim.max_decel)
        else:
            p = config.vehicle
            drag = closed_throttle_drag(p, speeds) + driving_resistance(p, speeds)
            self._decel = np.minimum(drag / p.mass, lim.accel_lon)
        self._curve = self._curvature_bands(speeds - speed_step)
        geo, paper = task.conflict, config.paper
        self._constants = LimitLayout(
            config.episode.dt, geo.zone_a[0], geo.zone_a[1], geo.zone_b[0], geo.zone_b[1],
            geo.s_point_a, geo.s_point_b, config.episode.approach_distance_m, speed_step,
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

    def times(self, scenarios: Scenarios) -> FloatArray:
        """Lower bounds on the time to clear [s] ``[B]`` (NaN: not possible within the
        horizon without triggering the logic)."""
        north, north_speed, start = self.oracle.north_trajectory(scenarios)
        ticks = _reachable(
            start, north, north_speed, self._accel, self._decel, self._curve, self._constants,
            self._paper,
        )  # fmt: skip
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


@jit
def _clear_tick(s0: float, v0: float, north: NDArray[np.float64], north_speed: NDArray[np.float64],
                accel: NDArray[np.float64], decel: NDArray[np.float64], curve: NDArray[np.float64],
                c: LimitLayout, paper: PaperConstants) -> int:  # fmt: skip
    """First tick on which the ego can be past its conflict zone, or -1 (see the class)."""
    dt, dv = c.dt, c.speed_step
    bins = accel.shape[0]
    lo = np.full(bins, np.inf)
    hi = np.full(bins, -np.inf)
    j0 = min(math.ceil(v0 / dv - 1e-12), bins - 1)
    lo[j0], hi[j0] = s0, s0
    new_lo = np.empty(bins)
    new_hi = np.empty(bins)
    piece_lo = np.empty(2 + curve.shape[1] + 4)
    piece_hi = np.empty(2 + curve.shape[1] + 4)
    for k in range(north.shape[0] - 1):
        tol = (k + 1) * dv * dt  # how far grid positions may run ahead of the true ones
        s_n, v_n = north[k + 1], north_speed[k + 1]
        north_in = c.north_zone_entry <= s_n <= c.north_zone_exit
        window = (c.north_conflict_point - s_n <= c.approach_distance) and (
            s_n <= c.north_zone_exit
        )
        ttr_n = time_to_reach(c.north_conflict_point - s_n, v_n, paper.min_speed)
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
                if north_in:
                    n = _remove(piece_lo, piece_hi, n, c.ego_zone_entry + tol, c.ego_zone_exit)
                if c.logic and window and n > 0:
                    # Fires for every true speed in (v2 - dv, v2] from the slowest one's braking
                    # point on, up to where the fastest one's TTR would leave a gap.
                    reach = firing_distance(max(v2 - dv, 0.0), paper)
                    fire_lo = max(
                        c.ego_zone_entry - reach, c.ego_conflict_point - c.approach_distance
                    )
                    fire_hi = c.ego_zone_exit
                    gap = ttr_n - paper.ttr_threshold_s
                    if gap >= 0:
                        fire_hi = min(
                            fire_hi, c.ego_conflict_point - gap * max(v2, paper.min_speed)
                        )
                    n = _remove(piece_lo, piece_hi, n, fire_lo + tol, fire_hi)
                for i in range(n):
                    new_lo[j2] = min(new_lo[j2], piece_lo[i])
                    new_hi[j2] = max(new_hi[j2], piece_hi[i])
        lo[:] = new_lo
        hi[:] = new_hi
        for j in range(bins):
            if lo[j] <= hi[j] and hi[j] > c.ego_zone_exit:
                return k + 1
    return -1


@numba.njit(cache=True, parallel=True)
def _reachable(start: NDArray[np.float64], north: NDArray[np.float64],
               north_speed: NDArray[np.float64], accel: NDArray[np.float64],
               decel: NDArray[np.float64], curve: NDArray[np.float64], c: LimitLayout,
               paper: PaperConstants) -> NDArray[np.int64]:  # fmt: skip
    out = np.empty(start.shape[0], dtype=np.int64)
    for b in numba.prange(start.shape[0]):
        out[b] = _clear_tick(start[b, 0], start[b, 1], north[b], north_speed[b], accel, decel,
                             curve, c, paper)  # fmt: skip
    return out
