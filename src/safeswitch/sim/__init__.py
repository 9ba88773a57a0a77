"""The embedded plant: road geometry and lane graph, vehicle dynamics, traffic, collisions.

Batch-first throughout (numpy, with the vehicle tick compiled per element by numba); nothing
in here knows about rewards or learning.
"""

from safeswitch.sim.autopilot import AutopilotParams, autopilot_pedals
from safeswitch.sim.collision import rectangle_separation, rectangles_overlap
from safeswitch.sim.conflict import ConflictGeometry, conflict_geometry, polyline_crossing
from safeswitch.sim.geometry import Route, RouteSet, resample_polyline, wrap_angle
from safeswitch.sim.road import Intersection, IntersectionGeometry
from safeswitch.sim.vehicle import (
    VehicleOutputs,
    VehicleParams,
    VehicleState,
    steady_state_throttle,
    vehicle_step,
)
from safeswitch.sim.world import World, WorldState, preview_offsets

__all__ = [
    "AutopilotParams",
    "ConflictGeometry",
    "Intersection",
    "IntersectionGeometry",
    "Route",
    "RouteSet",
    "VehicleOutputs",
    "VehicleParams",
    "VehicleState",
    "World",
    "WorldState",
    "autopilot_pedals",
    "conflict_geometry",
    "polyline_crossing",
    "preview_offsets",
    "rectangle_separation",
    "rectangles_overlap",
    "resample_polyline",
    "steady_state_throttle",
    "vehicle_step",
    "wrap_angle",
]
