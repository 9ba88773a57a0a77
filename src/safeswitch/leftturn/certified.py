"""The certified switching logic: a Simplex-style safety filter with two backups.

**Backups** (rule-based, each with a closed-form bound on what it achieves on the plant model):

* *stop* — full brake until standstill, then hold. Its stopping distance is bounded from the
  current speed and actual pedal positions: the first ``lag_ticks`` ticks follow the actuator
  lags exactly (throttle decaying, brake building up; drive force at its maximum, every
  resistance ignored), after which the weakest remaining deceleration is assumed. Full brake
  rather than ``PID_b``: the bound must be provable, and only the intervention ticks pay in comfort.
* *clear* — full throttle until the ego has left its conflict zone. Its time to cover a distance
  is bounded the same way from below on the acceleration (drive force at the clearing speed cap,
  full engine braking, resistances at the cap).

**Certificate.** A state is *safe* when the north car has left its zone, or the ego has left
its own, or the stop backup ends before the ego's zone entry, or the clear backup leaves the
ego's zone ``time_margin_s`` before the north car can first enter its zone (accelerating at
``north_max_accel`` up to ``north_max_speed_kmh``). The learned action is executed exactly when
the state after one tick of it — predicted with the plant's own longitudinal model, actuator
lags included — is safe. Otherwise the filter executes a backup that is feasible now, preferring
*stop* (it is robust to any behaviour of the north car once the ego stands before the zone).

**Invariant.** From a safe state, either action keeps the state safe: the learned one by the
check, a backup because its bound at the next tick is no larger than at this one (the bounds are
monotone along their own trajectories) while the north car, within the assumptions, cannot
arrive earlier than its bound said. Safe states never collide: the zones are computed from the
footprints with a margin covering the ego's lateral deviation. So no learned action sequence —
random, adversarial, NaN — leads to a collision while the assumptions hold.

If no backup is feasible (only when the assumptions were broken), the filter brakes fully while
the ego is still before its zone and accelerates fully once it is inside (best effort), and the
reason says so.

**Implementation.** The bounds follow the lag phase tick by tick, per element, in scalar code
compiled with numba: a few dozen floating-point operations per element instead of a few hundred
numpy calls per batch, so the filter costs little at any batch size. The learned tick is
predicted inside the same loop with the plant's own compiled
:func:`~safeswitch.sim.vehicle.longitudinal_tick`, so the filter and the plant cannot disagree
about it. The numpy-facing methods (:meth:`CertifiedSwitching.stop_distance`,
:meth:`~CertifiedSwitching.clear_time`, …) run the same compiled functions.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import broadcast_flat, jit
from safeswitch.core.registry import LogicContextError, context_name
from safeswitch.core.switching import BoolArray, Decision, FloatArray
from safeswitch.leftturn.config import CertifiedConfig
from safeswitch.leftturn.switching import ConflictState
from safeswitch.sim.conflict import conflict_geometry
from safeswitch.sim.vehicle import (
    GRAVITY,
    VehicleConstants,
    VehicleParams,
    drive_force,
    longitudinal_tick,
    resistance,
    vehicle_constants,
)

if TYPE_CHECKING:
    from safeswitch.leftturn.task import LeftTurnTask

#: Reason codes of the backups (indices into ``CertifiedSwitching.reasons``).
STOP, CLEAR, NO_BACKUP_BRAKE, NO_BACKUP_CLEAR = 1, 2, 3, 4


class CertifiedConstants(NamedTuple):
    """The scalars the compiled filter reads (built by :class:`CertifiedSwitching`).

    Attributes:
        dt: Tick [s].
        mass: Ego mass [kg].
        brake_max: Largest brake force the tyres transmit [N].
        drive_max: Largest drive force the driven axle transmits [N].
        drive_at_cap: Drive force at the clearing speed cap [N].
        resist_at_cap: Driving resistance at the cap [N].
        engine_brake_max: Largest closed-throttle drag [N].
        cap: Clearing speed cap [m/s].
        lag_time: Length of the lag phase the bounds follow tick by tick [s].
        accel_max: Largest acceleration the plant can give [m/s²].
        decel_tail_worst: Weakest deceleration after the lag phase from the worst pedals [m/s²].
        ego_enter: Ego's certified conflict-zone entry [m].
        ego_exit: Ego's certified conflict-zone exit [m].
        north_enter: North car's certified conflict-zone entry [m].
        north_exit: North car's certified conflict-zone exit [m].
        north_accel: Assumed largest acceleration of the north car [m/s²].
        north_top: Assumed top speed of the north car [m/s].
        progress_factor: Bound on progress along the route per distance driven.
        time_margin: Margin between the ego leaving and the north car entering [s].
        lag_ticks: Ticks of the lag phase (a float: it enters the closed forms).
        sum_k: ``Σ k`` over the lag phase.
        gt_last: Last partial sum of ``ρ_t^k``.
        gb_last: Last partial sum of ``ρ_b^k``.
        gt_sum: Sum of the partial sums of ``ρ_t^k``.
        gb_sum: Sum of the partial sums of ``ρ_b^k``.
    """

    dt: float
    mass: float
    brake_max: float
    drive_max: float
    drive_at_cap: float
    resist_at_cap: float
    engine_brake_max: float
    cap: float
    lag_time: float
    accel_max: float
    decel_tail_worst: float
    ego_enter: float
    ego_exit: float
    north_enter: float
    north_exit: float
    north_accel: float
    north_top: float
    progress_factor: float
    time_margin: float
    lag_ticks: float
    sum_k: float
    gt_last: float
    gb_last: float
    gt_sum: float
    gb_sum: float


@jit
def _stop_distance(
    speed: float,
    throttle: float,
    brake: float,
    c: CertifiedConstants,
    rho_t: FloatArray,
    rho_b: FloatArray,
) -> float:
    """Upper bound on the full-brake stopping distance [m]: on lag tick ``k`` the deceleration
    is at least ``A − B·ρ_b^k − C·ρ_t^k`` (the brake force built up, minus the largest drive
    force of the decaying throttle; resistances ignored); after the lag phase, its last value.
    Closed form while the car still moves at the end of the lag phase, else tick by tick."""
    dt, kk = c.dt, c.lag_ticks
    a = c.brake_max / c.mass
    b = a * (1.0 - brake)
    cc = c.drive_max / c.mass * throttle
    v_end = speed - dt * (kk * a - b * c.gb_last - cc * c.gt_last)
    last = rho_t.shape[0] - 1
    if v_end > 0.0:
        v_sum = kk * speed - dt * (c.sum_k * a - b * c.gb_sum - cc * c.gt_sum)
        decel_end = a - b * rho_b[last] - cc * rho_t[last]
        return dt * (v_sum + 0.5 * (speed - v_end)) + v_end * v_end / (2.0 * decel_end)
    v, total, decel = speed, 0.0, 0.0
    for k in range(last + 1):
        decel = a - b * rho_b[k] - cc * rho_t[k]
        v_next = max(v - dt * decel, 0.0)  # decel grows with k: once at rest, stays at rest
        total += 0.5 * dt * (v + v_next)
        v = v_next
    return total + v * v / (2.0 * decel)


@jit
def _quick_stop_distance(speed: float, c: CertifiedConstants) -> float:
    """A looser stopping bound for any pedal positions: the largest drive force for the whole
    lag phase, then the lag phase's weakest deceleration [m]."""
    t, a = c.lag_time, c.accel_max
    top = speed + a * t
    return (speed + 0.5 * a * t) * t + top * top / (2.0 * c.decel_tail_worst)


