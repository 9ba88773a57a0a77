"""Other road users: the north car's "autopilot".

It follows its lane at a target speed with its own speed and lane-keeping controllers and never
yields (the paper switches CARLA's autopilot's yielding off).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from safeswitch.core.arrays import clamp
from safeswitch.core.pid import PIDGains, PIDState, pid_step
from safeswitch.sim.geometry import FloatArray
from safeswitch.sim.vehicle import VehicleParams, steady_state_throttle


@dataclass(frozen=True)
class AutopilotParams:
    """Gains of the autopilot.

    Attributes:
        speed_gains: PID on the speed error [m/s] → pedal in [-1, 1] (positive throttle,
            negative brake), added to the steady-state throttle for the target speed.
        steer_gains: PID on the look-ahead lateral offset [m] → steering in [-1, 1].
        lookahead: Look-ahead distance of the lane keeper [m].
    """

    speed_gains: PIDGains = field(default_factory=lambda: PIDGains(0.5, 0.05, 0.0, -1.0, 1.0))
    steer_gains: PIDGains = field(default_factory=lambda: PIDGains(0.2, 0.01, 0.02, -1.0, 1.0))
    lookahead: float = 7.0


def autopilot_pedals(
    params: AutopilotParams,
    vehicle: VehicleParams,
    speed: FloatArray,
    target_speed: FloatArray,
    pid: PIDState,
    dt: float,
) -> tuple[FloatArray, FloatArray, PIDState]:
    """Throttle and brake that hold ``target_speed`` [m/s]: feed-forward plus PID.

    Returns:
        Throttle in [0, 1], brake in [0, 1] and the new PID state.
    """
    correction, pid = pid_step(params.speed_gains, pid, target_speed - speed, dt)
    pedal = steady_state_throttle(vehicle, target_speed) + correction
    return clamp(pedal, 0.0, 1.0), clamp(-pedal, 0.0, 1.0), pid
