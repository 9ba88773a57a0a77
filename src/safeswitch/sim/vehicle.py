"""Batched longitudinal and lateral vehicle dynamics: pedals → forces → kinematic bicycle.

The model is the smallest one that reproduces what the paper's controllers act on in CARLA:

* first-order lags between the commanded and the actual throttle, brake and steering;
* a drive force limited by the engine's peak force, its power and the driven axle's traction;
* brake force, rolling resistance, aerodynamic drag and engine braking (a closed or nearly
  closed throttle slows the car, as the paper notes for CARLA's vehicle);
* kinematic bicycle motion with a steering limit (below the tyres' limit slip is small at these
  speeds and a kinematic model is accurate);
* a friction circle: the combined acceleration never exceeds ``μ·g``. The pedals' force comes
  first (at most ``μ·m·g``, as ABS and traction control keep it), cornering gets what the
  tyres have left, ``√((μ·g)² − a_lon²)``. Asked for more — too fast into a curve, or braking
  hard in one — the front tyres slide: the car turns no tighter than the grip allows and runs
  wide of its path (understeer), as a real car does;
* no reversing: the car stops at zero speed.

All functions take arrays of any shape ``[...]`` (one element per vehicle). The longitudinal
model — lags, forces, speed — is scalar code compiled with numba (:func:`longitudinal_tick`),
run over every vehicle of a batch by one compiled loop; the certified switching logic predicts
the ego's next tick with the very same function, so the filter and the plant cannot disagree.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import broadcast_flat, each, flat, jit
from safeswitch.sim.params import AIR_DENSITY, GRAVITY, VehicleParams

FloatArray = NDArray[np.float64]


@dataclass
class VehicleState:
    """State of a batch of vehicles; every field has the same shape ``[...]``.

    Heading is carried as a unit vector ``(cos ψ, sin ψ)`` rather than an angle: every consumer
    (motion, lane keeping, collision checks) needs the cosine and sine, and numpy's float64
    trigonometric functions would otherwise dominate the cost of a step. :attr:`yaw` gives the
    angle.

    Attributes:
        x: Position of the centre of gravity, east [m].
        y: Position of the centre of gravity, north [m].
        cos_yaw: Cosine of the heading (counter-clockwise from east).
        sin_yaw: Sine of the heading.
        speed: Longitudinal speed, never negative [m/s].
        throttle: Actual throttle position in [0, 1] (after the actuator lag).
        brake: Actual brake position in [0, 1].
        steer: Actual steering position in [-1, 1], positive to the left.
    """

    x: FloatArray
    y: FloatArray
    cos_yaw: FloatArray
    sin_yaw: FloatArray
    speed: FloatArray
    throttle: FloatArray
    brake: FloatArray
    steer: FloatArray

    @classmethod
    def at(
        cls,
        x: FloatArray,
        y: FloatArray,
        yaw: FloatArray,
        speed: FloatArray,
        throttle: FloatArray | float = 0.0,
    ) -> VehicleState:
        """Vehicles at the given poses and speeds, brake released, wheels straight."""
        x = np.asarray(x, dtype=np.float64)
        shape = np.broadcast_shapes(x.shape, np.shape(y), np.shape(yaw), np.shape(speed))

        def full(value: FloatArray | float) -> FloatArray:
            return np.broadcast_to(np.asarray(value, dtype=np.float64), shape).copy()

        yaw = full(yaw)
        return cls(
            full(x),
            full(y),
            np.cos(yaw),
            np.sin(yaw),
            full(speed),
            full(throttle),
            full(0.0),
            full(0.0),
        )

    @property
    def yaw(self) -> FloatArray:
        """Heading, counter-clockwise from east, in ``(-pi, pi]`` [rad]."""
        return np.arctan2(self.sin_yaw, self.cos_yaw)

    @property
    def xy(self) -> FloatArray:
        """Positions stacked, shape ``[..., 2]``."""
        return np.stack([self.x, self.y], axis=-1)

    def copy(self) -> VehicleState:
        return VehicleState(*(getattr(self, f.name).copy() for f in fields(self)))


@dataclass
class VehicleOutputs:
    """Measured quantities of one tick, each of shape ``[...]``.

    Attributes:
        accel_lon: Longitudinal acceleration over the tick [m/s²] (negative when slowing).
        accel_lat: Lateral (centripetal) acceleration [m/s²], positive to the left: what the
            tyres gave, at most what the friction circle leaves.
        yaw_rate: Yaw rate [rad/s].
        grip_demand: The combined acceleration the pedals and the steering asked for, as a
            share of ``μ·g`` (above 1: the tyres slid this tick).
    """

    accel_lon: FloatArray
    accel_lat: FloatArray
    yaw_rate: FloatArray
    grip_demand: FloatArray


def lag_factor(time_constant: float, dt: float) -> float:
    """Exact discretisation of a first-order lag: the fraction of the gap closed in ``dt``."""
    return 1.0 - math.exp(-dt / time_constant)


class VehicleConstants(NamedTuple):
    """What the compiled vehicle model reads, derived once per parameter set and tick (see
    :func:`vehicle_constants`).

    Attributes:
        dt: Tick length [s].
        mass: Mass [kg].
        alpha_throttle: Fraction of the throttle command's gap closed per tick.
        alpha_brake: Fraction of the brake command's gap closed per tick.
        drive_max: Largest drive force [N].
        power: Peak power [W].
        traction: Largest force the driven axle transmits, ``μ·m·g·f_driven`` [N].
        engine_brake_base: Closed-throttle drag at 1 m/s and above, before the speed term [N].
        engine_brake_slope: Further closed-throttle drag per unit speed [N·s/m].
        engine_brake_max: Upper bound of the closed-throttle drag [N].
        brake_force: Brake force at full brake [N].
        rolling: Rolling resistance ``c_rr·m·g`` [N].
        aero: ``½·ρ·Cd·A`` [kg/m].
        grip: Tyre grip ``μ·m·g`` [N].
        grip_accel: The friction circle's radius ``μ·g`` [m/s²].
        alpha_steer: Fraction of the steering command's gap closed per tick.
        max_steer: Road-wheel angle at full steering [rad].
        rear_ratio: ``l_r / L``.
        wheelbase: ``L`` [m].
    """

    dt: float
    mass: float
    alpha_throttle: float
    alpha_brake: float
    drive_max: float
    power: float
    traction: float
    engine_brake_base: float
    engine_brake_slope: float
    engine_brake_max: float
    brake_force: float
    rolling: float
    aero: float
    grip: float
    grip_accel: float
    alpha_steer: float
    max_steer: float
    rear_ratio: float
    wheelbase: float


@functools.lru_cache(maxsize=16)
def vehicle_constants(params: VehicleParams, dt: float) -> VehicleConstants:
    """The constants :func:`vehicle_tick` and the force functions read (computed once per
    parameter set and tick)."""
    p = params
    return VehicleConstants(
        dt=dt,
        mass=p.mass,
        alpha_throttle=lag_factor(p.throttle_time_constant, dt),
        alpha_brake=lag_factor(p.brake_time_constant, dt),
        drive_max=p.max_drive_force,
        power=p.max_power,
        traction=p.friction_coefficient * p.mass * GRAVITY * p.driven_axle_load_fraction,
        engine_brake_base=p.engine_brake_base_force,
        engine_brake_slope=p.engine_brake_coefficient,
        engine_brake_max=p.max_engine_brake_force,
        brake_force=p.max_brake_force,
        rolling=p.rolling_resistance * p.mass * GRAVITY,
        aero=0.5 * AIR_DENSITY * p.drag_area,
        grip=p.friction_coefficient * p.mass * GRAVITY,
        grip_accel=p.friction_coefficient * GRAVITY,
        alpha_steer=lag_factor(p.steer_time_constant, dt),
        max_steer=p.max_steer_angle,
        rear_ratio=p.cg_to_rear_axle / p.wheelbase,
        wheelbase=p.wheelbase,
    )


@jit
def drive_force(speed: float, k: VehicleConstants) -> float:
    """Drive force at full throttle [N]: ``min(F_max, P/v, μ·m·g·f_driven)``."""
    return min(min(k.drive_max, k.power / max(speed, 0.1)), k.traction)


@jit
def engine_drag(speed: float, k: VehicleConstants) -> float:
    """Engine braking at closed throttle [N]: ``min(F_0·min(v, 1) + c·v, F_max)``."""
    base = k.engine_brake_base * min(speed, 1.0) + k.engine_brake_slope * speed
    return min(base, k.engine_brake_max)


@jit
def resistance(speed: float, k: VehicleConstants) -> float:
    """Rolling resistance plus aerodynamic drag [N] (for speed > 0)."""
    return k.rolling + k.aero * speed * speed


@jit
def net_force(speed: float, throttle: float, brake: float, k: VehicleConstants) -> float:
    """Net longitudinal force on the car [N] for actual pedal positions, at speed > 0:
    ``throttle · F_drive(v) − (1 − throttle) · F_drag(v) − brake · F_brake − F_res(v)``, bounded
    by the tyres' grip ``μ·m·g``."""
    force = (
        throttle * drive_force(speed, k)
        - (1.0 - throttle) * engine_drag(speed, k)
        - brake * k.brake_force
        - resistance(speed, k)
    )
    return min(max(force, -k.grip), k.grip)


