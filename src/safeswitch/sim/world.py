"""A batch of scenes, each with several vehicles on their own routes, stepped together.

Vehicle arrays have shape ``[B, V]``: ``B`` independent scenes, ``V`` vehicles per scene (slot 0
is the ego). Every vehicle slot follows its own route; after each tick every vehicle is projected
onto its route (progress, lateral deviation, heading error), and the ego's footprint is checked
against every other vehicle's. The world knows nothing of controllers, rewards or learning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from safeswitch.core.arrays import flat, jit
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
        out = tuple(np.empty(n) for _ in range(8))
        outputs = (np.empty(n), np.empty(n), np.empty(n), np.empty(n))
        progress, lateral, gap = np.empty(n), np.empty(n), np.empty(shape[0])
        routes, p, v = self.route_set, self.params, state.vehicles
        _world_tick(
            (v.x, v.y, v.cos_yaw, v.sin_yaw, v.speed, v.throttle, v.brake, v.steer),
            flat(throttle, shape), flat(brake, shape), flat(steer, shape),
            self.vehicle_constants, routes.tables, routes.spacing, routes.size - 2,
            routes.WALK_STEPS, self.route_base, state.progress, p.length, p.width,
            out, outputs, progress, lateral, gap,
        )  # fmt: skip
        vehicles = VehicleState(*(a.reshape(shape) for a in out))
        new = WorldState(
            vehicles, progress.reshape(shape), lateral.reshape(shape), state.time + self.dt
        )
        return new, VehicleOutputs(*(a.reshape(shape) for a in outputs)), gap

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


@jit
def _world_tick(
    state: tuple[FloatArray, ...], throttle: FloatArray, brake: FloatArray, steer: FloatArray,
    k: VehicleConstants, tables: FloatArray, spacing: float, k_max: int, walk_steps: int,
    base: IntArray, progress: FloatArray, length: float, width: float,
    out: tuple[FloatArray, ...], outputs: tuple[FloatArray, ...], progress_out: FloatArray,
    lateral_out: FloatArray, separation_out: FloatArray,
) -> None:  # fmt: skip
    """:meth:`World.step` in one loop: every vehicle's tick (:func:`vehicle_tick`) and route
    tracking (:func:`locate`), then each scene's separation between the ego (slot 0) and its
    nearest other vehicle. ``state`` holds the ``[B, V]`` fields of :class:`VehicleState`, the
    outputs are flat ``[B·V]`` (``separation_out``: ``[B]``)."""
    scenes, slots = progress.shape
    for b in range(scenes):
        for j in range(slots):
            i = b * slots + j
            r = vehicle_tick(
                state[0][b, j], state[1][b, j], state[2][b, j], state[3][b, j], state[4][b, j],
                state[5][b, j], state[6][b, j], state[7][b, j], throttle[i], brake[i], steer[i],
                k,
            )  # fmt: skip
            store_tick(out, outputs, i, r)
            _, progress_out[i], _, lateral_out[i] = locate(
                tables, spacing, k_max, walk_steps, base[j], r[0], r[1], progress[b, j]
            )
        separation_out[b] = nearest_gap(
            out[0], out[1], out[2], out[3], b * slots, slots, length, width
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
