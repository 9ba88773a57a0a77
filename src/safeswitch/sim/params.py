"""The simulator's physical parameters: the vehicle and the intersection's dimensions (plain,
validated dataclasses; configuration reads them without the simulation behind them)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

GRAVITY = 9.81  # [m/s²]
AIR_DENSITY = 1.2  # [kg/m³]


@dataclass(frozen=True)
class VehicleParams:
    """Physical parameters of a mid-size sedan (defaults after a Lincoln MKZ, CARLA's default car).

    Published figures for the 2017 MKZ 2.0 L: about 1,700–1,850 kg, 2.85 m wheelbase,
    4.93 m × 2.08 m (with mirrors, CARLA's bounding box is about 4.9 × 2.1 m), 180 kW.

    Attributes:
        mass: Mass with driver [kg].
        length: Bounding-box length [m].
        width: Bounding-box width [m].
        wheelbase: Distance between the axles [m].
        cg_to_rear_axle: Distance from the centre of gravity to the rear axle [m]. The
            bounding box is centred on the centre of gravity.
        max_steer_angle: Road-wheel angle at full steering command [rad] (35°).
        max_drive_force: Largest drive force at the wheels, in low gear [N].
        max_power: Peak engine power [W]; limits the drive force to ``power / speed``.
        friction_coefficient: Tyre–road friction coefficient ``μ``: the combined acceleration
            stays within ``μ·g`` (dry asphalt: peak coefficients of 0.8–0.9, Wong, *Theory
            of Ground Vehicles*, 4th ed., Table 1.3; 0.9 for a modern passenger-car tyre).
        driven_axle_load_fraction: Share of the weight on the driven (front) axle.
        max_brake_force: Brake force at full brake command [N] (about the tyre limit).
        rolling_resistance: Rolling resistance coefficient.
        drag_area: Drag coefficient times frontal area, ``Cd·A`` [m²].
        engine_brake_base_force: Closed-throttle drag force [N], faded in over the first 1 m/s
            so that a standing car pulls away with a small throttle. With the speed term it
            gives about 1.5 m/s² at 25 km/h — lift-off regeneration of a hybrid (the MKZ is sold
            as one) or a low gear — so the throttle alone can stop the car within about 20 m,
            as the paper's policy does in CARLA (its Fig. 10: a full stop, brake never used).
        engine_brake_coefficient: Further closed-throttle drag per unit speed [N·s/m].
        max_engine_brake_force: Upper bound of the closed-throttle drag [N].
        throttle_time_constant: Lag of the throttle actuator [s].
        brake_time_constant: Lag of the brake actuator [s].
        steer_time_constant: Lag of the steering actuator [s].
    """

    mass: float = 1800.0
    length: float = 4.9
    width: float = 2.1
    wheelbase: float = 2.85
    cg_to_rear_axle: float = 1.5
    max_steer_angle: float = math.radians(35.0)
    max_drive_force: float = 5500.0
    max_power: float = 180_000.0
    friction_coefficient: float = 0.9
    driven_axle_load_fraction: float = 0.6
    max_brake_force: float = 15_000.0
    rolling_resistance: float = 0.015
    drag_area: float = 0.7
    engine_brake_base_force: float = 1500.0
    engine_brake_coefficient: float = 150.0
    max_engine_brake_force: float = 3000.0
    throttle_time_constant: float = 0.10
    brake_time_constant: float = 0.08
    steer_time_constant: float = 0.10

    def __post_init__(self) -> None:
        nonneg = {
            "rolling_resistance",
            "drag_area",
            "engine_brake_coefficient",
            "max_engine_brake_force",
            "engine_brake_base_force",
        }
        for f in fields(self):
            value = getattr(self, f.name)
            ok = math.isfinite(value) and (value >= 0 if f.name in nonneg else value > 0)
            if not ok:
                raise ValueError(f"VehicleParams.{f.name} has an invalid value {value!r}")
        if not self.cg_to_rear_axle < self.wheelbase:
            raise ValueError(
                f"VehicleParams.cg_to_rear_axle ({self.cg_to_rear_axle}) must be shorter than "
                f"the wheelbase ({self.wheelbase})"
            )
        if self.driven_axle_load_fraction > 1:
            raise ValueError(
                "VehicleParams.driven_axle_load_fraction must be <= 1, got "
                f"{self.driven_axle_load_fraction!r}"
            )

    @property
    def max_brake_deceleration(self) -> float:
        """Deceleration at full brake on a level road, resistances ignored [m/s²]."""
        return (
            min(self.max_brake_force, self.friction_coefficient * self.mass * GRAVITY) / self.mass
        )


@dataclass(frozen=True)
class IntersectionGeometry:
    """Dimensions of the four-leg intersection.

    Attributes:
        lane_width: Width of every lane [m].
        box_half_size: Distance from the centre to each leg's stop line [m]. Larger than the
            road's half width (one lane each way = 3.5 m) because real junctions set stop lines
            back behind corner radii and crossings; it also sets the turn radii (left turn:
            ``box_half_size + lane_width / 2`` = 11.75 m by default).
        approach_length: Length of each leg from the stop line outwards [m]. At the default
            120 m a car starting from rest reaches 25 km/h long before the stop line.
        waypoint_spacing: Largest distance between route waypoints [m].
    """

    lane_width: float = 3.5
    box_half_size: float = 10.0
    approach_length: float = 120.0
    waypoint_spacing: float = 0.5

    def __post_init__(self) -> None:
        for name in ("lane_width", "box_half_size", "approach_length", "waypoint_spacing"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"IntersectionGeometry.{name} must be > 0, got {value!r}")
        if self.box_half_size < self.lane_width:
            raise ValueError(
                f"IntersectionGeometry.box_half_size ({self.box_half_size}) must be at least "
                f"the road's half width ({self.lane_width})"
            )
        if self.waypoint_spacing > 1.0:
            raise ValueError(
                f"IntersectionGeometry.waypoint_spacing must be <= 1 m, got {self.waypoint_spacing}"
            )
