"""A batch of scenes, each with several vehicles on their own routes, stepped together.

Vehicle arrays have shape ``[B, V]``: ``B`` independent scenes, ``V`` vehicles per scene (slot 0
is the ego). Every vehicle slot follows its own route; after each tick every vehicle is projected
onto its route (progress, lateral deviation, heading error), and the ego's footprint is checked
against every other vehicle's. The world knows nothing of controllers, rewards or learning.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from safeswitch.sim.collision import separation_from_axes
from safeswitch.sim.geometry import FloatArray, Route, RouteSet, wrap_angle
from safeswitch.sim.vehicle import (
    VehicleOutputs,
    VehicleParams,
    VehicleState,
    steady_state_throttle,
    vehicle_step,
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
        self._base = self.route_set.base_index(self.slots)  # [V], broadcasts against [B, V]

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
        vehicles, outputs = vehicle_step(
            self.params, state.vehicles, throttle, brake, steer, self.dt
        )
        progress, lateral = self.route_set.track_flat(
            self._base, vehicles.x, vehicles.y, state.progress
        )
        new = WorldState(vehicles, progress, lateral, state.time + self.dt)
        return new, outputs, self.ego_separation(vehicles)

    def ego_separation(self, vehicles: VehicleState) -> FloatArray:
        """Separation between the ego's footprint and the nearest other vehicle's [m], ``[B]``."""
        p, v = self.params, vehicles
        gap = separation_from_axes(
            v.x[:, 1:] - v.x[:, :1],
            v.y[:, 1:] - v.y[:, :1],
            v.cos_yaw[:, :1],
            v.sin_yaw[:, :1],
            p.length,
            p.width,
            v.cos_yaw[:, 1:],
            v.sin_yaw[:, 1:],
            p.length,
            p.width,
        )
        return gap.min(axis=1)


def preview_offsets(world: World, state: WorldState, lookahead: float) -> FloatArray:
    """Lateral offset of each vehicle's route point ``lookahead`` metres ahead, in the vehicle's
    frame [m], ``[B, V]`` (the lane keepers' error signal; see
    :meth:`~safeswitch.sim.geometry.RouteSet.preview_offset`)."""
    v = state.vehicles
    tx, ty, _ = world.route_set.pose_at_flat(world._base, state.progress + lookahead)
    return v.cos_yaw * (ty - v.y) - v.sin_yaw * (tx - v.x)


def heading_errors(world: World, state: WorldState) -> FloatArray:
    """Each vehicle's heading minus its route's heading at its progress [rad], ``[B, V]``."""
    _, _, route_heading = world.route_set.pose_at_flat(world._base, state.progress)
    return wrap_angle(state.vehicles.yaw - route_heading)
