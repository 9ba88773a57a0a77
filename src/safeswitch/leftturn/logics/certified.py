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

**Certificate.** Against every conflict of the view at once (the paper's scene has one, the
north car; in traffic every vehicle whose route crosses the ego's): a state is *safe* when the
*stop* backup ends before the entry of the first zone whose vehicle has not left, or the *clear*
backup leaves every such zone ``time_margin_s`` before its vehicle can first enter its own
(accelerating at ``north_max_accel`` up to ``north_max_speed_kmh``: the assumptions hold for
every other vehicle, the north car's name is historical). A conflict is over once its vehicle
has left its zone or the ego its own. The learned action is executed exactly when
the state after one tick of it — predicted with the plant's own longitudinal model, actuator
lags included — is safe. Otherwise the filter executes a backup that is feasible now, preferring
*stop* (it is robust to any behaviour of the north car once the ego stands before the zone).

**Invariant.** From a safe state, either action keeps the state safe: the learned one by the
check, a backup because its bound at the next tick is no larger than at this one (the bounds are
monotone along their own trajectories) while the north car, within the assumptions, cannot
arrive earlier than its bound said. Safe states never collide: the zones are computed from the
footprints with a margin covering the ego's lateral deviation. So no learned action sequence —
random, adversarial, NaN — leads to a collision while the assumptions hold.

**Vehicles still to come** (a scene in traffic: streams keep bringing vehicles). For every
movement that crosses the ego's, a *phantom* vehicle that could appear at the start of its
approach at any moment, at the assumed top speed, can reach its zone no sooner than ``entry /
north_max_speed`` from now (:class:`~safeswitch.leftturn.views.Phantoms`): the stop backup ends
before every zone the ego has not passed, and the clear backup must beat the phantoms too.
Without them a vehicle appearing on a crossing route could turn the place where the ego waits
into a conflict zone. A vehicle behind the ego is assumed to follow it without running into it
(its car-following brakes up to 8 m/s², as hard as the ego's backup); one that merges ahead of
the ego into its exit lane is assumed to drive on.

If no backup is feasible (only when the assumptions were broken), the filter brakes fully while
the ego is still before its first zone and accelerates fully once it is inside (best effort),
and the reason says so.

**Implementation.** The bounds follow the lag phase tick by tick, per element, in scalar code
compiled with numba: a few dozen floating-point operations per element instead of a few hundred
numpy calls per batch, so the filter costs little at any batch size. The learned tick is
predicted inside the same loop with the plant's own compiled
:func:`~safeswitch.sim.vehicle.longitudinal_tick`, so the filter and the plant cannot disagree
about it. A cheap screen (:meth:`CertifiedSwitching.settled`) passes the states no learned
action can make unsafe before the certificate is computed. One kernel serves every scene; the
numpy-facing methods (:meth:`CertifiedSwitching.stop_distance`,
:meth:`~CertifiedSwitching.clear_time`, …) run the same compiled functions through
:func:`~safeswitch.core.arrays.each`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import each, jit
from safeswitch.core.registry import LogicContextError, context_name
from safeswitch.core.switching import BoolArray, Decision, FloatArray
from safeswitch.leftturn.config import CertifiedConfig
from safeswitch.leftturn.views import ConflictView, LogicScene, Phantoms
from safeswitch.sim.vehicle import (
    GRAVITY,
    VehicleConstants,
    VehicleParams,
    drive_force,
    longitudinal_tick,
    resistance,
    vehicle_constants,
)

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
        other_accel: Assumed largest acceleration of every other vehicle [m/s²].
        other_top: Assumed top speed of every other vehicle [m/s].
        progress_factor: Bound on progress along the route per distance driven.
        time_margin: Margin between the ego leaving a zone and its vehicle entering its own [s].
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
    other_accel: float
    other_top: float
    progress_factor: float
    time_margin: float
    lag_ticks: float
    sum_k: float
    gt_last: float
    gb_last: float
    gt_sum: float
    gb_sum: float


class Bounds(NamedTuple):
    """Everything the compiled bounds read: the constants and the lag phase's decay factors.

    Attributes:
        c: The scalars.
        rho_t: ``ρ_t^k`` for ``k = 1 … K``: the share of the throttle's gap left ``[K]``.
        rho_b: ``ρ_b^k``, the same for the brake ``[K]``.
    """

    c: CertifiedConstants
    rho_t: FloatArray
    rho_b: FloatArray


@jit
def _stop_distance(
    speed: float,
    throttle: float,
    brake: float,
    t: Bounds,
) -> float:
    """Upper bound on the full-brake stopping distance [m]: on lag tick ``k`` the deceleration
    is at least ``A − B·ρ_b^k − C·ρ_t^k`` (the brake force built up, minus the largest drive
    force of the decaying throttle; resistances ignored); after the lag phase, its last value.
    Closed form while the car still moves at the end of the lag phase, else tick by tick."""
    c, rho_t, rho_b = t
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
    t: Bounds,
) -> float:
    """Upper bound on the time to drive ``distance`` [m] under full throttle [s]: on lag tick
    ``k`` the acceleration is at least ``A − P·ρ_t^k − Q·ρ_b^k`` (the throttle's drive force at
    the clearing speed cap minus full engine braking of its closed part, the releasing brake and
    the resistances at the cap). Closed form when no clamp of the speed bound (at 0 or at the
    cap) can act and the distance is not covered within the lag phase, else tick by tick."""
    c, rho_t, rho_b = t
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
def _arrival(
    progress: float, speed: float, enter: float, leave: float, c: CertifiedConstants
) -> float:
    """Earliest entry of a vehicle into its zone ``[enter, leave]`` within the assumptions [s]
    (0 inside, ``inf`` once it has left)."""
    if progress > leave:
        return math.inf
    a = c.other_accel
    top = max(c.other_top, speed)  # best effort if already faster
    distance = max(enter - progress, 0.0)
    to_top = (top * top - speed * speed) / (2.0 * a)
    if distance <= to_top:
        return (math.sqrt(speed * speed + 2.0 * a * distance) - speed) / a
    return (top - speed) / a + (distance - to_top) / top


@jit
def _clear_slack(
    progress: float, leave: float, arrive: float, speed: float, throttle: float, brake: float,
    t: Bounds,
) -> float:  # fmt: skip
    """The clear backup's time to spare against a vehicle that can enter its zone ``arrive``
    seconds from now [s]: that time less the margin and the backup's time for the ego at
    ``progress`` to leave its own zone at ``leave`` (negative: the backup fails)."""
    distance = t.c.progress_factor * max(leave - progress, 0.0)
    return arrive - t.c.time_margin - _clear_time(distance, speed, throttle, brake, t)


@jit
def _arrivals(
    present: BoolArray, other_progress: FloatArray, other_speed: FloatArray,
    other_zones: FloatArray, b: int, c: CertifiedConstants, out: FloatArray,
) -> None:  # fmt: skip
    """Each conflict's earliest entry into its zone in episode ``b`` (``inf``: no conflict, or
    its vehicle has left) into ``out`` ``[C]``."""
    for j in range(out.shape[0]):
        out[j] = math.inf
        if present[b, j]:
            out[j] = _arrival(other_progress[b, j], other_speed[b, j], other_zones[b, j, 0],
                              other_zones[b, j, 1], c)  # fmt: skip


@jit
def _first_entry(
    progress: float, present: BoolArray, zones: FloatArray, arrivals: FloatArray, b: int,
    phantom_zones: FloatArray,
) -> float:  # fmt: skip
    """The entry of the first zone still ahead of the ego at ``progress`` in episode ``b``
    whose vehicle has not left (a phantom's included) [m]; ``inf`` if none."""
    first = math.inf
    for j in range(present.shape[1]):
        if present[b, j] and not math.isinf(arrivals[j]) and progress <= zones[b, j, 1]:
            first = min(first, zones[b, j, 0])
    for p in range(phantom_zones.shape[0]):
        if progress <= phantom_zones[p, 1]:
            first = min(first, phantom_zones[p, 0])
    return first


@jit
def _settled(progress: float, speed: float, first: float, c: CertifiedConstants) -> bool:
    """No learned action can matter: no conflict is left ahead (``first``, the entry of the
    first zone ahead, is ``inf``), or even after a tick of the hardest acceleration the plant
    can give, a full brake (quick bound) still stops before that zone."""
    if math.isinf(first):
        return True
    dt, f = c.dt, c.progress_factor
    top = speed + c.accel_max * dt
    room = (first - (progress + top * dt * f)) / f
    return _quick_stop_distance(top, c) <= room


@jit
def _safe(
    low: float, high: float, speed: float, throttle: float, brake: float, present: BoolArray,
    zones: FloatArray, arrivals: FloatArray, b: int, shift: float, phantom_zones: FloatArray,
    phantom_entry: FloatArray, t: Bounds,
) -> tuple[bool, bool]:  # fmt: skip
    """(stop backup ok, clear backup ok) in episode ``b`` for the ego's progress known within
    ``[low, high]`` (the stop backup judged at the highest, the clear backup at the lowest),
    with the vehicles' arrivals brought ``shift`` seconds closer (a phantom's arrival is the
    same from any moment on)."""
    first_entry = math.inf
    relevant = False
    clear_ok = True
    conflicts = present.shape[1]
    for k in range(conflicts + phantom_entry.shape[0]):
        if k < conflicts:
            if not present[b, k] or math.isinf(arrivals[k]) or low > zones[b, k, 1]:
                continue
            enter, leave, arrive = zones[b, k, 0], zones[b, k, 1], arrivals[k] - shift
        else:
            p = k - conflicts
            enter, leave = phantom_zones[p, 0], phantom_zones[p, 1]
            arrive = phantom_entry[p] / t.c.other_top
            if low > leave:
                continue
        relevant = True
        first_entry = min(first_entry, enter)
        if clear_ok and _clear_slack(low, leave, arrive, speed, throttle, brake, t) < 0.0:
            clear_ok = False
    if not relevant:
        return True, True
    room = (first_entry - high) / t.c.progress_factor
    stop_ok = room >= 0.0 and (
        _quick_stop_distance(speed, t.c) <= room
        or _stop_distance(speed, throttle, brake, t) <= room
    )
    return stop_ok, clear_ok


@jit
def _decide(
    v: ConflictView, phantoms: Phantoms, learned: FloatArray, t: Bounds, k: VehicleConstants,
    use: BoolArray, reason: NDArray[np.int8], pedals: FloatArray,
) -> None:  # fmt: skip
    """The filter, episode by episode: a state the screen settles keeps the learned pedals;
    else the certificate of the state after one learned tick, and where it fails a backup."""
    # The tuples' arrays are taken out once: numba would otherwise fetch each array, and count
    # a reference to it, on every access inside the loop.
    ego_progress, ego_speed, ego_throttle, ego_brake = (
        v.ego_progress, v.ego_speed, v.ego_throttle, v.ego_brake
    )  # fmt: skip
    present, zones = v.present, v.ego_cert_zone
    other_progress, other_speed, other_zones = v.other_progress, v.other_speed, v.other_cert_zone
    phantom_zones, phantom_entry = phantoms.ego_zone, phantoms.entry
    c = t.c
    conflicts = present.shape[1]
    arrivals = np.empty(conflicts)
    for b in range(present.shape[0]):
        s, speed = ego_progress[b], ego_speed[b]
        throttle, brake = ego_throttle[b], ego_brake[b]
        # The screen, written out here: this loop runs for every episode on every tick, and a
        # helper taking the arrays would cost more than the arithmetic (see jit).
        first = math.inf
        for j in range(conflicts):
            arrivals[j] = math.inf
            if present[b, j]:
                arrivals[j] = _arrival(other_progress[b, j], other_speed[b, j],
                                       other_zones[b, j, 0], other_zones[b, j, 1], c)  # fmt: skip
                if not math.isinf(arrivals[j]) and s <= zones[b, j, 1]:
                    first = min(first, zones[b, j, 0])
        for p in range(phantom_zones.shape[0]):
            if s <= phantom_zones[p, 1]:
                first = min(first, phantom_zones[p, 0])
        if _settled(s, speed, first, c):
            continue
        low, high, v1, th1, br1 = _predict(
            s, speed, throttle, brake, learned[b, 0], learned[b, 1], c, k
        )
        # The vehicles may arrive one tick sooner after the learned tick.
        stop1, clear1 = _safe(low, high, v1, th1, br1, present, zones, arrivals, b, c.dt,
                              phantom_zones, phantom_entry, t)  # fmt: skip
        if stop1 or clear1:
            continue
        stop0, clear0 = _safe(s, s, speed, throttle, brake, present, zones, arrivals, b, 0.0,
                              phantom_zones, phantom_entry, t)  # fmt: skip
        use[b] = True
        # Stop where it can; else clear; else best effort: brake before the first zone, go
        # inside it.
        if stop0:
            reason[b], pedals[b, 0], pedals[b, 1] = STOP, 0.0, 1.0
        elif clear0:
            reason[b], pedals[b, 0], pedals[b, 1] = CLEAR, 1.0, 0.0
        elif s < first:
            reason[b], pedals[b, 0], pedals[b, 1] = NO_BACKUP_BRAKE, 0.0, 1.0
        else:
            reason[b], pedals[b, 0], pedals[b, 1] = NO_BACKUP_CLEAR, 1.0, 0.0


@jit
def _margins(v: ConflictView, t: Bounds, arrival: FloatArray, slack: FloatArray) -> None:
    """Fill :meth:`CertifiedSwitching.margins` (``inf`` where there is no conflict)."""
    present, zones, other = v.present, v.other_cert_zone, v.other_progress
    for b in range(present.shape[0]):
        for j in range(present.shape[1]):
            if not present[b, j]:
                continue
            arrive = _arrival(other[b, j], v.other_speed[b, j], zones[b, j, 0], zones[b, j, 1],
                              t.c)  # fmt: skip
            arrival[b, j] = arrive
            if not math.isinf(arrive):
                slack[b, j] = _clear_slack(
                    v.ego_progress[b], v.ego_cert_zone[b, j, 1], arrive, v.ego_speed[b],
                    v.ego_throttle[b], v.ego_brake[b], t,
                )  # fmt: skip


@jit
def _screen(v: ConflictView, phantoms: Phantoms, c: CertifiedConstants, out: BoolArray) -> None:
    present, zones = v.present, v.ego_cert_zone
    arrivals = np.empty(present.shape[1])
    for b in range(present.shape[0]):
        _arrivals(present, v.other_progress, v.other_speed, v.other_cert_zone, b, c, arrivals)
        s = v.ego_progress[b]
        first = _first_entry(s, present, zones, arrivals, b, phantoms.ego_zone)
        out[b] = _settled(s, v.ego_speed[b], first, c)


@jit
def _certificate(
    v: ConflictView, phantoms: Phantoms, pedals: FloatArray, t: Bounds, k: VehicleConstants,
    out: BoolArray,
) -> None:  # fmt: skip
    """Per episode: the certificate holds at the view's state (``pedals`` empty) or after one
    tick of ``pedals`` ``[B, 2]`` (the vehicles a tick closer, as :func:`_decide` judges)."""
    present, zones = v.present, v.ego_cert_zone
    arrivals = np.empty(present.shape[1])
    for b in range(present.shape[0]):
        _arrivals(present, v.other_progress, v.other_speed, v.other_cert_zone, b, t.c, arrivals)
        s = v.ego_progress[b]
        speed, throttle, brake = v.ego_speed[b], v.ego_throttle[b], v.ego_brake[b]
        low, high, shift = s, s, 0.0
        if pedals.shape[0]:
            low, high, speed, throttle, brake = _predict(
                s, speed, throttle, brake, pedals[b, 0], pedals[b, 1], t.c, k
            )
            shift = t.c.dt
        stop, clear = _safe(low, high, speed, throttle, brake, present, zones, arrivals, b,
                            shift, phantoms.ego_zone, phantoms.entry, t)  # fmt: skip
        out[b] = stop or clear


@jit
def _predict_all(v: ConflictView, pedals: FloatArray, c: CertifiedConstants, k: VehicleConstants,
                 out: FloatArray) -> None:  # fmt: skip
    for b in range(out.shape[0]):
        out[b, 0], out[b, 1], out[b, 2], out[b, 3], out[b, 4] = _predict(
            v.ego_progress[b], v.ego_speed[b], v.ego_throttle[b], v.ego_brake[b], pedals[b, 0],
            pedals[b, 1], c, k,
        )  # fmt: skip


class CertifiedSwitching:
    """The certified switching logic (see the module docstring).

    Args:
        config: Assumptions and margins.
        vehicle: Ego vehicle parameters (the plant model the bounds are computed on).
        dt: Tick length [s].
        phantoms: The vehicles still to come (none in the paper's scene).
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
        phantoms: Phantoms | None = None,
    ) -> None:
        self.config = config
        self.vehicle = vehicle
        self.dt = dt
        self.phantoms = Phantoms.none() if phantoms is None else Phantoms(
            np.ascontiguousarray(phantoms.ego_zone, dtype=np.float64),
            np.ascontiguousarray(phantoms.entry, dtype=np.float64),
        )  # fmt: skip
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
            other_accel=config.north_max_accel,
            other_top=config.north_max_speed_kmh / 3.6,
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
        self.bounds = Bounds(c, throttle_decay, brake_decay)

    # -- bounds (each element through the compiled scalar functions) ------------------------

    def stop_distance(
        self, speed: FloatArray, throttle: FloatArray, brake: FloatArray
    ) -> FloatArray:
        """Upper bound on the distance driven under full brake until standstill [m], from the
        current speed and actual pedal positions (the throttle decays and the brake builds up
        with their lags)."""
        return each(_stop_distance, self.bounds, speed, throttle, brake)

    def quick_stop_distance(self, speed: FloatArray) -> FloatArray:
        """A looser upper bound on :meth:`stop_distance`, valid for any pedal positions [m]."""
        return each(_quick_stop_distance, self._c, speed)

    def clear_time(
        self, distance: FloatArray, speed: FloatArray, throttle: FloatArray, brake: FloatArray
    ) -> FloatArray:
        """Upper bound on the time to drive ``distance`` [m] under full throttle [s]."""
        return each(_clear_time, self.bounds, distance, speed, throttle, brake)

    def arrival(
        self, progress: FloatArray, speed: FloatArray, enter: FloatArray, leave: FloatArray
    ) -> FloatArray:
        """Earliest time a vehicle at ``progress`` can enter its zone ``[enter, leave]``,
        within the assumptions [s] (0 if it is inside, ``inf`` if it has left)."""
        return each(_arrival, self._c, progress, speed, enter, leave)

    # -- the certificate --------------------------------------------------------------------

    def settled(self, view: ConflictView) -> BoolArray:
        """Episodes the learned action cannot make unsafe, whatever it is: no conflict is left
        ahead, or even after a tick of the hardest acceleration the plant can give, a full
        brake (loose bound) still stops before the first zone ahead. :meth:`decide`
        certifies only the rest."""
        out = np.empty(view.batch_size, dtype=np.bool_)
        _screen(view, self.phantoms, self._c, out)
        return out

    def safe(self, view: ConflictView) -> BoolArray:
        """The certificate at the view's state: some backup still avoids sharing a zone with
        any vehicle."""
        out = np.empty(view.batch_size, dtype=np.bool_)
        _certificate(view, self.phantoms, np.empty((0, 2)), self.bounds, self._plant, out)
        return out

    def accepts(self, view: ConflictView, pedals: FloatArray) -> BoolArray:
        """The certificate after one tick of ``pedals`` ``[B, 2]`` (throttle, brake), with the
        vehicles a tick closer: exactly what :meth:`decide` requires of a learned action the
        screen does not settle."""
        out = np.empty(view.batch_size, dtype=np.bool_)
        pedals = np.ascontiguousarray(pedals, dtype=np.float64)
        _certificate(view, self.phantoms, pedals, self.bounds, self._plant, out)
        return out

    def predict(
        self, view: ConflictView, pedals: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """The ego one tick ahead under ``pedals`` ``[B, 2]`` (throttle, brake), with the plant's
        own longitudinal model: progress bounds (low, high), speed, throttle and brake."""
        out = np.empty((view.batch_size, 5))
        _predict_all(view, np.asarray(pedals, dtype=np.float64), self._c, self._plant, out)
        return out[:, 0], out[:, 1], out[:, 2], out[:, 3], out[:, 4]

    def margins(self, view: ConflictView) -> tuple[FloatArray, FloatArray]:
        """Per conflict ``[B, C]``: the earliest time the vehicle can enter its zone within the
        assumptions [s] (0 inside, ``inf`` once it has left or where there is no conflict), and
        the certificate's slack for it [s]: that time less the margin and the clear backup's
        time to leave the ego's zone from now (negative: full throttle now would not clear it
        in time)."""
        arrival = np.full(view.present.shape, np.inf)
        slack = np.full(view.present.shape, np.inf)
        _margins(view, self.bounds, arrival, slack)
        return arrival, slack

    def decide(self, state: ConflictView, learned: FloatArray, safe: FloatArray) -> Decision:
        batch = learned.shape[0]
        use = np.zeros(batch, dtype=np.bool_)
        reason = np.zeros(batch, dtype=np.int8)
        action = np.zeros((batch, 2))
        _decide(state, self.phantoms, learned, self.bounds, self._plant, use, reason, action)
        return Decision(use, reason, action)


def certified_logic(scene: LogicScene) -> CertifiedSwitching:
    """Factory of the ``certified`` logic (registered under that name) for a left-turn scene:
    its assumptions and margins from the scene's configuration, and the scene's phantoms."""
    if not isinstance(scene, LogicScene):
        raise LogicContextError(
            "the 'certified' switching logic supervises the left-turn task, not "
            f"{context_name(scene)}"
        )
    c = scene.config
    return CertifiedSwitching(c.certified, c.vehicle, c.episode.dt, scene.phantoms())
