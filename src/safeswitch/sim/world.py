"""A batch of scenes, each with several vehicles on their own routes, stepped together.

Vehicle arrays have shape ``[B, V]``: ``B`` independent scenes, ``V`` vehicles per scene (slot 0
is the ego). Every vehicle slot follows its own route; after each tick every vehicle is projected
onto its route (progress, lateral deviation, heading error), and the ego's footprint is checked
against every other vehicle's. The world knows nothing of controllers, rewards or learning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from safeswitch.core.arrays import flat, jit, plain
from safeswitch.sim.collision import separation
from safeswitch.sim.geometry import FloatArray, IntArray, Route, RouteSet, locate, wrap_angle
from safeswitch.sim.vehicle import (
    VehicleConstants,
    VehicleOutputs,
    VehicleParams,
    VehicleState,
    steady_state_throttle,
    store_tick,
    vehicle_constants,
    vehicle_tick,
)


@dataclass
class WorldState:
    """State of ``B`` scenes with ``V`` vehicles each.

    Attributes:
        vehicles: Vehicle states, arrays of shape ``[B, V]``.
        progress: Arc length of each vehicle along its route [m], ``[B, V]``.
        lateral: Signed lateral deviation from the route, positive left [m], ``[B, V]``.
        time: Simulated time since the scene started [s], ``[B]``.
    """

    vehicles: VehicleState
    progress: FloatArray
    lateral: FloatArray
    time: FloatArray


@dataclass
class World:
    """Static description of the scenes: routes per vehicle slot, vehicle parameters, tick.

    Args:
        routes: One route per vehicle slot (slot 0 is the ego).
        params: Vehicle parameters, shared by all vehicles.
        dt: Tick length [s].
    """

    routes: list[Route]
    params: VehicleParams = field(default_factory=VehicleParams)
    dt: float = 0.02

    def __post_init__(self) -> None:
        if not 0 < self.dt <= 0.1:
            raise ValueError(f"World.dt must be in (0, 0.1] s, got {self.dt!r}")
        self.route_set = RouteSet(self.routes)
        self.slots = np.arange(len(self.routes))
        #: Flat index of each slot's route in the route set's tables, ``[V]``.
        self.route_base = self.route_set.base_index(self.slots)  # broadcasts against [B, V]
        #: The vehicle model's constants for this world's parameters and tick.
        self.vehicle_constants = vehicle_constants(self.params, self.dt)
        routes = self.route_set
        #: What the compiled tick reads that stays fixed (plain tuples at its entry, see
        #: :func:`~safeswitch.core.arrays.plain`).
        self._tick_constants = plain(WorldConstants(
            self.vehicle_constants, routes.tables, routes.spacing, routes.size - 2,
            routes.WALK_STEPS, self.route_base, self.params.length, self.params.width,
        ))  # fmt: skip

    @property
    def num_vehicles(self) -> int:
        return len(self.routes)

    def place(self, progress: FloatArray, speed: FloatArray) -> WorldState:
        """Scenes with every vehicle on its route's centre line, aligned with it, cruising: its
        throttle actuator already at the position that holds its speed.

        Args:
            progress: Arc length of each vehicle along its route [m], ``[B, V]``.
            speed: Initial speeds [m/s], ``[B, V]``.
        """
        progress = np.asarray(progress, dtype=np.float64)
        slots = np.broadcast_to(self.slots, progress.shape)
        xy, yaw = self.route_set.pose_at(slots, progress)
        zeros = np.zeros(progress.shape)
        speed = np.broadcast_to(np.asarray(speed, dtype=np.float64), progress.shape).copy()
        throttle = np.where(speed > 0, steady_state_throttle(self.params, speed), 0.0)
        vehicles = VehicleState.at(xy[..., 0], xy[..., 1], yaw, speed, throttle)
        return WorldState(vehicles, progress.copy(), zeros.copy(), np.zeros(progress.shape[0]))

    def step(
        self, state: WorldState, throttle: FloatArray, brake: FloatArray, steer: FloatArray
    ) -> tuple[WorldState, VehicleOutputs, FloatArray]:
        """Advance every scene by one tick.

        Args:
            state: Current state (not modified).
            throttle: Commanded throttle per vehicle, ``[B, V]``.
            brake: Commanded brake per vehicle, ``[B, V]``.
            steer: Commanded steering per vehicle, ``[B, V]``.

        Returns:
            The next state, the vehicles' measured outputs and, per scene, the separation
            between the ego's footprint and the nearest other vehicle's [m], ``[B]``
            (``<= 0`` is a collision).
        """
        shape = state.progress.shape
        n = state.progress.size
        e = np.empty
        out = WorldOutputs(
            (e(n), e(n), e(n), e(n), e(n), e(n), e(n), e(n)), (e(n), e(n), e(n), e(n)), e(n),
            e(n), e(shape[0]),
        )  # fmt: skip
        v = state.vehicles
        _world_tick_entry(
            self._tick_constants,
            tuple(WorldInputs(
                (v.x, v.y, v.cos_yaw, v.sin_yaw, v.speed, v.throttle, v.brake, v.steer),
                flat(throttle, shape), flat(brake, shape), flat(steer, shape), state.progress,
            )),
            tuple(out),
        )  # fmt: skip
        vehicles = VehicleState(*(a.reshape(shape) for a in out.vehicles))
        new = WorldState(
            vehicles, out.progress.reshape(shape), out.lateral.reshape(shape),
            state.time + self.dt,
        )  # fmt: skip
        measured = VehicleOutputs(*(a.reshape(shape) for a in out.outputs))
        return new, measured, out.separation

    def ego_separation(self, vehicles: VehicleState) -> FloatArray:
        """Separation between the ego's footprint and the nearest other vehicle's [m], ``[B]``
        (what :meth:`step` reports, through the same :func:`nearest_gap`)."""
        p, v = self.params, vehicles
        scenes, slots = v.x.shape
        out = np.empty(scenes)
        _map_nearest_gap(
            flat(v.x, v.x.shape), flat(v.y, v.x.shape), flat(v.cos_yaw, v.x.shape),
            flat(v.sin_yaw, v.x.shape), slots, p.length, p.width, out,
        )  # fmt: skip
        return out


def preview_offsets(world: World, state: WorldState, lookahead: float) -> FloatArray:
    """Lateral offset of each vehicle's route point ``lookahead`` metres ahead, in the vehicle's
    frame [m], ``[B, V]`` (the lane keepers' error signal; see
    :meth:`~safeswitch.sim.geometry.RouteSet.preview_offset`)."""
    v = state.vehicles
    return world.route_set.preview_offset_axes(
        world.route_base, state.progress, v.x, v.y, v.cos_yaw, v.sin_yaw, lookahead
    )


def heading_errors(world: World, state: WorldState) -> FloatArray:
    """Each vehicle's heading minus its route's heading at its progress [rad], ``[B, V]``."""
    _, _, route_heading = world.route_set.pose_at_flat(world.route_base, state.progress)
    return wrap_angle(state.vehicles.yaw - route_heading)


class WorldConstants(NamedTuple):
    """What the compiled tick reads that stays fixed for a world.

    Attributes:
        vehicle: The vehicle model's constants.
        tables: The routes' waypoint tables (see :class:`~safeswitch.sim.geometry.RouteSet`).
        spacing: Waypoint spacing [m].
        k_max: Last waypoint segment index.
        walk_steps: Segments the route tracking may walk per tick.
        base: Each slot's route row in ``tables`` ``[V]``.
        length: Vehicle footprint length [m].
        width: Vehicle footprint width [m].
    """

    vehicle: VehicleConstants
    tables: FloatArray
    spacing: float
    k_max: int
    walk_steps: int
    base: IntArray
    length: float
    width: float


class WorldInputs(NamedTuple):
    """The state the compiled tick reads.

    Attributes:
        vehicles: The ``[B, V]`` fields of :class:`VehicleState`, in its order.
        throttle: Commanded throttle, flat ``[B·V]``.
        brake: Commanded brake, flat ``[B·V]``.
        steer: Commanded steering, flat ``[B·V]``.
        progress: Each vehicle's arc length along its route ``[B, V]`` [m].
    """

    vehicles: tuple[FloatArray, ...]
    throttle: FloatArray
    brake: FloatArray
    steer: FloatArray
    progress: FloatArray


class WorldOutputs(NamedTuple):
    """What the compiled tick writes (flat ``[B·V]`` unless noted).

    Attributes:
        vehicles: The new fields of :class:`VehicleState`, in its order.
        outputs: The fields of :class:`VehicleOutputs`, in its order.
        progress: The new arc lengths along the routes [m].
        lateral: The new signed lateral deviations [m].
        separation: Each scene's separation between the ego and its nearest other vehicle
            ``[B]`` [m].
    """

    vehicles: tuple[FloatArray, ...]
    outputs: tuple[FloatArray, ...]
    progress: FloatArray
    lateral: FloatArray
    separation: FloatArray


@jit
def named_world_constants(c: tuple[Any, ...]) -> WorldConstants:
    """The inverse of ``plain`` for :class:`WorldConstants` (in compiled code)."""
    return WorldConstants(VehicleConstants(*c[0]), c[1], c[2], c[3], c[4], c[5], c[6], c[7])


@jit
def _world_tick_entry(c: tuple[Any, ...], i: tuple[Any, ...], o: tuple[Any, ...]) -> None:
    """:func:`_world_tick` called with plain tuples, named again here."""
    _world_tick(named_world_constants(c), WorldInputs(*i), WorldOutputs(*o))


@jit
def _world_tick(c: WorldConstants, i: WorldInputs, o: WorldOutputs) -> None:
    """:meth:`World.step` in one loop: every vehicle's tick (:func:`vehicle_tick`) and route
    tracking (:func:`locate`), then each scene's separation between the ego (slot 0) and its
    nearest other vehicle."""
    # The tuples' arrays taken out once (see jit).
    state, throttle, brake, steer, progress = i.vehicles, i.throttle, i.brake, i.steer, i.progress
    out, outputs, progress_out, lateral_out = o.vehicles, o.outputs, o.progress, o.lateral
    separation_out, tables, base, k = o.separation, c.tables, c.base, c.vehicle
    scenes, slots = progress.shape
    for b in range(scenes):
        for j in range(slots):
            n = b * slots + j
            r = vehicle_tick(
                state[0][b, j], state[1][b, j], state[2][b, j], state[3][b, j], state[4][b, j],
                state[5][b, j], state[6][b, j], state[7][b, j], throttle[n], brake[n], steer[n],
                k,
            )  # fmt: skip
            store_tick(out, outputs, n, r)
            _, progress_out[n], _, lateral_out[n] = locate(
                tables, c.spacing, c.k_max, c.walk_steps, base[j], r[0], r[1], progress[b, j]
            )
        separation_out[b] = nearest_gap(
            out[0], out[1], out[2], out[3], b * slots, slots, c.length, c.width
        )


@jit
def nearest_gap(
    x: FloatArray, y: FloatArray, cos_yaw: FloatArray, sin_yaw: FloatArray, ego: int,
    count: int, length: float, width: float,
) -> float:  # fmt: skip
    """Separation between the footprint of vehicle ``ego`` and the nearest of the next
    ``count − 1`` vehicles of the flat arrays (one scene) [m]."""
    gap = math.inf
    for i in range(ego + 1, ego + count):
        gap = min(
            gap,
            separation(
                x[i] - x[ego], y[i] - y[ego], cos_yaw[ego], sin_yaw[ego], length, width,
                cos_yaw[i], sin_yaw[i], length, width,
            ),
        )  # fmt: skip
    return gap


@jit
def _map_nearest_gap(
    x: FloatArray, y: FloatArray, cos_yaw: FloatArray, sin_yaw: FloatArray, slots: int,
    length: float, width: float, out: FloatArray,
) -> None:  # fmt: skip
    for b in range(out.shape[0]):
        out[b] = nearest_gap(x, y, cos_yaw, sin_yaw, b * slots, slots, length, width)