@jit
def _tail_time(rest: float, v: float, a: float, cap: float) -> float:
    """Time to drive ``rest`` [m] from speed ``v`` at constant ``a`` up to ``cap``, then at
    the cap [s]."""
    if a > 0.0:
        to_cap = (cap * cap - v * v) / (2.0 * a)
        if rest <= to_cap:
            return (math.sqrt(v * v + 2.0 * a * rest) - v) / a
        return (cap - v) / a + (rest - to_cap) / cap
    if v > 0.0:
        return rest / v
    return math.inf


@jit
def _clear_time(
    distance: float,
    speed: float,
    throttle: float,
    brake: float,
    c: CertifiedConstants,
    rho_t: FloatArray,
    rho_b: FloatArray,
) -> float:
    """Upper bound on the time to drive ``distance`` [m] under full throttle [s]: on lag tick
    ``k`` the acceleration is at least ``A − P·ρ_t^k − Q·ρ_b^k`` (the throttle's drive force at
    the clearing speed cap minus full engine braking of its closed part, the releasing brake and
    the resistances at the cap). Closed form when no clamp of the speed bound (at 0 or at the
    cap) can act and the distance is not covered within the lag phase, else tick by tick."""
    dt, cap, mass, kk = c.dt, c.cap, c.mass, c.lag_ticks
    a = (c.drive_at_cap - c.resist_at_cap) / mass
    q_t = (1.0 - throttle) * (c.drive_at_cap + c.engine_brake_max) / mass
    q_b = brake * c.brake_max / mass
    last = rho_t.shape[0] - 1
    first = a - q_t * rho_t[0] - q_b * rho_b[0]
    v_end = speed + dt * (kk * a - q_t * c.gt_last - q_b * c.gb_last)
    v_sum = kk * speed + dt * (c.sum_k * a - q_t * c.gt_sum - q_b * c.gb_sum)
    covered = dt * (v_sum + 0.5 * (speed - v_end))
    # The bound's acceleration only grows with k, so the speed bound is valley-shaped: it cannot
    # reach 0 if even K ticks at the first (lowest) acceleration would not, and its largest
    # value is at an end of the lag phase.
    if speed + kk * dt * min(first, 0.0) >= 0.0 and max(speed, v_end) <= cap and covered < distance:
        a_end = a - q_t * rho_t[last] - q_b * rho_b[last]
        return c.lag_time + _tail_time(distance - covered, v_end, a_end, cap)
    raw, v, accel, speeds = speed, speed, 0.0, 0.0
    for k in range(last + 1):
        accel = a - q_t * rho_t[k] - q_b * rho_b[k]
        raw += dt * accel
        v = min(max(raw, 0.0), cap)  # clamping only lowers the bound
        speeds += v
        covered = dt * (speeds + 0.5 * (speed - v))
        if covered >= distance:
            return (k + 1) * dt
    return c.lag_time + _tail_time(max(distance - covered, 0.0), v, accel, cap)


