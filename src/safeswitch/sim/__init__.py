"""The embedded plant: road geometry and lane graph, vehicle dynamics, traffic, collisions.

Batch-first throughout (numpy, with the vehicle tick compiled per element by numba); nothing
in here knows about rewards or learning. The public names are imported on first use (the
parameters in :mod:`safeswitch.sim.params` need no compiled code).
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "AutopilotParams": "safeswitch.sim.autopilot",
    "autopilot_pedals": "safeswitch.sim.autopilot",
    "rectangle_separation": "safeswitch.sim.collision",
    "rectangles_overlap": "safeswitch.sim.collision",
    "ConflictGeometry": "safeswitch.sim.conflict",
    "conflict_geometry": "safeswitch.sim.conflict",
    "polyline_crossing": "safeswitch.sim.conflict",
    "Route": "safeswitch.sim.geometry",
    "RouteSet": "safeswitch.sim.geometry",
    "resample_polyline": "safeswitch.sim.geometry",
    "wrap_angle": "safeswitch.sim.geometry",
    "IntersectionGeometry": "safeswitch.sim.params",
    "Intersection": "safeswitch.sim.road",
    "VehicleOutputs": "safeswitch.sim.vehicle",
    "VehicleParams": "safeswitch.sim.params",
    "VehicleState": "safeswitch.sim.vehicle",
    "steady_state_throttle": "safeswitch.sim.vehicle",
    "vehicle_step": "safeswitch.sim.vehicle",
    "World": "safeswitch.sim.world",
    "WorldState": "safeswitch.sim.world",
    "preview_offsets": "safeswitch.sim.world",
}

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

if TYPE_CHECKING:
    from safeswitch.sim.autopilot import AutopilotParams, autopilot_pedals
    from safeswitch.sim.collision import rectangle_separation, rectangles_overlap
    from safeswitch.sim.conflict import ConflictGeometry, conflict_geometry, polyline_crossing
    from safeswitch.sim.geometry import Route, RouteSet, resample_polyline, wrap_angle
    from safeswitch.sim.params import IntersectionGeometry, VehicleParams
    from safeswitch.sim.road import Intersection
    from safeswitch.sim.vehicle import (
        VehicleOutputs,
        VehicleState,
        steady_state_throttle,
        vehicle_step,
    )
    from safeswitch.sim.world import World, WorldState, preview_offsets


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'safeswitch.sim' has no attribute {name!r}")
