"""The left turn among many vehicles (``safeswitch/LeftTurnTraffic-v0``): the paper's scene plus
streams on every approach (:mod:`safeswitch.sim.streams`).

:class:`LeftTurnTrafficTask` is the left-turn task with its hooks filled in: the paper's north
car stays as it is (plant, autopilot, never yields; its arrival set by the scenario), the other
vehicles follow the traffic rules and their own car-following, and

* the switching logic sees every vehicle whose route conflicts with the ego's
  (:class:`~safeswitch.leftturn.views.ConflictView` with one column per vehicle; the
  ``paper`` and ``certified`` logics are written over any number of conflicts), and the
  certificate beats the vehicles still to come (:meth:`LeftTurnTrafficTask.phantoms`);
* a collision with any vehicle ends the episode; collisions among the others are counted
  (:attr:`TrafficTaskState.npc_collisions`; they must stay 0);
* the observation is the paper's six values followed by the ``K`` nearest other vehicles
  (:data:`OBSERVED_FEATURES` each, nearest first, zeros and ``present = 0`` where there are
  fewer), or with ``traffic.observe: conflicts`` the ``K`` conflicting vehicles soonest to
  reach their conflict zone with the ego, in distances along the routes
  (:data:`CONFLICT_FEATURES`).

With ``traffic=None`` none of this exists: the environments build the plain
:class:`~safeswitch.leftturn.task.LeftTurnTask` (bit-identical to the paper's scene).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import jit, plain
from safeswitch.core.config import ConfigError
from safeswitch.leftturn.config import LeftTurnConfig, TrafficConfig
from safeswitch.leftturn.logics.certified import CertifiedSwitching, certified_logic
from safeswitch.leftturn.perception import Perception, Sighted
from safeswitch.leftturn.scenarios import Scenarios, counter_uniforms, named_scenarios
from safeswitch.leftturn.task import LeftTurnTask, TaskState
from safeswitch.leftturn.views import ConflictView, Phantoms, approaching
from safeswitch.sim.geometry import FloatArray
from safeswitch.sim.idm import IDMParams
from safeswitch.sim.network import MAIN_ROAD, RoadNetwork, turn_of
from safeswitch.sim.params import GRAVITY
from safeswitch.sim.road import LEG_DIRECTIONS
from safeswitch.sim.streams import (
    Arrivals,
    ArrivalSchedule,
    Drivers,
    Externals,
    RightOfWay,
    StreamConstants,
    TrafficState,
    network_tables,
    npc_separations,
    place,
    spawn_entry,
    traffic_tick_entry,
)
from safeswitch.sim.world import WorldState

BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

#: The fields of a :class:`TrafficState` that :func:`traffic_tick` writes whole (every slot):
#: the next tick's state needs no copy of them.
_TICK_WRITES = ("progress", "speed", "waited", "accel")
#: The ego's top speed as the other drivers estimate its earliest arrival [m/s].
EGO_TOP_SPEED = 15.0
#: Per observed vehicle: present (1/0), x [m], y [m], speed [m/s], heading cos, heading sin.
OBSERVED_FEATURES = ("present", "x", "y", "speed", "cos_yaw", "sin_yaw")

#: Per observed vehicle with ``traffic.observe: conflicts`` (distances along the routes, zones
#: with the certified margin, negative once inside): present (1/0), the vehicle's distance to
#: its conflict zone with the ego [m] and to the zone's end [m], its speed [m/s], the ego's
#: distance to its own zone with the vehicle [m] and to that zone's end [m].
CONFLICT_FEATURES = ("present", "to_zone", "to_zone_end", "speed", "ego_to_zone", "ego_to_zone_end")
#: With ``traffic.observe: margins``: :data:`CONFLICT_FEATURES`, then what the certified filter
#: reckons for the vehicle: the earliest it can enter its zone within the filter's assumptions
#: [s] and the certificate's slack against it [s] (that time less the filter's margin and the
#: clear backup's time for the ego to leave its own zone from now; both capped at
#: :data:`MARGIN_CAP_S`).
MARGIN_FEATURES = (*CONFLICT_FEATURES, "arrival_s", "slack_s")
#: The cap on :data:`MARGIN_FEATURES`' times [s].
MARGIN_CAP_S = 30.0
#: With ``traffic.observe: backups``: :data:`MARGIN_FEATURES`, then the stop backup's room before
#: the ego's zone with the vehicle [m]: the distance to its entry as the certificate counts it
#: less the full brake's stopping distance from the current speed and pedals, so negative once
#: braking now would not stop before it (capped at :data:`ROOM_CAP_M`). Of the two backups the
#: margins show only the clear one's; this is how long the ego may keep its speed before the
#: filter would have to brake (the pedals' lag is not otherwise in the observation).
BACKUP_FEATURES = (*MARGIN_FEATURES, "stop_room_m")
#: The cap on :data:`BACKUP_FEATURES`' room [m].
ROOM_CAP_M = 250.0
#: The features per observed vehicle of each ``traffic.observe``.
FEATURES = {"nearest": OBSERVED_FEATURES, "conflicts": CONFLICT_FEATURES,
            "margins": MARGIN_FEATURES, "backups": BACKUP_FEATURES}  # fmt: skip
#: The ``traffic.observe`` values in conflict coordinates.
_CONFLICT_OBSERVATIONS = ("conflicts", "margins", "backups")
#: Candidates drawn per approach before the nearest ``max_vehicles`` are kept.
_PER_LEG = 8
#: Uniforms per candidate: headway, turn, desired speed, yielding.
_DRAWS = 4


@dataclass
class TrafficScenarios(Scenarios):
    """The paper's scenario parameters plus the other vehicles' initial placement.

    Attributes:
        traffic: The other vehicles at the start ``[B, N]``.
    """

    traffic: TrafficState


@dataclass
class TrafficTaskState(TaskState):
    """:class:`TaskState` plus the other vehicles.

    Attributes:
        traffic: The other vehicles ``[B, N]``.
        npc_collisions: Pairs of other vehicles that overlapped, summed over the episode ``[B]``.
        ghost_ego: The others do not see the ego: they neither give way to it nor follow it
            ``[B]`` (:meth:`LeftTurnTrafficTask.initial_without_ego`).
    """

    traffic: TrafficState
    npc_collisions: NDArray[np.int64]
    ghost_ego: BoolArray


class LeftTurnTrafficTask(LeftTurnTask):
    """The left-turn task in traffic (see the module docstring).

    Args:
        config: The task's configuration.
        traffic: The traffic.
    """

    def __init__(self, config: LeftTurnConfig, traffic: TrafficConfig) -> None:
        if config.episode.go_model is not None:
            raise ConfigError(
                f"episode.go_model={config.episode.go_model!r} is the single-car scene's go "
                "predictor; in traffic set traffic.go_model (a predictor learned in traffic)"
            )
        super().__init__(config)
        self.traffic = traffic
        footprint = (config.vehicle.length, config.vehicle.width)
        #: The movements with the paper logic's conflict margin, and with the certified one's.
        self.network = RoadNetwork(config.geometry, footprint, config.episode.conflict_margin_m)
        self.cert_network = RoadNetwork(config.geometry, footprint, config.certified.zone_margin_m)
        self.tables = network_tables(
            self.network, config.vehicle.friction_coefficient * GRAVITY,
            IDMParams().comfortable_decel,
        )  # fmt: skip
        self.ego_route = self.network.index("south", "west")
        self.north_route = self.network.index("north", "south")
        self.idm = IDMParams()
        self.rules = RightOfWay(
            gap_time=1.0, go_accel=1.0, stop_buffer=0.5, ego_accel=3.0, ego_rank=1,
            length=config.vehicle.length, patience=traffic.patience_s, slow_speed=1.0,
            look_ahead=60.0,
        )  # fmt: skip
        self._ext_is_ego = np.array([True, False])
        dt = config.episode.dt
        #: Ticks between two decisions of a driver (``traffic.action_step_s``).
        self._action_ticks = round(traffic.action_step_s / dt)
        if self._action_ticks < 1 or abs(self._action_ticks * dt - traffic.action_step_s) > 1e-9:
            raise ConfigError(
                f"traffic.action_step_s={traffic.action_step_s!r} must be a whole number of "
                f"ticks of episode.dt={dt!r}"
            )
        #: Where a vehicle leaves the scene, per movement [m].
        self.exit_at = np.minimum(
            self.network.box_exits + traffic.exit_distance_m, self.network.lengths - 1.0
        )
        #: What the compiled streams read that stays fixed (plain tuples at their entry, see
        #: :func:`~safeswitch.core.arrays.plain`).
        self._streams = plain(StreamConstants(
            self.tables, self.rules, self.idm.kernel, config.episode.dt, self.exit_at
        ))  # fmt: skip
        n = self.north_conflict
        #: What the compiled conflict view reads that stays fixed (plain at its entry).
        self._conflict_tables = plain(ConflictTables(
            self.ego_route,
            np.ascontiguousarray(np.stack([self.network.conflicts, self.cert_network.conflicts])),
            _zone_middles(self.network),
            np.array([n.ego_zone, n.ego_cert_zone, n.north_zone, n.north_cert_zone]),
            np.array([n.ego_point, n.north_point]), n.approach_distance,
        ))  # fmt: skip
        #: Per movement, its conflict point and its zone's exit (paper margin) with the ego's
        #: route, on its own route [m] — for a movement that does not cross the ego's, where it
        #: enters its first conflict zone and where it leaves the junction: what the sensor's
        #: sight distance and adversarial errors are measured from.
        crossing = self.network.conflicts[:, self.ego_route]
        middles = _zone_middles(self.network)[:, self.ego_route]
        self._slot_point = np.where(np.isnan(middles), self.tables.zones_from, middles)
        self._slot_exit = np.where(np.isnan(crossing[:, 1]), self.tables.box_exits,
                                   crossing[:, 1])  # fmt: skip
        low: list[float]
        high: list[float]
        if traffic.observe in _CONFLICT_OBSERVATIONS:
            low, high = [0, -50, -50, 0, -250, -250], [1, 250, 250, 60, 250, 250]
            if traffic.observe != "conflicts":
                low, high = [*low, 0, -MARGIN_CAP_S], [*high, MARGIN_CAP_S, MARGIN_CAP_S]
            if traffic.observe == "backups":
                low, high = [*low, -ROOM_CAP_M], [*high, ROOM_CAP_M]
        else:
            low, high = [0, -150, -150, 0, -1, -1], [1, 150, 150, 60, 1, 1]
        self._observed_low = np.tile(np.array(low, dtype=np.float32), traffic.observed)
        self._observed_high = np.tile(np.array(high, dtype=np.float32), traffic.observed)

    @cached_property
    def _margins(self) -> CertifiedSwitching | None:
        """The certified filter whose reckoning ``observe: margins`` or ``backups`` shows,
        whatever logic the task runs (the observation belongs to the policy), built from the
        finished scene."""
        return certified_logic(self) if self.traffic.observe in ("margins", "backups") else None

    # -- scenarios and the start ------------------------------------------------------------

    def draw_scenarios(
        self, seed: int, env_ids: NDArray[np.int64], episodes: NDArray[np.int64]
    ) -> TrafficScenarios:
        base = super().draw_scenarios(seed, env_ids, episodes)
        return self.with_traffic(base, seed, env_ids, episodes)

    def named(self, name: str, batch: int, seed: int = 0) -> TrafficScenarios:
        """A named scenario of the paper with traffic drawn around it (from ``seed``)."""
        ids = np.arange(batch)
        return self.with_traffic(named_scenarios(name, batch), seed, ids, np.zeros_like(ids))

    @property
    def arrivals_per_leg(self) -> int:
        """``M``: scheduled arrivals per approach, enough for the densest flow over the
        horizon with a wide margin (the mean plus six standard deviations, plus four)."""
        flow = max(self.traffic.main_flow_veh_h[1], self.traffic.minor_flow_veh_h[1]) / 3600.0
        mean = flow * self.config.episode.horizon_s
        return math.ceil(mean + 6.0 * math.sqrt(mean) + 4.0)

    def with_traffic(
        self, base: Scenarios, seed: int, env_ids: NDArray[np.int64], episodes: NDArray[np.int64]
    ) -> TrafficScenarios:
        """The paper's scenario parameters ``base`` with traffic drawn around them (row ``i``
        a pure function of ``(seed, env_ids[i], episodes[i])``)."""
        legs = len(LEG_DIRECTIONS)
        start = counter_uniforms(seed ^ 0x5AFE, env_ids, episodes, 3 + legs * _PER_LEG * _DRAWS)
        later = counter_uniforms(
            seed ^ 0xA771, env_ids, episodes, legs * self.arrivals_per_leg * _DRAWS
        )
        return TrafficScenarios(
            base.ego_start_distance, base.ego_speed, base.north_speed, base.arrival_offset,
            traffic=self._place_streams(base, start, later, self.traffic.max_vehicles),
        )  # fmt: skip

    def _place_streams(
        self, base: Scenarios, u: FloatArray, later: FloatArray, slots: int
    ) -> TrafficState:
        """Poisson streams on every approach: the vehicles on the approaches at the start (the
        nearest ``slots`` kept) and the schedule of those still to come."""
        t, net, g = self.traffic, self.network, self.config.geometry
        batch = u.shape[0]
        approach = g.approach_length
        v_lim = self.config.controllers.speed_limit
        length = self.config.vehicle.length
        main = t.main_flow_veh_h[0] + u[:, 0] * (t.main_flow_veh_h[1] - t.main_flow_veh_h[0])
        minor = t.minor_flow_veh_h[0] + u[:, 1] * (t.minor_flow_veh_h[1] - t.minor_flow_veh_h[0])
        rude = t.non_yielding_share[0] + u[:, 2] * np.ptp(t.non_yielding_share)
        # Where each approach's stream starts, measured from its stop line outwards [m].
        ego_to_line = base.ego_start_distance - (self.conflict.s_point_a - approach)
        north_to_line = base.north_start_distance(v_lim) - (self.conflict.s_point_b - approach)
        legs = list(LEG_DIRECTIONS)
        routes = np.array([[net.index(leg, d) for d in _destinations(leg)] for leg in legs])
        cdf = np.cumsum(t.turn_shares)

        def driver(draws: FloatArray, li: int) -> tuple[IntArray, FloatArray, BoolArray]:
            """Route, desired speed and yielding of drivers from their uniforms ``[..., 4]``."""
            turn = np.minimum(np.searchsorted(cdf, draws[..., 1], side="right"), 2)
            v0 = (t.speed_kmh[0] + draws[..., 2] * np.ptp(t.speed_kmh)) / 3.6
            return (
                routes[li][turn],
                v0,
                draws[..., 3] >= rude.reshape((-1,) + (1,) * (draws.ndim - 2)),
            )

        candidates = len(legs) * _PER_LEG
        route = np.zeros((batch, candidates), dtype=np.int64)
        distance = np.full((batch, candidates), np.inf)
        desired = np.zeros((batch, candidates))
        yields = np.zeros((batch, candidates), dtype=bool)
        most = self.arrivals_per_leg
        schedule = ArrivalSchedule(
            time=np.full((batch, len(legs), most), np.inf),
            route=np.zeros((batch, len(legs), most), dtype=np.int64),
            desired=np.zeros((batch, len(legs), most)),
            yields=np.zeros((batch, len(legs), most), dtype=bool),
        )
        for li, leg in enumerate(legs):
            flow = main if leg in MAIN_ROAD else minor
            mean_gap = np.maximum(3600.0 / np.maximum(flow, 1e-9) - t.min_headway_s, 0.1)
            for k in range(_PER_LEG):
                col = li * _PER_LEG + k
                draws = u[:, 3 + col * _DRAWS : 3 + (col + 1) * _DRAWS]
                r, v0, y = driver(draws[:, None, :], li)
                headway = t.min_headway_s - mean_gap * np.log1p(-draws[:, 0])
                spacing = length + v0[:, 0] * headway
                if k == 0:
                    if leg == "north":  # behind the paper's north car
                        d = north_to_line + spacing
                    elif leg == "south":  # behind the ego
                        d = ego_to_line + spacing
                    else:  # room to stop at the give-way line
                        d = v0[:, 0] ** 2 / 4.0 + 5.0 + draws[:, 0] * spacing
                else:
                    d = distance[:, col - 1] + spacing
                distance[:, col] = np.where(flow > 0, d, np.inf)
                route[:, col], desired[:, col], yields[:, col] = r[:, 0], v0[:, 0], y[:, 0]
            # Later arrivals at the start of the approach: the first after an exponential time
            # (a Poisson stream has no memory), then minimum headway plus exponential gaps.
            draws = later[:, li * most * _DRAWS : (li + 1) * most * _DRAWS].reshape(
                batch, most, _DRAWS
            )
            gaps = -mean_gap[:, None] * np.log1p(-draws[..., 0])
            gaps[:, 1:] += t.min_headway_s
            times = np.cumsum(gaps, axis=1)
            schedule.time[:, li] = np.where(flow[:, None] > 0, times, np.inf)
            schedule.route[:, li], schedule.desired[:, li], schedule.yields[:, li] = driver(
                draws, li
            )
        distance = np.where(distance <= approach - 2.0, distance, np.inf)
        keep = np.argsort(distance, axis=1, kind="stable")[:, :slots]
        rows = np.arange(batch)[:, None]
        d = distance[rows, keep]
        active = np.isfinite(d)
        state = TrafficState(
            route=route[rows, keep],
            progress=np.where(active, approach - np.where(active, d, 0.0), 0.0),
            speed=np.where(active, desired[rows, keep], 0.0),
            desired=desired[rows, keep],
            yields=yields[rows, keep],
            active=active,
            waited=np.zeros((batch, slots)),
            x=np.zeros((batch, slots)),
            y=np.zeros((batch, slots)),
            cos_yaw=np.ones((batch, slots)),
            sin_yaw=np.zeros((batch, slots)),
            accel=np.zeros((batch, slots)),
            schedule=schedule,
            entered=np.zeros((batch, len(legs)), dtype=np.int64),
            next_arrival=schedule.time[:, :, 0].min(axis=1),
        )
        place(self.tables, state)
        return state

    def initial(self, scenarios: Scenarios) -> TrafficTaskState:
        if not isinstance(scenarios, TrafficScenarios):
            raise TypeError("a traffic task starts from TrafficScenarios (draw_scenarios)")
        base = super().initial(scenarios)
        batch = base.batch_size
        fields = {f: getattr(base, f) for f in base.__dataclass_fields__}
        return TrafficTaskState(
            **fields, traffic=scenarios.traffic.copy(schedule=True),
            npc_collisions=np.zeros(batch, dtype=np.int64),
            ghost_ego=np.zeros(batch, dtype=np.bool_),
        )  # fmt: skip

    def others_at_start(self, scenarios: Scenarios) -> TrafficState:
        assert isinstance(scenarios, TrafficScenarios)
        return scenarios.traffic

    def sighted(self, world: WorldState, others: Any, before: TaskState | None) -> Sighted:
        """The north car (column 0), then every slot: a slot's vehicle is new when the slot was
        empty, or holds another movement or a vehicle farther back than before (the one that
        left, replaced within the tick)."""
        north = super().sighted(world, None, before)
        traffic: TrafficState = others[0] if isinstance(others, tuple) else others
        route, active = traffic.route, traffic.active
        fresh = np.zeros_like(active)
        if before is not None:
            assert isinstance(before, TrafficTaskState)
            old = before.traffic
            replaced = (old.route != route) | (traffic.progress < old.progress)
            fresh = active & (~old.active | replaced)
        point = self._slot_point[route]
        exit_ = self._slot_exit[route]
        return Sighted(
            np.concatenate([north.progress, traffic.progress], axis=1),
            np.concatenate([north.speed, traffic.speed], axis=1),
            np.concatenate([north.exists, active], axis=1),
            np.concatenate([north.fresh, fresh], axis=1),
            np.concatenate([north.point, point], axis=1),
            np.concatenate([north.exit, exit_], axis=1),
            np.concatenate([north.bounded, np.zeros_like(active)], axis=1),
        )

    # -- the hooks ------------------------------------------------------------------------------

    def view(
        self, state: TaskState, window: BoolArray | None = None, truth: bool = False
    ) -> ConflictView:
        """Every conflict of the ego: column 0 the north car, then every slot (``present``
        false where the slot is empty or its route does not cross the ego's), as the ego
        perceives them (``truth``: as they are)."""
        assert isinstance(state, TrafficTaskState)
        tr = state.traffic
        batch, slots = tr.route.shape
        c = slots + 1
        e = np.empty
        out = ConflictArrays(
            e((batch, c), dtype=bool), e((batch, c), dtype=bool), e((4, batch, c, 2)),
            e((2, batch, c)), e((3, batch, c)),
        )  # fmt: skip
        present, inside, zones, points, other = out
        v, progress, seen = state.world.vehicles, state.world.progress, state.perception
        north = (np.ascontiguousarray(progress[:, 1]), np.ascontiguousarray(v.speed[:, 1]),
                 state.scenarios.north_speed)  # fmt: skip
        drivers = Drivers.of(tr)
        lead, lag, speed_high = np.zeros((batch, c)), np.zeros((batch, c)), None
        if seen is not None and not truth:
            # What the ego sees: each vehicle once sighted, at its point estimate (a vehicle
            # not yet seen is left to the phantoms).
            north = (
                np.ascontiguousarray(seen.progress[:, 0]),
                np.ascontiguousarray(seen.speed[:, 0]),
                state.scenarios.north_speed,
            )
            drivers = drivers._replace(
                progress=np.ascontiguousarray(seen.progress[:, 1:]),
                speed=np.ascontiguousarray(seen.speed[:, 1:]),
                active=tr.active & seen.ever[:, 1:],
            )
            lead, lag, speed_high = Perception.uncertainty(seen)
        _conflict_view_entry(self._conflict_tables, tuple(drivers),
                             np.ascontiguousarray(progress[:, 0]), north, tuple(out))  # fmt: skip
        return ConflictView(
            ego_progress=progress[:, 0], ego_speed=v.speed[:, 0], ego_throttle=v.throttle[:, 0],
            ego_brake=v.brake[:, 0], present=present, window=inside, ego_point=points[0],
            ego_zone=zones[0], ego_cert_zone=zones[1], other_progress=other[0],
            other_point=points[1], other_zone=zones[2], other_cert_zone=zones[3],
            other_speed=other[1], other_top=other[2], other_lead=lead, other_lag=lag,
            other_speed_high=other[1] if speed_high is None else speed_high,
        )  # fmt: skip

    def crossing_zones(self) -> FloatArray:
        """The ego's conflict zone with each movement, on its route [m] ``[R, 2]`` (``inf``
        where a movement does not cross the ego's)."""
        return np.ascontiguousarray(self.network.conflicts[self.ego_route])

    def initial_without_ego(self, scenarios: Scenarios) -> TrafficTaskState:
        """The initial state with the ego a ghost: the others neither give way to it nor
        follow it (its arc length is put infinitely far behind in what they see)."""
        state = self.initial(scenarios)
        return replace(state, ghost_ego=np.ones(state.batch_size, dtype=np.bool_))

    @cached_property
    def _zones_with_ego(self) -> FloatArray:
        """Each movement's own conflict zone with the ego's route, on its route [m] ``[R, 2]``."""
        return np.ascontiguousarray(self.network.conflicts[:, self.ego_route])

    def mark_occupied(self, state: TaskState, tick: int, occupied: BoolArray) -> None:
        assert isinstance(state, TrafficTaskState)
        tr = state.traffic
        _occupied(tr.route, tr.progress, tr.active, self._zones_with_ego, tick, occupied)

    def phantoms(self) -> Phantoms:
        """Every movement whose route crosses the ego's, with the certified margin: the ego's
        zone with it ``[P, 2]`` and the entry of its own zone, from the start of its approach
        [m] ``[P]`` (a vehicle not yet in the scene can appear there at any moment)."""
        cert = self.cert_network.conflicts
        crossing = np.flatnonzero(np.isfinite(cert[self.ego_route, :, 0]))
        entry = cert[crossing, self.ego_route, 0]
        if self.perception is not None and self.config.certified.perception == "declared":
            # A vehicle not yet seen may be beyond the sight edge, or have been in the scene
            # unseen for the latency and a miss (see Perception.phantom_entry).
            point = self._slot_point[crossing]
            entry = self.perception.phantom_entry(entry, point, entry)
        return Phantoms(cert[self.ego_route, crossing], entry)

    def advance_others(
        self, state: TaskState, new_world: WorldState, separation: FloatArray
    ) -> tuple[Any, FloatArray]:
        assert isinstance(state, TrafficTaskState)
        tr = state.traffic
        v, world = state.world.vehicles, state.world
        batch = tr.route.shape[0]
        externals = np.empty((batch, 2), dtype=np.int64)
        externals[:, 0], externals[:, 1] = self.ego_route, self.north_route
        top = np.empty((batch, 2))
        top[:, 0] = EGO_TOP_SPEED
        top[:, 1] = state.scenarios.north_speed
        new = tr.copy(overwritten=_TICK_WRITES)
        ext_progress = _ghost(np.ascontiguousarray(world.progress), state.ghost_ego)
        ext = Externals(externals, ext_progress, np.ascontiguousarray(v.speed), top,
                        self._ext_is_ego)  # fmt: skip
        decide = state.tick % self._action_ticks == 0
        drivers = tuple(Drivers.of(new))  # written by the tick, then by spawn, in place
        traffic_tick_entry(self._streams, tuple(Drivers.of(tr)), tuple(ext), decide, drivers)
        now = (state.tick + 1).astype(np.float64) * self.config.episode.dt
        moved = ext._replace(
            progress=_ghost(np.ascontiguousarray(new_world.progress), state.ghost_ego),
            speed=np.ascontiguousarray(new_world.vehicles.speed),
        )
        spawn_entry(self._streams, now, tuple(Arrivals.of(tr.schedule)), new.entered,
                    new.next_arrival, drivers, tuple(moved))  # fmt: skip
        place(self.tables, new)
        return self.with_separations(state, new, new_world, separation)

    def with_separations(
        self, state: TrafficTaskState, new: TrafficState, new_world: WorldState,
        separation: FloatArray,
    ) -> tuple[Any, FloatArray]:  # fmt: skip
        """What :meth:`advance_others` returns for the others' new state ``new`` (poses
        placed): it with their collisions among themselves added up, and the ego's separation
        from the nearest of them or ``separation`` (the north car's) ``[B]``."""
        nv, p = new_world.vehicles, self.config.vehicle
        batch = new.route.shape[0]
        gap = np.empty(batch)
        collisions = np.empty(batch, dtype=np.int64)
        npc_separations(
            new.x, new.y, new.cos_yaw, new.sin_yaw, new.active, p.length, p.width,
            np.ascontiguousarray(nv.x[:, 0]), np.ascontiguousarray(nv.y[:, 0]),
            np.ascontiguousarray(nv.cos_yaw[:, 0]), np.ascontiguousarray(nv.sin_yaw[:, 0]),
            gap, collisions,
        )  # fmt: skip
        others = (new, state.npc_collisions + collisions, state.ghost_ego)
        return others, np.minimum(separation, gap)

    def make_state(self, base: TaskState, others: Any) -> TrafficTaskState:
        traffic, collisions, ghost = others
        fields = {f: getattr(base, f) for f in base.__dataclass_fields__}
        return TrafficTaskState(**fields, traffic=traffic, npc_collisions=collisions,
                                ghost_ego=ghost)  # fmt: skip

    def extend_observation(
        self, state: TaskState, observation: NDArray[np.float32]
    ) -> NDArray[np.float32]:
        assert isinstance(state, TrafficTaskState)
        k, observe = self.traffic.observed, self.traffic.observe
        width = len(FEATURES[observe])
        out = np.zeros((observation.shape[0], 6 + width * k), dtype=np.float32)
        out[:, :6] = observation
        if observe in _CONFLICT_OBSERVATIONS:
            v = self.view(state)
            extra = np.zeros((*v.present.shape, width - len(CONFLICT_FEATURES)))
            if self._margins is not None:
                arrival, slack, room = self._margins.margins(v)
                extra[..., 0] = np.minimum(arrival, MARGIN_CAP_S)
                extra[..., 1] = np.clip(slack, -MARGIN_CAP_S, MARGIN_CAP_S)
                if observe == "backups":
                    extra[..., 2] = np.clip(room, -ROOM_CAP_M, ROOM_CAP_M)
            _soonest_conflicts(
                v.present, v.ego_progress, v.ego_cert_zone, v.other_progress,
                v.other_cert_zone, v.other_speed, extra, k, out,
            )  # fmt: skip
            return out
        tr, seen = state.traffic, state.perception
        if seen is not None:  # the vehicles where the ego sees them, posed on their routes
            zeros = np.zeros_like(tr.x)
            tr = replace(
                tr, progress=np.ascontiguousarray(seen.progress[:, 1:]),
                speed=np.ascontiguousarray(seen.speed[:, 1:]), active=tr.active & seen.ever[:, 1:],
                x=zeros, y=zeros.copy(), cos_yaw=zeros.copy(), sin_yaw=zeros.copy(),
            )  # fmt: skip
            place(self.tables, tr)
        _nearest(
            observation[:, 0].astype(np.float64), observation[:, 1].astype(np.float64),
            tr.x, tr.y, tr.speed, tr.cos_yaw, tr.sin_yaw, tr.active, k, out,
        )  # fmt: skip
        return out

    @property
    def scene_observation_bounds(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        low, high = super().scene_observation_bounds
        return np.concatenate([low, self._observed_low]), np.concatenate(
            [high, self._observed_high]
        )

    @property
    def go_model_setting(self) -> tuple[str, str | None]:
        """In traffic the go predictor is ``traffic.go_model``'s (it is learned on scenes with
        traffic); ``episode.go_model``, the single-car scene's, is refused when the task is
        built."""
        return "traffic.go_model", self.traffic.go_model


def _destinations(origin: str) -> tuple[str, str, str]:
    """The destinations of ``origin`` for (straight, right, left)."""
    out = {turn_of(origin, d): d for d in LEG_DIRECTIONS if d != origin}
    return out["straight"], out["right"], out["left"]


def _zone_middles(network: RoadNetwork) -> FloatArray:
    """Per ordered pair of movements, the middle of the first's conflict zone [m] (NaN: none):
    the conflict point the time-to-reach of the paper's rule is measured to."""
    z = network.conflicts
    return 0.5 * (z[..., 0] + z[..., 1])


@jit
def _take_smallest(values: FloatArray) -> int:
    """The index of the smallest finite value, then set to ``inf`` (taken); -1 if none is
    left. The first of equal values wins."""
    best, pick = math.inf, -1
    for i in range(values.shape[0]):
        if values[i] < best:
            best, pick = values[i], i
    if pick >= 0:
        values[pick] = math.inf
    return pick


@jit
def _nearest(
    ego_x: FloatArray, ego_y: FloatArray, x: FloatArray, y: FloatArray, speed: FloatArray,
    cos_yaw: FloatArray, sin_yaw: FloatArray, active: BoolArray, k: int,
    out: NDArray[np.float32],
) -> None:  # fmt: skip
    """The ``k`` nearest active other vehicles of every scene into ``out[:, 6:]``."""
    slots = x.shape[1]
    distance = np.empty(slots)  # squared; inf for an empty slot or one already taken
    for b in range(x.shape[0]):
        for i in range(slots):
            distance[i] = (
                (x[b, i] - ego_x[b]) ** 2 + (y[b, i] - ego_y[b]) ** 2 if active[b, i] else math.inf
            )
        for n in range(k):
            pick = _take_smallest(distance)
            if pick < 0:
                break
            base = 6 + 6 * n
            out[b, base] = 1.0
            out[b, base + 1] = x[b, pick]
            out[b, base + 2] = y[b, pick]
            out[b, base + 3] = speed[b, pick]
            out[b, base + 4] = cos_yaw[b, pick]
            out[b, base + 5] = sin_yaw[b, pick]


@jit
def _soonest_conflicts(
    present: BoolArray, ego_progress: FloatArray, ego_zone: FloatArray,
    other_progress: FloatArray, other_zone: FloatArray, other_speed: FloatArray,
    extra: FloatArray, k: int, out: NDArray[np.float32],
) -> None:  # fmt: skip
    """The ``k`` conflicting vehicles of every scene that neither they nor the ego have got
    past, soonest to reach their zone first (distance over speed, the speed floored at
    1 m/s), into ``out[:, 6:]`` (:data:`CONFLICT_FEATURES`, then the vehicle's ``extra``
    values ``[B, C, E]``)."""
    columns = present.shape[1]
    width = 6 + extra.shape[2]
    soon = np.empty(columns)  # inf: not a conflict, or one already taken
    for b in range(present.shape[0]):
        s_e = ego_progress[b]
        for j in range(columns):
            soon[j] = math.inf
            if (
                present[b, j]
                and other_progress[b, j] <= other_zone[b, j, 1]
                and (s_e <= ego_zone[b, j, 1])
            ):
                ahead = max(other_zone[b, j, 0] - other_progress[b, j], 0.0)
                soon[j] = ahead / max(other_speed[b, j], 1.0)
        for n in range(k):
            pick = _take_smallest(soon)
            if pick < 0:
                break
            base = 6 + width * n
            out[b, base] = 1.0
            out[b, base + 1] = other_zone[b, pick, 0] - other_progress[b, pick]
            out[b, base + 2] = other_zone[b, pick, 1] - other_progress[b, pick]
            out[b, base + 3] = other_speed[b, pick]
            out[b, base + 4] = ego_zone[b, pick, 0] - s_e
            out[b, base + 5] = ego_zone[b, pick, 1] - s_e
            for e in range(extra.shape[2]):
                out[b, base + 6 + e] = extra[b, pick, e]


class ConflictTables(NamedTuple):
    """What the compiled conflict view reads that stays fixed for a task.

    Attributes:
        ego_route: The ego's movement.
        pair_zones: Per ordered pair of movements, the first's zone, paper and certified
            margins ``[2, R, R, 2]``.
        point: Per ordered pair, the middle of the first's zone ``[R, R]``.
        north_zones: The north car's conflict: the ego's zone, its certified zone, the north
            car's, its certified one ``[4, 2]``.
        north_points: The conflict point on the ego's and on the north car's route ``[2]``.
        approach: Algorithm 1's "at the intersection" distance [m].
    """

    ego_route: int
    pair_zones: FloatArray
    point: FloatArray
    north_zones: FloatArray
    north_points: FloatArray
    approach: float


class ConflictArrays(NamedTuple):
    """The arrays of a :class:`~safeswitch.leftturn.views.ConflictView` the compiled view
    fills: ``present`` and ``window`` ``[B, C]``, ``zones`` (the ego's, its certified, the
    other's, its certified) ``[4, B, C, 2]``, ``points`` (the ego's, the other's)
    ``[2, B, C]``, ``other`` (progress, speed, top speed) ``[3, B, C]``."""

    present: BoolArray
    window: BoolArray
    zones: FloatArray
    points: FloatArray
    other: FloatArray


@jit
def _conflict_view_entry(
    c: tuple[Any, ...], drivers: tuple[Any, ...], ego_progress: FloatArray,
    north: tuple[FloatArray, FloatArray, FloatArray], out: tuple[Any, ...],
) -> None:  # fmt: skip
    """:func:`_conflict_view` called with plain tuples, named again here."""
    _conflict_view(ConflictTables(*c), Drivers(*drivers), ego_progress, north,
                   ConflictArrays(*out))  # fmt: skip


@jit
def _conflict_view(
    c: ConflictTables, drivers: Drivers, ego_progress: FloatArray,
    north: tuple[FloatArray, FloatArray, FloatArray], out: ConflictArrays,
) -> None:  # fmt: skip
    """Fill the arrays of a :class:`~safeswitch.leftturn.views.ConflictView`: column 0 the
    north car (``north``: its progress, speed and top speed ``[B]``), then every slot
    (``present`` false where the slot is empty or its route does not cross the ego's);
    ``window``: Algorithm 1's While condition of each pair (both within ``approach`` of their
    conflict point, neither past its zone)."""
    # The tuples' arrays taken out once (see jit).
    ego_route, pair_zones, point, approach = c.ego_route, c.pair_zones, c.point, c.approach
    north_zones, north_points = c.north_zones, c.north_points
    route, active, progress, speed, desired = (
        drivers.route, drivers.active, drivers.progress, drivers.speed, drivers.desired,
    )  # fmt: skip
    north_progress, north_speed, north_top = north
    present, window, zones, points, other = out
    for b in range(route.shape[0]):
        present[b, 0] = True
        for m in range(4):
            zones[m, b, 0, 0], zones[m, b, 0, 1] = north_zones[m, 0], north_zones[m, 1]
        points[0, b, 0], points[1, b, 0] = north_points[0], north_points[1]
        other[0, b, 0], other[1, b, 0], other[2, b, 0] = (
            north_progress[b], north_speed[b], north_top[b],
        )  # fmt: skip
        for i in range(route.shape[1]):
            r, k = route[b, i], i + 1
            for m in range(2):
                for e in range(2):
                    zones[m, b, k, e] = pair_zones[m, ego_route, r, e]
                    zones[m + 2, b, k, e] = pair_zones[m, r, ego_route, e]
            present[b, k] = active[b, i] and not math.isnan(zones[0, b, k, 0])
            points[0, b, k], points[1, b, k] = point[ego_route, r], point[r, ego_route]
            other[0, b, k], other[1, b, k], other[2, b, k] = (
                progress[b, i],
                speed[b, i],
                desired[b, i],
            )
        s_e = ego_progress[b]
        for k in range(present.shape[1]):
            s_k = other[0, b, k]
            window[b, k] = (
                present[b, k]
                and approaching(s_e, points[0, b, k], zones[0, b, k, 1], approach)
                and approaching(s_k, points[1, b, k], zones[2, b, k, 1], approach)
            )


def _ghost(progress: FloatArray, ghost: BoolArray) -> FloatArray:
    """The plant's arc lengths with the ego's put infinitely far behind in the episodes where
    it is a ghost."""
    if not ghost.any():
        return progress
    out = progress.copy()
    out[ghost, 0] = -np.inf
    return out


@jit
def _occupied(
    route: NDArray[np.int64], progress: FloatArray, active: BoolArray, zones: FloatArray,
    tick: int, out: NDArray[np.bool_],
) -> None:  # fmt: skip
    """Mark ``out[b, r, tick]`` where an active vehicle on movement ``r`` is inside its zone
    (``zones[r]``; NaN: the movement does not cross the ego's)."""
    for b in range(route.shape[0]):
        for i in range(route.shape[1]):
            if active[b, i]:
                r = route[b, i]
                if zones[r, 0] <= progress[b, i] <= zones[r, 1]:
                    out[b, r, tick] = True
