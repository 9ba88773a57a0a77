"""The north car's "autopilot" (the stream vehicles of traffic from every leg are driven by
:mod:`safeswitch.sim.streams`).

It follows its lane at a target speed with its own speed and lane-keeping controllers and never
yields (the paper switches CARLA's autopilot's yielding off).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from safeswitch.core.arrays import flat, jit
from safeswitch.core.pid import PIDState, pid_tick
from safeswitch.core.pid_gains import PIDGains, PIDKernel
from safeswitch.sim.geometry import FloatArray
from safeswitch.sim.vehicle import (
    VehicleConstants,
    VehicleParams,
    steady_throttle,
    vehicle_constants,
)


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
    shape = pid.integral.shape
    throttle, brake = np.empty(shape), np.empty(shape)
    integral, error, derivative = np.empty(shape), np.empty(shape), np.empty(shape)
    _map_autopilot(
        params.speed_gains.kernel, dt, vehicle_constants(vehicle, dt), flat(speed, shape),
        flat(target_speed, shape), flat(pid.integral, shape), flat(pid.prev_error, shape),
        flat(pid.derivative, shape),
        (throttle.reshape(-1), brake.reshape(-1), integral.reshape(-1), error.reshape(-1),
         derivative.reshape(-1)),
    )  # fmt: skip
    return throttle, brake, PIDState(integral, error, derivative)


@jit
def autopilot_tick(
    gains: PIDKernel, dt: float, plant: VehicleConstants, speed: float, target: float,
    integral: float, prev_error: float, derivative: float,
) -> tuple[float, float, float, float, float]:  # fmt: skip
    """:func:`autopilot_pedals` for one car (``gains``: the speed PID's
    :attr:`~safeswitch.core.pid_gains.PIDGains.kernel`, ``plant``: its vehicle constants). Returns
    throttle, brake and the PID's new integral, error and derivative."""
    error = target - speed
    correction, integral, derivative = pid_tick(gains, dt, error, integral, prev_error, derivative)
    pedal = steady_throttle(target, plant) + correction
    return min(max(pedal, 0.0), 1.0), min(max(-pedal, 0.0), 1.0), integral, error, derivative


@jit
def _map_autopilot(
    gains: PIDKernel, dt: float, plant: VehicleConstants, speed: FloatArray, target: FloatArray,
    integral: FloatArray, prev_error: FloatArray, derivative: FloatArray,
    out: tuple[FloatArray, ...],
) -> None:  # fmt: skip
    for i in range(speed.shape[0]):
        out[0][i], out[1][i], out[2][i], out[3][i], out[4][i] = autopilot_tick(
            gains, dt, plant, speed[i], target[i], integral[i], prev_error[i], derivative[i]
        )
