"""Traffic from every leg: other vehicles on all twelve movements, batch-first.

Every scene has ``N`` slots of other vehicles (a fixed maximum; unused slots are inactive). A
vehicle drives along the centre line of its route as a point mass (what SUMO's default model
does too), ``s' = v``, ``v' = a``, advanced every tick in one compiled loop over the scenes.
``a`` comes from its driver, who decides every ``action_step`` ticks (SUMO's *action step
length*: on the scene's ticks with ``tick % action_step == 0``) and holds it in between —
drivers react, they do not re-plan every 20 ms. A decision is:

1. **Car following** — the Intelligent Driver Model (:mod:`safeswitch.sim.idm`) behind the
   nearest vehicle ahead on the same lane: any vehicle, the automated ego included, on a shared
   segment of the two routes (:attr:`RoadNetwork.shared`).
2. **Right of way** — within ``look_ahead`` metres before a conflict zone with a vehicle that
   has the right of way (lower
   :func:`~safeswitch.sim.network.priority_rank`; on equal rank, the one that can arrive first),
   a driver goes only if it can clear its zone, driving on at no less than ``go_accel``,
   ``gap_time`` before the other can possibly reach its own (accelerating at its bound up to
   its top speed) — and, keeping the box clear, only if its leader has left room for it past
   the zone; else it treats its zone's entry as a stopped vehicle and waits there.
3. **Occupied zones** — nobody enters a conflict zone while a conflicting vehicle is inside its
   own (however late that vehicle has become): the last line against collisions among them.

4. **Curves** — a driver takes a turn within :data:`TURN_LATERAL_ACCEL` (``v² |κ|``): its
   desired speed is capped by the speeds from which braking at the IDM's comfortable
   deceleration keeps to it at every curve ahead (:func:`curve_envelope`), and the tyres give
   its pedals no more than the friction circle leaves (:func:`grip_room`), as for the ego.

A driver who *yields* follows 2 and 3 towards the ego too (the ego, turning left from the main
road, has the right of way over the minor road); a *non-yielding* driver ignores the ego there
— the paper's north car — but still keeps its distance when following it. A yielding driver
loses patience (SUMO's ``impatience`` is the same idea): once it has waited ``patience`` seconds
it no longer gives way to an ego that is waiting too (slower than ``slow_speed``) — without it
a courteous driver and a cautious ego would wait for each other forever. Other vehicles never
ignore each other, so collisions among them are impossible by these rules as long as their
brakes can keep up (the tests count them; they must stay 0).

Vehicles keep coming: each scene carries an :class:`ArrivalSchedule` per approach (drawn with
the scene, so a scene is a pure function of its seed). A scheduled vehicle enters at the start
of its approach once its time has come, a slot is free and the lane there has room for it
(:func:`spawn`: it enters no faster than its leader and with the IDM's equilibrium gap);
otherwise it waits outside the scene, as in a queue. A vehicle leaves the scene
``exit_distance`` metres after the box, freeing its slot.

The ego's own route, speed and pose come in from the plant each tick; the ego uses the network's
``south->west`` movement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import jit
from safeswitch.sim.collision import separation
from safeswitch.sim.geometry import FloatArray, heading_axes, pose_axes
from safeswitch.sim.idm import IDMKernel, idm_accel
from safeswitch.sim.network import RoadNetwork

BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]


class RightOfWay(NamedTuple):
    """The drivers' right-of-way rules, as compiled code reads them.

    Attributes:
        gap_time: Margin between clearing one's zone and the earliest arrival of a vehicle with
            the right of way [s].
        go_accel: Acceleration a driver counts on when it estimates its own clearing time (below
            the IDM's 1.5 m/s²: the estimate is an upper bound) [m/s²].
        stop_buffer: Distance before a zone's entry where a waiting driver stops [m].
        ego_accel: Bound on the acceleration of a vehicle driven by the plant (the ego, the
            paper's north car), for its earliest arrival [m/s²].
        ego_rank: The ego's right of way (1: turning left from the main road).
        length: Vehicle length [m] (for gaps).
        patience: Waiting time after which a yielding driver goes before a waiting ego [s].
        look_ahead: A driver heeds a conflict zone from this far before it [m].
        slow_speed: Below this speed a vehicle counts as waiting [m/s].
    """

    gap_time: float
    go_accel: float
    stop_buffer: float
    ego_accel: float
    ego_rank: int
    length: float
    patience: float
    slow_speed: float
    look_ahead: float


class NetworkTables(NamedTuple):
    """The network's per-movement tables, as compiled code reads them."""

    shared: FloatArray  # [R, R, 2, 3]
    shares: BoolArray  # [R, R]: any shared segment (a quick test before _leader)
    conflicts: FloatArray  # [R, R, 2]
    ranks: IntArray  # [R]
    lengths: FloatArray  # [R]
    box_exits: FloatArray  # [R]
    zones_from: FloatArray  # [R]: where the route's first conflict zone starts
    zones_to: FloatArray  # [R]: where its last one ends
    route_tables: FloatArray  # RouteSet.tables
    axes: FloatArray  # heading_axes(route_tables)
    spacing: float
    k_max: int
    size: int
    curvature: FloatArray  # [R, size]: |κ| at each waypoint (padding straight)
    curve_speed_sq: FloatArray  # [R, size]: the drivers' squared speed envelope at each waypoint
    grip: float  # μ·g [m/s²]


#: What an ordinary driver takes a turn at: ``v² |κ| ≤`` this [m/s²] (urban turning speeds of
#: 3 m/s² and less are typical; the paper's own comfort limit for the ego is the same).
TURN_LATERAL_ACCEL = 3.0


#: A driver faster than its curve envelope slows towards it with this time constant [s].
CURVE_RESPONSE_S = 0.5


def curve_envelope(
    curvature: FloatArray, spacing: float, lateral_accel: float, decel: float
) -> FloatArray:
    """At each waypoint (rows: routes), the largest squared speed from which braking at
    ``decel`` keeps ``v² |κ| ≤ lateral_accel`` at every later waypoint [m²/s²]."""
    curve = np.where(curvature > 0, lateral_accel / np.maximum(curvature, 1e-12), np.inf)
    out = np.empty_like(curve)
    out[..., -1] = curve[..., -1]
    for i in range(curve.shape[-1] - 2, -1, -1):
        out[..., i] = np.minimum(curve[..., i], out[..., i + 1] + 2.0 * decel * spacing)
    return out


def network_tables(
    network: RoadNetwork, grip: float, decel: float, lateral_accel: float = TURN_LATERAL_ACCEL
) -> NetworkTables:
    """The network as the compiled traffic reads it; the drivers brake for curves at ``decel``
    [m/s²] to take them within ``lateral_accel``, and the tyres give at most ``grip`` (``μ·g``)
    [m/s²] in all."""
    routes = network.routes
    kappa = np.zeros((len(routes.routes), routes.size))
    for r, route in enumerate(routes.routes):
        kappa[r, : len(route.points)] = np.abs(route.curvature)
    # a waypoint's segments on both sides: the sharper one counts, so that the value read at the
    # waypoint before a vehicle bounds the curvature up to the next one
    kappa[:, :-1] = np.maximum(kappa[:, :-1], kappa[:, 1:])
    return NetworkTables(
        np.ascontiguousarray(network.shared),
        np.ascontiguousarray((network.shared[..., 0] <= network.shared[..., 1]).any(axis=-1)),
        np.ascontiguousarray(network.conflicts),
        network.ranks, network.lengths, network.box_exits,
        np.nanmin(network.conflicts[..., 0], axis=1), np.nanmax(network.conflicts[..., 1], axis=1),
        routes.tables, heading_axes(routes.tables), routes.spacing, routes.size - 2, routes.size,
        kappa, curve_envelope(kappa, routes.spacing, lateral_accel, decel), float(grip),
    )  # fmt: skip


@jit
def _at(table: FloatArray, route: int, progress: float, spacing: float) -> float:
    """A per-waypoint table's value at the waypoint at or before ``progress``."""
    k = min(max(int(progress // spacing), 0), table.shape[1] - 1)
    return table[route, k]


@jit
def grip_room(route: int, progress: float, speed: float, t: NetworkTables) -> float:
    """What the tyres leave for the pedals at ``speed`` on ``route`` at ``progress``:
    ``√((μ·g)² − (v² κ)²)`` [m/s²] (0 where cornering alone takes all of it)."""
    lateral = speed * speed * _at(t.curvature, route, progress, t.spacing)
    return math.sqrt(max(t.grip * t.grip - lateral * lateral, 0.0))


@dataclass
class ArrivalSchedule:
    """The vehicles still to enter each scene, per approach leg in order of arrival, arrays
    ``[B, L, M]`` (``L`` legs, at most ``M`` arrivals each; ``time`` is ``inf`` past the last).

    Attributes:
        time: Scene time at which it reaches the start of its approach [s].
        route: Its movement.
        desired: Its desired speed [m/s].
        yields: Whether it yields to the ego.
    """

    time: FloatArray
    route: IntArray
    desired: FloatArray
    yields: BoolArray


@dataclass
class TrafficState:
    """The other vehicles of ``B`` scenes, ``N`` slots each, arrays ``[B, N]``, and the
    vehicles still to come.

    Attributes:
        route: Movement index (into the network's routes).
        progress: Arc length along the route [m].
        speed: Speed [m/s].
        desired: Desired speed ``v0`` [m/s].
        yields: Whether the driver yields to the ego (else it ignores the ego at conflicts).
        active: Whether the slot holds a vehicle.
        waited: Time spent slower than :attr:`RightOfWay.slow_speed` before leaving the box [s].
        accel: The acceleration its driver last decided on, held until the next decision
            [m/s²] (0 for a vehicle that entered since).
        x: Position east [m].
        y: Position north [m].
        cos_yaw: Heading cosine.
        sin_yaw: Heading sine.
        schedule: The vehicles still to come (read-only while a scene runs).
        entered: How many of each leg's scheduled vehicles have entered ``[B, L]``.
        next_arrival: When the next scheduled vehicle of the scene is due [s] ``[B]`` (what
            :func:`spawn` checks before it reads the schedule).
    """

    route: IntArray
    progress: FloatArray
    speed: FloatArray
    desired: FloatArray
    yields: BoolArray
    active: BoolArray
    waited: FloatArray
    x: FloatArray
    y: FloatArray
    cos_yaw: FloatArray
    sin_yaw: FloatArray
    accel: FloatArray
    schedule: ArrivalSchedule
    entered: IntArray
    next_arrival: FloatArray

    @property
    def batch_size(self) -> int:
        return int(self.route.shape[0])

    def copy(self, schedule: bool = False, overwritten: tuple[str, ...] = ()) -> TrafficState:
        """A copy of the vehicles (the schedule shared unless ``schedule``: it never changes
        while a scene runs, and copying it every tick would cost more than the tick); the
        fields named in ``overwritten`` are allocated but not filled (for a caller that
        writes every element of them)."""
        values = {
            f.name: (np.empty_like if f.name in overwritten else np.copy)(getattr(self, f.name))
            for f in fields(self)
            if f.name != "schedule"
        }
        plan = self.schedule
        if schedule:
            plan = ArrivalSchedule(*(getattr(plan, f.name).copy() for f in fields(plan)))
        return TrafficState(**values, schedule=plan)


class StreamConstants(NamedTuple):
    """What the compiled streams read that stays fixed for a scene's traffic.

    Attributes:
        tables: The network's per-movement tables.
        rules: The drivers' right-of-way rules.
        idm: The drivers' car-following model.
        dt: Tick [s].
        exit_at: Where a vehicle leaves the scene, per movement [m] ``[R]``.
    """

    tables: NetworkTables
    rules: RightOfWay
    idm: IDMKernel
    dt: float
    exit_at: FloatArray


class Drivers(NamedTuple):
    """The other vehicles' arrays ``[B, N]`` the compiled streams read and write (the fields
    of :class:`TrafficState` of the same names)."""

    route: IntArray
    progress: FloatArray
    speed: FloatArray
    desired: FloatArray
    yields: BoolArray
    active: BoolArray
    waited: FloatArray
    accel: FloatArray

    @classmethod
    def of(cls, state: TrafficState) -> Drivers:
        return cls(state.route, state.progress, state.speed, state.desired, state.yields,
                   state.active, state.waited, state.accel)  # fmt: skip


class Externals(NamedTuple):
    """The vehicles driven by the plant — the ego, the paper's north car — as the drivers see
    them, arrays ``[B, E]``.

    Attributes:
        route: Their movements.
        progress: Their arc lengths [m].
        speed: Their speeds [m/s].
        top: Their top speeds [m/s] (for their earliest arrival).
        is_ego: ``[E]``: the automated ego (a non-yielding driver ignores it at conflicts;
            every other one is given way to by the rules).
    """

    route: IntArray
    progress: FloatArray
    speed: FloatArray
    top: FloatArray
    is_ego: BoolArray


class Arrivals(NamedTuple):
    """An :class:`ArrivalSchedule`'s arrays, as the compiled :func:`spawn` reads them."""

    time: FloatArray
    route: IntArray
    desired: FloatArray
    yields: BoolArray

    @classmethod
    def of(cls, schedule: ArrivalSchedule) -> Arrivals:
        return cls(schedule.time, schedule.route, schedule.desired, schedule.yields)


@jit
def named_stream_constants(c: tuple[Any, ...]) -> StreamConstants:
    """The inverse of ``plain`` for :class:`StreamConstants` (in compiled code)."""
    return StreamConstants(NetworkTables(*c[0]), RightOfWay(*c[1]), IDMKernel(*c[2]), c[3], c[4])


def place(tables: NetworkTables, state: TrafficState) -> None:
    """Fill the poses of ``state``'s active vehicles from their routes and arc lengths (in
    place; an empty slot keeps whatever it held)."""
    _place(
        tables, state.route, state.progress, state.active, state.x, state.y, state.cos_yaw,
        state.sin_yaw,
    )  # fmt: skip


@jit
def _place(
    t: NetworkTables, route: IntArray, progress: FloatArray, active: BoolArray, x: FloatArray,
    y: FloatArray, c: FloatArray, s: FloatArray,
) -> None:  # fmt: skip
    for b in range(route.shape[0]):
        for i in range(route.shape[1]):
            if not active[b, i]:
                continue
            x[b, i], y[b, i], c[b, i], s[b, i] = pose_axes(
                t.route_tables, t.axes, t.spacing, t.k_max, route[b, i] * t.size, progress[b, i]
            )


@jit
def earliest_arrival(distance: float, speed: float, accel: float, top: float) -> float:
    """Shortest time to drive ``distance`` [m] from ``speed`` accelerating at ``accel`` up to
    ``top`` [m/s] [s] (0 if already there)."""
    if distance <= 0.0:
        return 0.0
    top = max(top, speed)
    to_top = (top * top - speed * speed) / (2.0 * accel)
    if distance <= to_top:
        return (math.sqrt(speed * speed + 2.0 * accel * distance) - speed) / accel
    return (top - speed) / accel + (distance - to_top) / top


@jit
def _leader(t: NetworkTables, ri: int, si: float, rj: int, sj: float) -> float:
    """Gap along ``ri`` from a vehicle at ``si`` to one on ``rj`` at ``sj`` when they share a
    lane there and the other is ahead (bumper to bumper needs the length subtracted), else
    ``inf``."""
    best = math.inf
    for k in range(2):
        lo, hi, off = t.shared[ri, rj, k, 0], t.shared[ri, rj, k, 1], t.shared[ri, rj, k, 2]
        if lo > hi or si < lo - 10.0 or si > hi:
            continue
        mapped = sj - off  # the other's position in this route's arc length
        if mapped >= lo - 10.0 and mapped > si:
            best = min(best, mapped - si)
    return best


@jit
def traffic_tick_entry(
    c: tuple[Any, ...], old: tuple[Any, ...], ext: tuple[Any, ...], decide: BoolArray,
    new: tuple[Any, ...],
) -> None:  # fmt: skip
    """:func:`traffic_tick` called with plain tuples (see
    :func:`~safeswitch.core.arrays.plain`), named again here."""
    traffic_tick(named_stream_constants(c), Drivers(*old), Externals(*ext), decide, Drivers(*new))


@jit
def traffic_tick(
    c: StreamConstants, old: Drivers, ext: Externals, decide: BoolArray, new: Drivers
) -> None:
    """One tick of every other vehicle of every scene (see the module docstring), from
    ``old`` into ``new``'s progress, speed, waiting time and acceleration. ``ext`` are the
    vehicles driven by the plant, seen by the drivers as they are. Where ``decide`` ``[B]``
    is false the drivers of that scene hold their last accelerations (``old.accel``);
    ``new.accel`` gets each vehicle's acceleration over the tick."""
    # The tuples' arrays taken out once (see jit).
    t, rules, idm, dt = c.tables, c.rules, c.idm, c.dt
    route, progress, speed, desired, yields, active, waited, held = (
        old.route, old.progress, old.speed, old.desired, old.yields, old.active, old.waited,
        old.accel,
    )  # fmt: skip
    ext_route, ext_progress, ext_speed, ext_top, ext_is_ego = (
        ext.route, ext.progress, ext.speed, ext.top, ext.is_ego,
    )  # fmt: skip
    new_progress, new_speed, new_waited, accel_out = new.progress, new.speed, new.waited, new.accel
    scenes, slots = route.shape
    externals = ext_route.shape[1]
    # On a decision tick a scene's active vehicles are gathered first: the pair loops below
    # then skip no empty slots (visiting them in slot order, as ties between equally near
    # leaders are broken).
    index = np.empty(slots, dtype=np.int64)
    for b in range(scenes):
        n = 0
        for i in range(slots):
            if not active[b, i]:
                new_progress[b, i], new_speed[b, i], accel_out[b, i] = (
                    progress[b, i], speed[b, i], 0.0,
                )  # fmt: skip
                new_waited[b, i] = waited[b, i]
            elif not decide[b]:  # between two of its driver's decisions: the last one holds
                _advance(b, i, route[b, i], progress[b, i], speed[b, i], held[b, i], dt, t,
                         rules, waited, new_progress, new_speed, new_waited, accel_out)  # fmt: skip
            else:
                index[n] = i
                n += 1
        for k in range(n):
            i = index[k]
            ri, si, vi = route[b, i], progress[b, i], speed[b, i]
            gap, lead_v = math.inf, 0.0
            # 1. the nearest vehicle ahead on the same lane (the ego included)
            for e in range(externals):
                if not t.shares[ri, ext_route[b, e]]:
                    continue
                g = _leader(t, ri, si, ext_route[b, e], ext_progress[b, e])
                if g < gap:
                    gap, lead_v = g, ext_speed[b, e]
            for m in range(n):
                j = index[m]
                if j == i or not t.shares[ri, route[b, j]]:
                    continue
                g = _leader(t, ri, si, route[b, j], progress[b, j])
                if g < gap:
                    gap, lead_v = g, speed[b, j]
            ahead = gap  # centre to centre
            gap = gap - rules.length
            # 2.-3. conflict zones
            stop_at = math.inf
            my_rank = t.ranks[ri]
            impatient = waited[b, i] >= rules.patience
            heeds = t.zones_from[ri] - si <= rules.look_ahead and si <= t.zones_to[ri]
            for m in range(-externals, n if heeds else -externals):
                j = index[m] if m >= 0 else m  # an external vehicle when negative
                if j == i:
                    continue
                e = j + externals  # the external vehicle's index when j < 0
                rj = ext_route[b, e] if j < 0 else route[b, j]
                sj = ext_progress[b, e] if j < 0 else progress[b, j]
                vj = ext_speed[b, e] if j < 0 else speed[b, j]
                z_in, z_out = t.conflicts[ri, rj, 0], t.conflicts[ri, rj, 1]
                if math.isnan(z_in) or si > z_in or z_in - si > rules.look_ahead:
                    continue  # no conflict, already inside its zone (it cannot undo that), or far
                w_in, w_out = t.conflicts[rj, ri, 0], t.conflicts[rj, ri, 1]
                if sj > w_out:
                    continue  # the other has passed
                if (
                    j < 0
                    and ext_is_ego[e]
                    and (not yields[b, i] or (impatient and vj < rules.slow_speed))
                ):
                    continue  # a non-yielding (or impatient) driver ignores the ego
                entry = z_in - rules.stop_buffer
                # 3. the other is inside its zone: wait before one's own
                if sj >= w_in:
                    stop_at = min(stop_at, entry)
                    continue
                # 2. give way if the other has the right of way: a higher rank, or the same
                # and the earlier possible arrival
                their_rank = t.ranks[rj]
                if j < 0 and ext_is_ego[e]:
                    their_rank = rules.ego_rank
                if their_rank > my_rank:
                    continue
                # one that cannot stop before its zone any more goes on (it was allowed to)
                if vi > rules.slow_speed and si + vi * vi / (2.0 * idm.max_brake) > entry:
                    continue
                if j < 0:
                    their_accel, their_top = rules.ego_accel, ext_top[b, e]
                else:
                    their_accel, their_top = idm.max_accel, desired[b, j]
                arrive = earliest_arrival(w_in - sj, vj, their_accel, their_top)
                if their_rank == my_rank and arrive >= earliest_arrival(
                    z_in - si, vi, idm.max_accel, desired[b, i]
                ):
                    continue
                # keep the box clear: not before the leader has left room past the zone
                if si + ahead < z_out + rules.length + idm.min_gap:
                    stop_at = min(stop_at, entry)
                    continue
                clear = earliest_arrival(z_out + rules.length - si, vi, rules.go_accel, 1e9)
                if clear + rules.gap_time > arrive:
                    stop_at = min(stop_at, entry)
            if stop_at - si < gap:
                # a virtual stopped vehicle whose rear is at stop_at (the real leader stays the
                # one to follow when it is nearer: it may wait beyond that point)
                gap, lead_v = stop_at - si, 0.0
            # The driver slows for curves ahead (its desired speed capped by the envelope),
            # and the tyres give the pedals only what cornering leaves them.
            # (read here and where the driver will be after its response time: it slows in
            # time, and speeds up only once out of the curve)
            curve = math.sqrt(min(_at(t.curve_speed_sq, ri, si, t.spacing),
                                  _at(t.curve_speed_sq, ri, si + vi * CURVE_RESPONSE_S,
                                      t.spacing)))  # fmt: skip
            a = idm_accel(vi, min(desired[b, i], curve), gap if gap < 1e8 else math.inf, lead_v,
                          idm)  # fmt: skip
            if vi > curve:  # late for a curve (IDM's free term brakes gently): catch up
                a = min(a, (curve - vi) / CURVE_RESPONSE_S)
            room = grip_room(ri, si, vi, t)
            a = min(max(a, -room), room)
            _advance(b, i, ri, si, vi, a, dt, t, rules, waited, new_progress, new_speed, new_waited,
                     accel_out)  # fmt: skip


@jit
def _advance(
    b: int, i: int, ri: int, si: float, vi: float, a: float, dt: float, t: NetworkTables,
    rules: RightOfWay, waited: FloatArray, new_progress: FloatArray, new_speed: FloatArray,
    new_waited: FloatArray, accel_out: FloatArray,
) -> None:  # fmt: skip
    """Vehicle ``i`` of scene ``b`` over one tick at acceleration ``a`` [m/s²] (stopping, not
    reversing, when the speed would go negative)."""
    v_next = vi + a * dt
    if v_next < 0.0:  # stops within the tick
        new_progress[b, i] = si + vi * vi / (2.0 * max(-a, 1e-9))
        new_speed[b, i] = 0.0
    else:
        new_progress[b, i] = si + vi * dt + 0.5 * a * dt * dt
        new_speed[b, i] = v_next
    accel_out[b, i] = a
    in_queue = si <= t.box_exits[ri] and new_speed[b, i] < rules.slow_speed
    new_waited[b, i] = waited[b, i] + dt if in_queue else waited[b, i]


@jit
def npc_separations(
    x: FloatArray, y: FloatArray, cos_yaw: FloatArray, sin_yaw: FloatArray, active: BoolArray,
    length: float, width: float, ego_x: FloatArray, ego_y: FloatArray, ego_cos: FloatArray,
    ego_sin: FloatArray, ego_gap: FloatArray, npc_collisions: IntArray,
) -> None:  # fmt: skip
    """Per scene: the ego's separation from the nearest other vehicle [m] (``ego_gap``) and the
    number of overlapping pairs of other vehicles (``npc_collisions``); a bounding-circle test
    first, the separating-axis test only for close pairs."""
    scenes, slots = x.shape
    reach = length + width  # beyond this centre distance two cars cannot touch
    # The active vehicles of a scene gathered first (their positions side by side): the pair
    # loop then has no empty slots to skip.
    index = np.empty(slots, dtype=np.int64)
    px, py = np.empty(slots), np.empty(slots)
    for b in range(scenes):
        n = 0
        for i in range(slots):
            if active[b, i]:
                index[n], px[n], py[n] = i, x[b, i], y[b, i]
                n += 1
        best, far = math.inf, math.inf  # far: the smallest squared distance beyond reach
        for k in range(n):
            dx, dy = px[k] - ego_x[b], py[k] - ego_y[b]
            square = dx * dx + dy * dy
            if square < reach * reach:
                i = index[k]
                gap = separation(
                    dx, dy, ego_cos[b], ego_sin[b], length, width, cos_yaw[b, i],
                    sin_yaw[b, i], length, width,
                )  # fmt: skip
                best = min(best, gap)
            else:
                far = min(far, square)
        # one square root for the nearest of the far ones (the root is monotonic)
        ego_gap[b] = min(best, math.sqrt(far) - reach)
        count = 0
        for k in range(n):
            for m in range(k + 1, n):
                dx, dy = px[m] - px[k], py[m] - py[k]
                if dx * dx + dy * dy >= reach * reach:
                    continue
                i, j = index[k], index[m]
                if separation(dx, dy, cos_yaw[b, i], sin_yaw[b, i], length, width,
                              cos_yaw[b, j], sin_yaw[b, j], length, width) <= 0.0:  # fmt: skip
                    count += 1
        npc_collisions[b] = count


@jit
def spawn_entry(
    c: tuple[Any, ...], now: FloatArray, arrivals: tuple[Any, ...], entered: IntArray,
    next_arrival: FloatArray, drivers: tuple[Any, ...], ext: tuple[Any, ...],
) -> None:  # fmt: skip
    """:func:`spawn` called with plain tuples, named again here."""
    spawn(named_stream_constants(c), now, Arrivals(*arrivals), entered, next_arrival,
          Drivers(*drivers), Externals(*ext))  # fmt: skip


@jit
def spawn(
    c: StreamConstants, now: FloatArray, arrivals: Arrivals, entered: IntArray,
    next_arrival: FloatArray, drivers: Drivers, ext: Externals,
) -> None:  # fmt: skip
    """Retire the vehicles past their exit (``c.exit_at``) and let in the scheduled ones whose
    time ``now`` ``[B]`` has come (see the module docstring), in place; ``next_arrival``
    ``[B]`` is kept at the soonest time a scene's schedule has anything due (scenes with
    nothing due skip their schedule: reading it is a cache miss per leg)."""
    # The tuples' arrays taken out once (see jit).
    t, rules, idm, exit_at = c.tables, c.rules, c.idm, c.exit_at
    arrive_time, arrive_route, arrive_desired, arrive_yields = (
        arrivals.time, arrivals.route, arrivals.desired, arrivals.yields,
    )  # fmt: skip
    route, progress, speed, desired, yields, active, waited, accel = (
        drivers.route, drivers.progress, drivers.speed, drivers.desired, drivers.yields,
        drivers.active, drivers.waited, drivers.accel,
    )  # fmt: skip
    ext_route, ext_progress, ext_speed = ext.route, ext.progress, ext.speed
    scenes, slots = route.shape
    legs, most = arrive_time.shape[1], arrive_time.shape[2]
    for b in range(scenes):
        for i in range(slots):
            if active[b, i] and progress[b, i] >= exit_at[route[b, i]]:
                active[b, i] = False
        if next_arrival[b] > now[b]:
            continue
        for leg in range(legs):
            n = entered[b, leg]
            if n >= most or arrive_time[b, leg, n] > now[b]:
                continue
            free = -1
            for i in range(slots):
                if not active[b, i]:
                    free = i
                    break
            if free < 0:
                continue  # no slot: it waits outside the scene
            r = arrive_route[b, leg, n]
            gap, lead_v = math.inf, math.inf
            for e in range(ext_route.shape[1]):
                g = _leader(t, r, -1e-9, ext_route[b, e], ext_progress[b, e])
                if g < gap:
                    gap, lead_v = g, ext_speed[b, e]
            for j in range(slots):
                if active[b, j]:
                    g = _leader(t, r, -1e-9, route[b, j], progress[b, j])
                    if g < gap:
                        gap, lead_v = g, speed[b, j]
            v = min(arrive_desired[b, leg, n], lead_v)
            if gap < math.inf:
                room = gap - rules.length - idm.min_gap
                v = min(v, room / idm.time_headway)
                if room < 0.0 or v < 0.0:
                    continue  # the lane is full up to its start: it waits outside
            route[b, free], progress[b, free], speed[b, free] = r, 0.0, v
            desired[b, free] = arrive_desired[b, leg, n]
            yields[b, free] = arrive_yields[b, leg, n]
            active[b, free], waited[b, free], accel[b, free] = True, 0.0, 0.0
            entered[b, leg] = n + 1
        next_arrival[b] = _soonest_arrival(arrive_time, entered, b)


@jit
def _soonest_arrival(arrive_time: FloatArray, entered: IntArray, b: int) -> float:
    """The soonest time a vehicle is due to enter scene ``b`` [s] (``inf``: none left): the
    earliest of every leg's next scheduled arrival (one that has not found room yet stays
    due)."""
    soonest = math.inf
    for leg in range(arrive_time.shape[1]):
        n = entered[b, leg]
        if n < arrive_time.shape[2]:
            soonest = min(soonest, arrive_time[b, leg, n])
    return soonest