@jit
def steady_throttle(speed: float, k: VehicleConstants) -> float:
    """Throttle position that holds ``speed`` on a level road:
    ``throttle·F_drive − (1 − throttle)·F_drag − F_res = 0``, clipped to [0, 1]."""
    drag = engine_drag(speed, k)
    throttle = (drag + resistance(speed, k)) / (drive_force(speed, k) + drag)
    return min(max(throttle, 0.0), 1.0)


@jit
def longitudinal_tick(
    speed: float,
    throttle: float,
    brake: float,
    throttle_cmd: float,
    brake_cmd: float,
    k: VehicleConstants,
) -> tuple[float, float, float]:
    """One tick of the longitudinal model: the commands (clipped to [0, 1]) through the
    actuator lags, then the speed under the net force (never negative). Returns the new
    throttle and brake positions and the new speed."""
    throttle += k.alpha_throttle * (min(max(throttle_cmd, 0.0), 1.0) - throttle)
    brake += k.alpha_brake * (min(max(brake_cmd, 0.0), 1.0) - brake)
    accel = net_force(speed, throttle, brake, k) / k.mass
    return throttle, brake, max(speed + accel * k.dt, 0.0)


@jit
def _rotate(c: float, s: float, angle: float) -> tuple[float, float]:
    """Rotate the unit vector ``(c, s)`` by a small angle [rad].

    Taylor series to fifth order: the error is below ``angle⁶/720``, 1e-11 at the 0.05 rad a car
    turns in a tick at most here (8e-8 at 0.2 rad, a full-lock turn at 35 m/s).
    """
    a2 = angle * angle
    cos_a = 1.0 - a2 * (0.5 - a2 * (1.0 / 24.0))
    sin_a = angle * (1.0 - a2 * ((1.0 / 6.0) - a2 * (1.0 / 120.0)))
    return c * cos_a - s * sin_a, s * cos_a + c * sin_a