@jit
def _north_arrival(progress: float, speed: float, c: CertifiedConstants) -> float:
    """Earliest time the north car can enter its zone within the assumptions [s] (0 inside,
    ``inf`` once it has left)."""
    if progress > c.north_exit:
        return math.inf
    a = c.north_accel
    top = max(c.north_top, speed)  # best effort if already faster
    distance = max(c.north_enter - progress, 0.0)
    to_top = (top * top - speed * speed) / (2.0 * a)
    if distance <= to_top:
        return (math.sqrt(speed * speed + 2.0 * a * distance) - speed) / a
    return (top - speed) / a + (distance - to_top) / top


@jit
def _stop_ok(
    progress: float,
    speed: float,
    throttle: float,
    brake: float,
    c: CertifiedConstants,
    rho_t: FloatArray,
    rho_b: FloatArray,
) -> bool:
    """Full braking ends before the ego's zone entry (the quick bound first)."""
    room = (c.ego_enter - progress) / c.progress_factor
    if _quick_stop_distance(speed, c) <= room:
        return True
    if room < 0.0:
        return False
    return _stop_distance(speed, throttle, brake, c, rho_t, rho_b) <= room


@jit
def _clear_ok(
    progress: float,
    speed: float,
    throttle: float,
    brake: float,
    arrival: float,
    c: CertifiedConstants,
    rho_t: FloatArray,
    rho_b: FloatArray,
) -> bool:
    """Full throttle leaves the ego's zone ``time_margin_s`` before the north car can enter."""
    distance = c.progress_factor * max(c.ego_exit - progress, 0.0)
    deadline = arrival - c.time_margin
    return _clear_time(distance, speed, throttle, brake, c, rho_t, rho_b) <= deadline