@jit
def vehicle_tick(
    x: float, y: float, cos_yaw: float, sin_yaw: float, speed0: float, throttle: float,
    brake: float, steer: float, throttle_cmd: float, brake_cmd: float, steer_cmd: float,
    k: VehicleConstants,
) -> tuple[float, ...]:  # fmt: skip
    """One tick of one vehicle: its :class:`VehicleState` fields in, the new ones followed by
    its :class:`VehicleOutputs` (``accel_lon``, ``accel_lat``, ``yaw_rate``, ``grip_demand``)
    out."""
    dt = k.dt
    throttle, brake, speed = longitudinal_tick(speed0, throttle, brake, throttle_cmd, brake_cmd, k)
    steer += k.alpha_steer * (min(max(steer_cmd, -1.0), 1.0) - steer)
    mean_speed = 0.5 * (speed0 + speed)
    # Kinematic bicycle about the centre of gravity: slip angle β = atan(l_r/L · tan δ).
    tan_delta = math.tan(steer * k.max_steer)
    tan_slip = k.rear_ratio * tan_delta
    cos_slip = 1.0 / math.sqrt(1.0 + tan_slip * tan_slip)
    sin_slip = tan_slip * cos_slip
    yaw_rate = mean_speed * cos_slip * tan_delta / k.wheelbase
    # The friction circle: the pedals' acceleration first (bounded by the grip already), the
    # turn gets what is left; asked for more, the tyres slide and the car turns less tightly.
    accel = (speed - speed0) / dt
    lateral = mean_speed * yaw_rate
    grip = k.grip_accel
    demand = math.sqrt(accel * accel + lateral * lateral) / grip
    if demand > 1.0:
        left = math.sqrt(max(grip * grip - accel * accel, 0.0))
        if abs(lateral) > left:  # (not a rounding of an acceleration at the grip itself)
            yaw_rate *= left / abs(lateral)
    # Midpoint heading over the tick, then the course ψ + β, by rotating the heading vector.
    cos_mid, sin_mid = _rotate(cos_yaw, sin_yaw, 0.5 * yaw_rate * dt)
    step = mean_speed * dt
    x_new = x + step * (cos_mid * cos_slip - sin_mid * sin_slip)  # cos(ψ + β)
    y_new = y + step * (sin_mid * cos_slip + cos_mid * sin_slip)  # sin(ψ + β)
    cos_yaw, sin_yaw = _rotate(cos_yaw, sin_yaw, yaw_rate * dt)
    # Keep the heading a unit vector (rounding would otherwise drift over long runs).
    norm = 1.5 - 0.5 * (cos_yaw * cos_yaw + sin_yaw * sin_yaw)  # a Newton step of 1/sqrt
    return (
        x_new, y_new, cos_yaw * norm, sin_yaw * norm, speed, throttle, brake, steer,
        accel, mean_speed * yaw_rate, yaw_rate, demand,
    )  # fmt: skip


@jit
def map_vehicle_tick(
    state: tuple[FloatArray, ...], throttle_cmd: FloatArray, brake_cmd: FloatArray,
    steer_cmd: FloatArray, k: VehicleConstants, out: tuple[FloatArray, ...],
    outputs: tuple[FloatArray, ...],
) -> None:  # fmt: skip
    """:func:`vehicle_tick` for every vehicle: ``state`` and ``out`` hold the fields of
    :class:`VehicleState` in order, ``outputs`` those of :class:`VehicleOutputs`, each a flat
    vector (separate vectors, not one block: fresh memory of a large batch costs more in page
    faults than the arithmetic)."""
    for i in range(throttle_cmd.shape[0]):
        r = vehicle_tick(
            state[0][i], state[1][i], state[2][i], state[3][i], state[4][i], state[5][i],
            state[6][i], state[7][i], throttle_cmd[i], brake_cmd[i], steer_cmd[i], k,
        )  # fmt: skip
        store_tick(out, outputs, i, r)


@jit
def store_tick(
    out: tuple[FloatArray, ...], outputs: tuple[FloatArray, ...], i: int, r: tuple[float, ...]
) -> None:
    """Write one :func:`vehicle_tick` result at flat index ``i``: the new state into ``out``,
    the measured outputs into ``outputs``."""
    out[0][i], out[1][i], out[2][i], out[3][i] = r[0], r[1], r[2], r[3]
    out[4][i], out[5][i], out[6][i], out[7][i] = r[4], r[5], r[6], r[7]
    outputs[0][i], outputs[1][i], outputs[2][i], outputs[3][i] = r[8], r[9], r[10], r[11]