@jit
def _certified(
    low: float,
    high: float,
    speed: float,
    throttle: float,
    brake: float,
    arrival: float,
    c: CertifiedConstants,
    rho_t: FloatArray,
    rho_b: FloatArray,
) -> bool:
    """The certificate with the ego's progress known within ``[low, high]``: the stop backup
    judged at the highest progress, the clear backup at the lowest."""
    if math.isinf(arrival) or low > c.ego_exit:
        return True
    if _stop_ok(high, speed, throttle, brake, c, rho_t, rho_b):
        return True
    return _clear_ok(low, speed, throttle, brake, arrival, c, rho_t, rho_b)


@jit
def _settled(progress: float, speed: float, north_progress: float, c: CertifiedConstants) -> bool:
    """No learned action can matter: the conflict is over, or even after a tick of the hardest
    acceleration the plant can give, a full brake (quick bound) still stops before the zone."""
    if north_progress > c.north_exit or progress > c.ego_exit:
        return True
    dt, f = c.dt, c.progress_factor
    top = speed + c.accel_max * dt
    room = (c.ego_enter - (progress + top * dt * f)) / f
    return _quick_stop_distance(top, c) <= room


@jit
def _predict(
    progress: float,
    speed: float,
    throttle: float,
    brake: float,
    throttle_cmd: float,
    brake_cmd: float,
    c: CertifiedConstants,
    k: VehicleConstants,
) -> tuple[float, float, float, float, float]:
    """The ego one tick ahead under the given pedals, on the plant's own longitudinal model
    (:func:`~safeswitch.sim.vehicle.longitudinal_tick`): progress bounds (low, high) — the path
    length over the tick is known within ``progress_factor`` of the speed-integrated step —,
    speed, throttle and brake."""
    next_throttle, next_brake, next_speed = longitudinal_tick(
        speed, throttle, brake, throttle_cmd, brake_cmd, k
    )
    step = 0.5 * (speed + next_speed) * c.dt
    f = c.progress_factor
    return progress + step / f, progress + step * f, next_speed, next_throttle, next_brake


@jit
def _decide(
    progress: FloatArray,
    speed: FloatArray,
    throttle: FloatArray,
    brake: FloatArray,
    north_progress: FloatArray,
    north_speed: FloatArray,
    learned: FloatArray,
    c: CertifiedConstants,
    rho_t: FloatArray,
    rho_b: FloatArray,
    k: VehicleConstants,
    use: BoolArray,
    reason: NDArray[np.int8],
    pedals: FloatArray,
) -> None:
    """The filter, element by element (:func:`certify_one`), written into ``use``, ``reason``
    and ``pedals``."""
    for i in range(progress.shape[0]):
        switch, code, go = certify_one(
            progress[i], speed[i], throttle[i], brake[i], north_progress[i], north_speed[i],
            learned[i, 0], learned[i, 1], c, rho_t, rho_b, k,
        )  # fmt: skip
        if switch:
            use[i], reason[i] = True, code
            pedals[i, 0] = 1.0 if go else 0.0
            pedals[i, 1] = 0.0 if go else 1.0


@jit
def certify_one(
    progress: float, speed: float, throttle: float, brake: float, north_progress: float,
    north_speed: float, throttle_cmd: float, brake_cmd: float, c: CertifiedConstants,
    rho_t: FloatArray, rho_b: FloatArray, k: VehicleConstants,
) -> tuple[bool, int, bool]:  # fmt: skip
    """The filter for one episode and learned pedals: a state the screen settles keeps them; else
    the certificate of the state after one learned tick, and where it fails the backup. Returns
    (switch to a backup, reason code, the backup accelerates — else it brakes)."""
    if _settled(progress, speed, north_progress, c):
        return False, 0, False
    low, high, next_speed, next_throttle, next_brake = _predict(
        progress, speed, throttle, brake, throttle_cmd, brake_cmd, c, k
    )
    arrival = _north_arrival(north_progress, north_speed, c)
    # The north car may arrive one tick sooner after the learned tick.
    if _certified(
        low, high, next_speed, next_throttle, next_brake, arrival - c.dt, c, rho_t, rho_b
    ):
        return False, 0, False
    # Stop where it can; else clear; else best effort: brake before the zone, go inside it.
    if _stop_ok(progress, speed, throttle, brake, c, rho_t, rho_b):
        return True, STOP, False
    if _clear_ok(progress, speed, throttle, brake, arrival, c, rho_t, rho_b):
        return True, CLEAR, True
    if progress < c.ego_enter:
        return True, NO_BACKUP_BRAKE, False
    return True, NO_BACKUP_CLEAR, True


@jit
def _map_predict(
    progress: FloatArray,
    speed: FloatArray,
    throttle: FloatArray,
    brake: FloatArray,
    pedals: FloatArray,
    c: CertifiedConstants,
    k: VehicleConstants,
    out: FloatArray,
) -> None:
    for i in range(progress.shape[0]):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3], out[i, 4] = _predict(
            progress[i], speed[i], throttle[i], brake[i], pedals[i, 0], pedals[i, 1], c, k
        )


@jit
def _map_stop_distance(
    speed: FloatArray,
    throttle: FloatArray,
    brake: FloatArray,
    c: CertifiedConstants,
    rho_t: FloatArray,
    rho_b: FloatArray,
    out: NDArray[Any],
) -> None:
    for i in range(speed.shape[0]):
        out[i] = _stop_distance(speed[i], throttle[i], brake[i], c, rho_t, rho_b)


@jit
def _map_clear_time(
    distance: FloatArray,
    speed: FloatArray,
    throttle: FloatArray,
    brake: FloatArray,
    c: CertifiedConstants,
    rho_t: FloatArray,
    rho_b: FloatArray,
    out: NDArray[Any],
) -> None:
    for i in range(speed.shape[0]):
        out[i] = _clear_time(distance[i], speed[i], throttle[i], brake[i], c, rho_t, rho_b)


@jit
def _map_quick_stop_distance(speed: FloatArray, c: CertifiedConstants, out: NDArray[Any]) -> None:
    for i in range(speed.shape[0]):
        out[i] = _quick_stop_distance(speed[i], c)


@jit
def _map_north_arrival(
    progress: FloatArray, speed: FloatArray, c: CertifiedConstants, out: NDArray[Any]
) -> None:
    for i in range(progress.shape[0]):
        out[i] = _north_arrival(progress[i], speed[i], c)


@jit
def _map_certified(
    low: FloatArray,
    high: FloatArray,
    speed: FloatArray,
    throttle: FloatArray,
    brake: FloatArray,
    arrival: FloatArray,
    c: CertifiedConstants,
    rho_t: FloatArray,
    rho_b: FloatArray,
    out: NDArray[Any],
) -> None:
    for i in range(low.shape[0]):
        out[i] = _certified(
            low[i], high[i], speed[i], throttle[i], brake[i], arrival[i], c, rho_t, rho_b
        )


@jit
def _map_settled(
    progress: FloatArray,
    speed: FloatArray,
    north_progress: FloatArray,
    c: CertifiedConstants,
    out: NDArray[Any],
) -> None:
    for i in range(progress.shape[0]):
        out[i] = _settled(progress[i], speed[i], north_progress[i], c)


def _columns(*values: FloatArray | float) -> list[FloatArray]:
    """The values as contiguous float64 vectors of one common length (what the compiled
    functions take)."""
    return broadcast_flat(*values)[1]