@jit
def _map_forces(
    speed: FloatArray,
    throttle: FloatArray,
    brake: FloatArray,
    k: VehicleConstants,
    net: FloatArray,
    drive: FloatArray,
    drag: FloatArray,
    resist: FloatArray,
) -> None:
    for i in range(speed.shape[0]):
        net[i] = net_force(speed[i], throttle[i], brake[i], k)
        drive[i] = drive_force(speed[i], k)
        drag[i] = engine_drag(speed[i], k)
        resist[i] = resistance(speed[i], k)


def _force_constants(params: VehicleParams) -> VehicleConstants:
    """The constants the force functions read; the tick length does not enter the forces, so
    any valid one selects the same values."""
    return vehicle_constants(params, 0.02)


def forces(
    params: VehicleParams,
    speed: FloatArray,
    throttle: FloatArray | float = 0.0,
    brake: FloatArray | float = 0.0,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The force model on arrays (broadcast together) [N]: net force (:func:`net_force`), full
    drive force, closed-throttle engine braking and driving resistance."""
    shape, (v, th, br) = broadcast_flat(speed, throttle, brake)
    net, drive, drag, resist = (np.empty(shape) for _ in range(4))
    _map_forces(
        v,
        th,
        br,
        _force_constants(params),
        net.reshape(-1),
        drive.reshape(-1),
        drag.reshape(-1),
        resist.reshape(-1),
    )
    return net, drive, drag, resist


def available_drive_force(params: VehicleParams, speed: FloatArray) -> FloatArray:
    """Drive force at full throttle [N] (see :func:`drive_force`)."""
    return forces(params, speed)[1]


def closed_throttle_drag(params: VehicleParams, speed: FloatArray) -> FloatArray:
    """Engine braking at closed throttle [N] (see :func:`engine_drag`)."""
    return forces(params, speed)[2]


def driving_resistance(params: VehicleParams, speed: FloatArray) -> FloatArray:
    """Rolling resistance plus aerodynamic drag [N] (see :func:`resistance`)."""
    return forces(params, speed)[3]


def longitudinal_force(
    params: VehicleParams, speed: FloatArray, throttle: FloatArray, brake: FloatArray
) -> FloatArray:
    """Net longitudinal force on the car [N] for actual pedal positions (see
    :func:`net_force`)."""
    return forces(params, speed, throttle, brake)[0]


def steady_state_throttle(params: VehicleParams, speed: FloatArray) -> FloatArray:
    """Throttle position that holds ``speed`` on a level road (feed-forward for speed control;
    see :func:`steady_throttle`)."""
    return each(steady_throttle, _force_constants(params), speed)


def vehicle_step(
    params: VehicleParams,
    state: VehicleState,
    throttle_cmd: FloatArray,
    brake_cmd: FloatArray,
    steer_cmd: FloatArray,
    dt: float,
) -> tuple[VehicleState, VehicleOutputs]:
    """Advance a batch of vehicles by one tick.

    Commands are clipped to their ranges here, at the plant's input, whatever the caller did.
    Speed is integrated explicitly; position with the mean of the old and new speed, so constant
    deceleration gives the exact ``v²/(2a)`` stopping distance.

    Args:
        params: Vehicle parameters (shared by the batch).
        state: Current state (not modified).
        throttle_cmd: Commanded throttle in [0, 1].
        brake_cmd: Commanded brake in [0, 1].
        steer_cmd: Commanded steering in [-1, 1], positive to the left.
        dt: Tick length [s].

    Returns:
        The next state and this tick's measured outputs.
    """
    shape = state.speed.shape
    n = state.speed.size
    out = tuple(np.empty(n) for _ in range(8))
    outputs = (np.empty(n), np.empty(n), np.empty(n), np.empty(n))
    map_vehicle_tick(
        tuple(flat(getattr(state, f.name), shape) for f in fields(VehicleState)),
        flat(throttle_cmd, shape),
        flat(brake_cmd, shape),
        flat(steer_cmd, shape),
        vehicle_constants(params, dt),
        out,
        outputs,
    )
    new = VehicleState(*(a.reshape(shape) for a in out))
    return new, VehicleOutputs(*(a.reshape(shape) for a in outputs))