class CertifiedSwitching:
    """The certified switching logic (see the module docstring).

    Args:
        config: Assumptions and margins.
        vehicle: Ego vehicle parameters (the plant model the bounds are computed on).
        dt: Tick length [s].
        ego_zone: ``(enter, exit)`` arc lengths of the ego's conflict zone [m], computed with
            ``config.zone_margin_m``.
        north_zone: ``(enter, exit)`` of the north car's conflict zone [m].
    """

    reasons: tuple[str, ...] = (
        "learned",
        "backup_stop",
        "backup_clear",
        "no_certified_backup_brake",
        "no_certified_backup_clear",
    )
    assert reasons.index("no_certified_backup_clear") == NO_BACKUP_CLEAR

    def __init__(
        self,
        config: CertifiedConfig,
        vehicle: VehicleParams,
        dt: float,
        ego_zone: tuple[float, float],
        north_zone: tuple[float, float],
    ) -> None:
        self.config = config
        self.vehicle = vehicle
        self.dt = dt
        self.ego_zone = ego_zone
        self.north_zone = north_zone
        p = vehicle
        grip = p.friction_coefficient * p.mass * GRAVITY
        #: The plant's longitudinal model the learned tick is predicted with.
        self._plant = plant = vehicle_constants(vehicle, dt)
        k = np.arange(1, config.lag_ticks + 1, dtype=np.float64)
        throttle_decay = (1.0 - plant.alpha_throttle) ** k  # ρ_t^k, [K]
        brake_decay = (1.0 - plant.alpha_brake) ** k  # ρ_b^k, [K]
        # Forces that bound the backups [N].
        drive_max = min(p.max_drive_force, grip * p.driven_axle_load_fraction)
        brake_max = min(p.max_brake_force, grip)
        cap = config.clear_speed_cap
        # A cheap, looser stop bound for the easy cases (far from the zone): from the worst
        # pedal positions (throttle 1, brake 0), accelerate at the largest drive force for the
        # whole lag phase, then brake at the lag phase's last (weakest) deceleration.
        decel_tail_worst = float(
            (brake_max * (1.0 - brake_decay[-1]) - drive_max * throttle_decay[-1]) / p.mass
        )
        if decel_tail_worst <= 0:
            raise ValueError(
                f"certified.lag_ticks={config.lag_ticks} is too short: after it the brake "
                "cannot yet overcome a fully open throttle; increase it"
            )
        # Sums for the closed forms: Σk, and the last value and sum of the partial sums of ρ^k.
        kk = config.lag_ticks
        gt, gb = np.cumsum(throttle_decay), np.cumsum(brake_decay)
        c = CertifiedConstants(
            dt=dt,
            mass=p.mass,
            brake_max=brake_max,
            drive_max=drive_max,
            drive_at_cap=drive_force(cap, plant),
            resist_at_cap=resistance(cap, plant),
            engine_brake_max=p.max_engine_brake_force,
            cap=cap,
            lag_time=kk * dt,
            accel_max=drive_max / p.mass,
            decel_tail_worst=decel_tail_worst,
            ego_enter=ego_zone[0],
            ego_exit=ego_zone[1],
            north_enter=north_zone[0],
            north_exit=north_zone[1],
            north_accel=config.north_max_accel,
            north_top=config.north_max_speed_kmh / 3.6,
            progress_factor=config.progress_factor,
            time_margin=config.time_margin_s,
            lag_ticks=float(kk),
            sum_k=kk * (kk + 1) / 2.0,
            gt_last=float(gt[-1]),
            gb_last=float(gb[-1]),
            gt_sum=float(gt.sum()),
            gb_sum=float(gb.sum()),
        )
        self._c = c
        #: Everything the compiled bounds read: constants, ρ_t^k and ρ_b^k.
        self._tables = (c, throttle_decay, brake_decay)

    # -- bounds (each element through the compiled scalar functions) ------------------------

    def stop_distance(
        self, speed: FloatArray, throttle: FloatArray, brake: FloatArray
    ) -> FloatArray:
        """Upper bound on the distance driven under full brake until standstill [m], from the
        current speed and actual pedal positions (the throttle decays and the brake builds up
        with their lags)."""
        v, th, br = _columns(speed, throttle, brake)
        out = np.empty(v.shape[0])
        _map_stop_distance(v, th, br, *self._tables, out)
        return out

    def quick_stop_distance(self, speed: FloatArray) -> FloatArray:
        """A looser upper bound on :meth:`stop_distance`, valid for any pedal positions [m]."""
        (v,) = _columns(speed)
        out = np.empty(v.shape[0])
        _map_quick_stop_distance(v, self._c, out)
        return out

    def clear_time(
        self, distance: FloatArray, speed: FloatArray, throttle: FloatArray, brake: FloatArray
    ) -> FloatArray:
        """Upper bound on the time to drive ``distance`` [m] under full throttle [s]."""
        d, v, th, br = _columns(distance, speed, throttle, brake)
        out = np.empty(d.shape[0])
        _map_clear_time(d, v, th, br, *self._tables, out)
        return out

    def north_arrival(self, progress: FloatArray, speed: FloatArray) -> FloatArray:
        """Earliest time the north car can enter its conflict zone, within the assumptions [s]
        (0 if it is inside, ``inf`` if it has left)."""
        s, v = _columns(progress, speed)
        out = np.empty(s.shape[0])
        _map_north_arrival(s, v, self._c, out)
        return out

    # -- the certificate --------------------------------------------------------------------

    def safe(
        self,
        progress: FloatArray,
        speed: FloatArray,
        throttle: FloatArray,
        brake: FloatArray,
        north_arrival: FloatArray,
    ) -> BoolArray:
        """The certificate: some backup still avoids sharing the zone with the north car."""
        return self._certify(progress, progress, speed, throttle, brake, north_arrival)

    def _certify(
        self,
        progress_low: FloatArray,
        progress_high: FloatArray,
        speed: FloatArray,
        throttle: FloatArray,
        brake: FloatArray,
        north_arrival: FloatArray,
    ) -> BoolArray:
        """:meth:`safe` with the ego's progress known only within ``[low, high]``: the stop
        backup is judged at the highest progress, the clear backup at the lowest."""
        low, high, v, th, br, arrival = _columns(
            progress_low, progress_high, speed, throttle, brake, north_arrival
        )
        out = np.empty(low.shape[0], dtype=np.bool_)
        _map_certified(low, high, v, th, br, arrival, *self._tables, out)
        return out

    def settled(self, state: ConflictState) -> BoolArray:
        """Elements the learned action cannot make unsafe, whatever it is: the conflict is over
        (the north car has left its zone, or the ego its own), or even after a tick of the
        hardest acceleration the plant can give, a full brake (loose bound) still stops before
        the ego's zone. :meth:`decide` certifies only the rest."""
        out = np.empty(state.ego_speed.shape[0], dtype=np.bool_)
        _map_settled(state.ego_progress, state.ego_speed, state.north_progress, self._c, out)
        return out

    def predict(
        self, state: ConflictState, pedals: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """The ego one tick ahead under ``pedals`` ``[B, 2]`` (throttle, brake), with the plant's
        own longitudinal model: progress bounds (low, high), speed, throttle and brake."""
        out = np.empty((state.ego_speed.shape[0], 5))
        s = state
        _map_predict(
            s.ego_progress, s.ego_speed, s.ego_throttle, s.ego_brake,
            np.asarray(pedals, dtype=np.float64), self._c, self._plant, out,
        )  # fmt: skip
        return out[:, 0], out[:, 1], out[:, 2], out[:, 3], out[:, 4]

    def decide(self, state: ConflictState, learned: FloatArray, safe: FloatArray) -> Decision:
        batch = learned.shape[0]
        use = np.zeros(batch, dtype=np.bool_)
        reason = np.zeros(batch, dtype=np.int8)
        action = np.zeros((batch, 2))
        s = state
        _decide(
            s.ego_progress, s.ego_speed, s.ego_throttle, s.ego_brake, s.north_progress,
            s.north_speed, learned, *self._tables, self._plant, use, reason, action,
        )  # fmt: skip
        return Decision(use, reason, action)


def certified_logic(task: LeftTurnTask) -> CertifiedSwitching:
    """Factory of the ``certified`` logic (registered under that name) for a left-turn task:
    the conflict zones recomputed with the certificate's own margin."""
    config = getattr(task, "config", None)
    if not isinstance(getattr(config, "certified", None), CertifiedConfig):
        raise LogicContextError(
            "the 'certified' switching logic supervises the left-turn task, not "
            f"{context_name(task)}"
        )
    c = task.config
    from safeswitch.leftturn.traffic import LeftTurnTrafficTask

    if isinstance(task, LeftTurnTrafficTask):  # in traffic: every conflicting vehicle
        from safeswitch.leftturn.traffic_logics import CertifiedTrafficSwitching

        return CertifiedTrafficSwitching(
            c.certified, c.vehicle, c.episode.dt, task.switching_zones(), task.crossing_zones()
        )
    footprint = (c.vehicle.length, c.vehicle.width)
    ego_route, north_route = task.world.routes
    zones = conflict_geometry(
        ego_route, north_route, footprint, footprint, margin=c.certified.zone_margin_m
    )
    return CertifiedSwitching(c.certified, c.vehicle, c.episode.dt, zones.zone_a, zones.zone_b)
