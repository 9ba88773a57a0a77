"""The certified switching logic: a Simplex-style safety filter with two backups.

**Backups** (rule-based, each with a closed-form bound on what it achieves on the plant model):

* *stop* — full brake until standstill, then hold. Its stopping distance is bounded from the
  current speed and actual pedal positions: the first ``lag_ticks`` ticks follow the actuator
  lags exactly (throttle decaying, brake building up; drive force at its maximum, every
  resistance ignored), after which the weakest remaining deceleration is assumed. Full brake
  rather than ``PID_b``: the bound must be provable, and only the intervention ticks pay in comfort.
* *clear* — leave the conflict zone at the sharpest curve's speed: full throttle up to a
  holding speed, full brake while well above it (:func:`clear_pedals`). Its time to cover a
  distance is bounded the same way from below on the acceleration (drive force at the clearing
  speed bound, full engine braking, resistances there), and from below on the speed once it has
  reached the holding speed.

**Certificate.** Against every conflict of the view at once (the paper's scene has one, the
north car; in traffic every vehicle whose route crosses the ego's): a state is *safe* when the
*stop* backup ends before the entry of the first zone whose vehicle has not left, or the *clear*
backup leaves every such zone ``time_margin_s`` before its vehicle can first enter its own
(accelerating at ``other_max_accel`` up to ``other_max_speed_kmh``: the assumptions hold for
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

**Curves.** The tyres hold the ego within a friction circle (:mod:`safeswitch.sim.vehicle`):
too fast into a curve they slide and the ego leaves its lane. A second certificate keeps that
from ever happening: a state is *stable* when full braking (the stop backup's bound: the lag
phase at up to the plant's largest acceleration, then the weakest deceleration) keeps the
ego's cornering ``v² |κ(s)|`` within ``curve_lateral_accel`` at every point of its route
ahead. The braking envelope behind every curve is computed once per scene
(:class:`CurveEnvelope`). Both backups keep a stable state stable — the stop backup by
construction, the clear backup because it brakes as the stop backup does down to a speed within
every curve's and never exceeds it after — and a learned action is accepted only if the state
after it is stable too; where only stability fails, the filter brakes
(``backup_brake_for_curve``). The envelope is a lower bound on what the tyres allow (5 m/s² of
cornering against μ·g = 8.8 m/s²): braking in the curve still leaves them some grip to turn.

**Vehicles still to come** (a scene in traffic: streams keep bringing vehicles). For every
movement that crosses the ego's, a *phantom* vehicle that could appear at the start of its
approach at any moment, at the assumed top speed, can reach its zone no sooner than ``entry /
other_max_speed`` from now (:class:`~safeswitch.leftturn.views.Phantoms`): the stop backup ends
before every zone the ego has not passed, and the clear backup must beat the phantoms too.
Without them a vehicle appearing on a crossing route could turn the place where the ego waits
into a conflict zone. A vehicle behind the ego is assumed to follow it without running into it
(its car-following brakes up to 8 m/s², as hard as the ego's backup); one that merges ahead of
the ego into its exit lane is assumed to drive on.

**Perception** (:mod:`safeswitch.leftturn.perception`). With the scene's perception bounds
declared (``certified.perception: declared``), every vehicle is read as the worst case its
tracker allows — ``other_lead`` ahead of what is seen, at ``other_speed_high``, and gone from its
zone only once ``other_lag`` behind what is seen is past it. The tracker's bounds at a tick are
never worse than the previous tick's propagated, so the invariant above holds for any errors
within the bounds; vehicles not yet seen are phantoms, brought closer by what the sensor may
miss. Under ``perfect`` the filter takes what it sees as the truth.

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
STOP, CLEAR, NO_BACKUP_BRAKE, NO_BACKUP_CLEAR, CURVE = 1, 2, 3, 4, 5


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
        cap: Clearing speed bound [m/s]: the clear backup's speed, once it has reached it,
            never falls below it (``clear_speed_cap``, or :attr:`clear_hold` less what the
            backup loses with its throttle closed over the lag phase).
        lag_time: Length of the lag phase the bounds follow tick by tick [s].
        accel_max: Largest acceleration the plant can give [m/s²].
        decel_tail_worst: Weakest deceleration after the lag phase from the worst pedals [m/s²].
        other_accel: Assumed largest acceleration of every other vehicle [m/s²].
        other_top: Assumed top speed of every other vehicle [m/s].
        curve_decel: The stop backup's weakest deceleration after the lag phase per metre
            of progress along the route [m/s²] (what the curve envelope assumes).
        clear_hold: The speed the clear backup throttles up to, or brakes down to, and holds
            [m/s] (:func:`clear_pedals`): what it can keep to in the ego route's sharpest
            curve, lags included.
        lag_gain_worst: The most the speed rises in the stop backup's lag phase from the
            worst pedals (full throttle, no brake) [m/s].
        progress_factor: Bound on progress along the route per distance driven.
        progress_jump: How far the progress measured on the route's polyline can jump at a
            waypoint [m]: ``ego_max_lateral_m · tan(spacing · κ_max)`` (a point off the
            polyline changes segment with a step; 0 on a straight route). Added to each
            bound once, on top of ``progress_factor`` (which covers the jumps on average).
        time_margin: Margin between the ego leaving a zone and its vehicle entering its own [s].
        lag_ticks: Ticks of the lag phase (a float: it enters the closed forms).
        sum_k: ``Σ k`` over the lag phase.
        gt_last: Last partial sum of ``ρ_t^k``.
        gb_last: Last partial sum of ``ρ_b^k``.
        gt_sum: Sum of the partial sums of ``ρ_t^k``.
        gb_sum: Sum of the partial sums of ``ρ_b^k``.
        robust: 1 under ``perception: declared`` (the other vehicles' states are read as the
            worst case the tracker allows: ahead by ``other_lead``, at ``other_speed_high``,
            left only once ``other_lag`` behind the estimate is past the zone), 0 under
            ``perfect`` (the estimate is taken as the truth).
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
    curve_decel: float
    clear_hold: float
    lag_gain_worst: float
    progress_factor: float
    progress_jump: float
    time_margin: float
    lag_ticks: float
    sum_k: float
    gt_last: float
    gb_last: float
    gt_sum: float
    gb_sum: float
    robust: float


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


class CurveEnvelope(NamedTuple):
    """The ego's route as the curve certificate reads it (arc lengths on the route [m]).

    Attributes:
        spacing: Waypoint spacing of the ego's route [m].
        decel: The stop backup's weakest deceleration per metre of progress [m/s²].
        curve: Per segment between two waypoints, the largest squared speed at which the ego
            keeps within ``curve_lateral_accel`` on it (the sharper of its two waypoints'
            curvatures) [m²/s²] ``[N − 1]`` (``inf`` where straight).
        node: At each waypoint, a lower bound on the largest squared speed from which braking
            at ``decel`` meets every later segment's curve speed [m²/s²] ``[N]``.
    """

    spacing: float
    decel: float
    curve: FloatArray
    node: FloatArray

    @classmethod
    def of_route(
        cls, spacing: float, curvature: FloatArray, lateral_accel: float, decel: float
    ) -> CurveEnvelope:
        """The envelope of a route with ``|κ|`` at its waypoints, a cornering limit [m/s²] and a
        deceleration per metre of progress along the route [m/s²]."""
        sharpest = np.maximum(curvature[:-1], curvature[1:])
        curve = np.where(sharpest > 0, lateral_accel / np.maximum(sharpest, 1e-12), np.inf)
        # Backwards: each segment counted whole from its start (a lower bound).
        node = np.full(len(curvature), np.inf)
        for i in range(len(curve) - 1, -1, -1):
            node[i] = min(curve[i], node[i + 1] + 2.0 * decel * spacing)
        return cls(float(spacing), float(decel), curve, node)


@jit
def _segment(progress: float, spacing: float, segments: int) -> int:
    """The route segment at ``progress`` (0 before the route, ``segments`` past its end)."""
    return min(max(int(progress // spacing), 0), segments)


@jit
def _envelope_window(
    low: float, high: float, spacing: float, decel: float, curve: FloatArray, node: FloatArray
) -> tuple[float, float]:
    """Over the stretch ``[low, high]`` of the route: the smallest curve speed and the smallest
    braking envelope, both squared [m²/s²]. The envelope at ``x`` in segment ``i`` is
    ``min(curve_i, node_{i+1} + 2·decel·(x_{i+1} − x))``, a lower bound on the largest squared
    speed from which braking meets every curve from ``x`` on; it falls by at most ``2·decel``
    per metre (what makes the certificate hold along the stop backup's own path)."""
    segments = curve.shape[0]
    lowest_curve, lowest = math.inf, math.inf
    for i in range(_segment(low, spacing, segments), _segment(high, spacing, segments) + 1):
        if i >= segments:
            break
        end = (i + 1) * spacing
        lowest_curve = min(lowest_curve, curve[i])
        lowest = min(lowest, curve[i], node[i + 1] + 2.0 * decel * max(end - high, 0.0))
    return lowest_curve, lowest


@jit
def _stable_quick(progress: float, peak: float, c: CertifiedConstants, e: CurveEnvelope) -> bool:
    """A sufficient condition for :func:`_stable` at no cost: with every speed of the stop's
    lag phase at most ``peak`` and every position within the stretch it can cover, the
    envelope where the stretch begins leaves room for the whole stretch."""
    low = progress - c.progress_jump
    reach = progress + c.progress_jump + c.progress_factor * c.lag_time * peak
    _, lowest = _envelope_window(low, low, e.spacing, e.decel, e.curve, e.node)
    return peak * peak + 2.0 * e.decel * (reach - low) <= lowest


@jit
def _stable(
    progress: float, speed: float, throttle: float, brake: float, t: Bounds, e: CurveEnvelope
) -> bool:
    """Full braking from ``progress`` at ``speed`` (with the pedals at ``throttle`` and
    ``brake``) keeps the ego's cornering within ``curve_lateral_accel``: tick by tick through
    the lag phase (the speed bound and the reach of :func:`_stop_distance`'s deceleration
    bounds), the speed within every curve the ego can be on, and at its end within the
    braking envelope everywhere the ego can be."""
    c, rho_t, rho_b = t
    a = c.brake_max / c.mass
    b = a * (1.0 - brake)
    cc = c.drive_max / c.mass * throttle
    f, dt = c.progress_factor, c.dt
    low, high, v = progress - c.progress_jump, progress + c.progress_jump, speed
    # The smallest curve speed over [low, high], kept as ``high`` grows: each segment is read
    # once (the same minimum as _envelope_window's, which would re-read the stretch each tick).
    segments = e.curve.shape[0]
    i, lowest_curve = _segment(low, e.spacing, segments), math.inf
    for k in range(rho_t.shape[0]):
        v_next = max(v - dt * (a - b * rho_b[k] - cc * rho_t[k]), 0.0)
        high += f * dt * 0.5 * (v + v_next)
        top = max(v, v_next)
        last = min(_segment(high, e.spacing, segments), segments - 1)
        while i <= last:
            lowest_curve = min(lowest_curve, e.curve[i])
            i += 1
        if top * top > lowest_curve:
            return False
        v = v_next
    # At its end: the speed within every curve up to a tick further on, and within the braking
    # envelope wherever the ego can be, with the room of a tick's braking besides — what the
    # same check, made again a tick later, asks of that tick (so the certificate holds along
    # the stop backup's own path).
    _, lowest = _envelope_window(low, high, e.spacing, e.decel, e.curve, e.node)
    further, _ = _envelope_window(low, high + f * dt * v, e.spacing, e.decel, e.curve, e.node)
    return v * v <= further and v * v + 2.0 * e.decel * f * dt * v <= lowest


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
    length over the tick is known within ``progress_factor`` of the speed-integrated step, and
    the progress measured on the route's polyline may jump by ``progress_jump`` at a waypoint —,
    speed, throttle and brake."""
    next_throttle, next_brake, next_speed = longitudinal_tick(
        speed, throttle, brake, throttle_cmd, brake_cmd, k
    )
    step = 0.5 * (speed + next_speed) * c.dt
    f, jump = c.progress_factor, c.progress_jump
    low, high = progress + step / f - jump, progress + step * f + jump
    return low, high, next_speed, next_throttle, next_brake


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
    distance = t.c.progress_factor * max(leave - progress + t.c.progress_jump, 0.0)
    return arrive - t.c.time_margin - _clear_time(distance, speed, throttle, brake, t)


@jit
def _seen_arrival(v: ConflictView, b: int, j: int, c: CertifiedConstants) -> float:
    """:func:`_arrival` of conflict ``j`` of episode ``b`` as the view shows it: under declared
    perception the worst case the tracker allows (the vehicle ``other_lead`` ahead of its
    estimate, at ``other_speed_high``, and left only once ``other_lag`` behind the estimate is
    past the zone), else the estimate itself."""
    r = c.robust
    lead, lag = r * v.other_lead[b, j], r * v.other_lag[b, j]
    speed = v.other_speed[b, j] + r * (v.other_speed_high[b, j] - v.other_speed[b, j])
    zone = v.other_cert_zone
    return _arrival(v.other_progress[b, j] + lead, speed, zone[b, j, 0],
                    zone[b, j, 1] + lead + lag, c)  # fmt: skip


@jit
def _arrivals(v: ConflictView, b: int, c: CertifiedConstants, out: FloatArray) -> None:
    """Each conflict's earliest entry into its zone in episode ``b`` (``inf``: no conflict, or
    its vehicle has left) into ``out`` ``[C]``."""
    present = v.present
    for j in range(out.shape[0]):
        out[j] = math.inf
        if present[b, j]:
            out[j] = _seen_arrival(v, b, j, c)


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
    room = (first - (progress + top * dt * f + 2.0 * c.progress_jump)) / f
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
    room = (first_entry - high - t.c.progress_jump) / t.c.progress_factor
    stop_ok = room >= 0.0 and (
        _quick_stop_distance(speed, t.c) <= room
        or _stop_distance(speed, throttle, brake, t) <= room
    )
    return stop_ok, clear_ok


@jit
def clear_pedals(speed: float, throttle: float, c: CertifiedConstants) -> tuple[float, float]:
    """The clear backup's pedals (throttle, brake) at ``speed`` with the throttle actually at
    ``throttle``: full throttle up to :attr:`CertifiedConstants.clear_hold`; above it the
    throttle closed, and full braking while ``v + a·t·throttle`` — the speed with what the
    throttle still open can add over a lag phase — exceeds ``clear_hold + a·t``. So the ego
    brakes for the curves as the stop backup does, never exceeds ``clear_hold + a·t`` after
    (within every curve's speed), and never drops below the speed its time bound counts on."""
    lag = c.accel_max * c.lag_time
    if speed + c.accel_max * c.dt <= c.clear_hold:
        return 1.0, 0.0
    if speed + lag * throttle > c.clear_hold + lag:
        return 0.0, 1.0
    return 0.0, 0.0


@jit
def _decide(
    v: ConflictView, phantoms: Phantoms, envelope: CurveEnvelope, learned: FloatArray,
    t: Bounds, k: VehicleConstants, use: BoolArray, reason: NDArray[np.int8],
    pedals: FloatArray,
) -> None:  # fmt: skip
    """The filter, episode by episode: a state the screen settles keeps the learned pedals;
    else the certificates (conflicts and curves) of the state after one learned tick, and
    where either fails a backup."""
    # The tuples' arrays are taken out once: numba would otherwise fetch each array, and count
    # a reference to it, on every access inside the loop.
    ego_progress, ego_speed, ego_throttle, ego_brake = (
        v.ego_progress, v.ego_speed, v.ego_throttle, v.ego_brake
    )  # fmt: skip
    present, zones = v.present, v.ego_cert_zone
    other_progress, other_speed, other_zones = v.other_progress, v.other_speed, v.other_cert_zone
    lead_of, lag_of, speed_high = v.other_lead, v.other_lag, v.other_speed_high
    phantom_zones, phantom_entry = phantoms.ego_zone, phantoms.entry
    c = t.c
    step = c.dt * c.progress_factor
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
                # As _seen_arrival, written out (see the screen's note).
                lead, lag = c.robust * lead_of[b, j], c.robust * lag_of[b, j]
                seen = other_speed[b, j]
                arrivals[j] = _arrival(other_progress[b, j] + lead,
                                       seen + c.robust * (speed_high[b, j] - seen),
                                       other_zones[b, j, 0], other_zones[b, j, 1] + lead + lag,
                                       c)  # fmt: skip
                if not math.isinf(arrivals[j]) and s <= zones[b, j, 1]:
                    first = min(first, zones[b, j, 0])
        for p in range(phantom_zones.shape[0]):
            if s <= phantom_zones[p, 1]:
                first = min(first, phantom_zones[p, 0])
        top = speed + c.accel_max * c.dt  # after a tick of the hardest acceleration
        settled = _settled(s, speed, first, c)
        if settled and _stable_quick(
            s + top * step + c.progress_jump, top + c.lag_gain_worst, c, envelope
        ):
            continue
        low, high, v1, th1, br1 = _predict(
            s, speed, throttle, brake, learned[b, 0], learned[b, 1], c, k
        )
        # A settled state stays free of conflicts whatever the learned tick: only its curves
        # are left to certify. Else the vehicles may arrive one tick sooner after that tick.
        conflicts_ok = settled
        if not settled:
            stop1, clear1 = _safe(low, high, v1, th1, br1, present, zones, arrivals, b, c.dt,
                                  phantom_zones, phantom_entry, t)  # fmt: skip
            conflicts_ok = stop1 or clear1
        # The quick curve bound first (sufficient for _stable, as in the screen), now with the
        # speed the learned tick gives rather than the hardest acceleration's.
        if conflicts_ok and (
            _stable_quick(high, v1 + c.lag_gain_worst, c, envelope)
            or _stable(high, v1, th1, br1, t, envelope)
        ):
            continue
        stop0, clear0 = _safe(s, s, speed, throttle, brake, present, zones, arrivals, b, 0.0,
                              phantom_zones, phantom_entry, t)  # fmt: skip
        use[b] = True
        # No conflict ahead: only the curve failed, brake for it. Else stop where it can;
        # else clear; else best effort: brake before the first zone, go inside it.
        if math.isinf(first):
            reason[b], pedals[b, 0], pedals[b, 1] = CURVE, 0.0, 1.0
        elif stop0:
            reason[b], pedals[b, 0], pedals[b, 1] = STOP, 0.0, 1.0
        elif clear0:
            pedals[b, 0], pedals[b, 1] = clear_pedals(speed, throttle, c)
            reason[b] = CLEAR
        elif s < first:
            reason[b], pedals[b, 0], pedals[b, 1] = NO_BACKUP_BRAKE, 0.0, 1.0
        else:
            pedals[b, 0], pedals[b, 1] = clear_pedals(speed, throttle, c)
            reason[b] = NO_BACKUP_CLEAR


@jit
def _margins(
    v: ConflictView, t: Bounds, arrival: FloatArray, slack: FloatArray, room: FloatArray
) -> None:
    """Fill :meth:`CertifiedSwitching.margins` (``inf`` where there is no conflict)."""
    present, c = v.present, t.c
    for b in range(present.shape[0]):
        s, speed = v.ego_progress[b], v.ego_speed[b]
        throttle, brake = v.ego_throttle[b], v.ego_brake[b]
        stop = math.nan  # computed once per episode, where some conflict needs it
        for j in range(present.shape[1]):
            if not present[b, j]:
                continue
            arrive = _seen_arrival(v, b, j, c)
            arrival[b, j] = arrive
            if not math.isinf(arrive):
                slack[b, j] = _clear_slack(
                    s, v.ego_cert_zone[b, j, 1], arrive, speed, throttle, brake, t
                )
                if math.isnan(stop):
                    stop = _stop_distance(speed, throttle, brake, t)
                # As _safe's stop backup counts the room, against this zone alone.
                ahead = (v.ego_cert_zone[b, j, 0] - s - c.progress_jump) / c.progress_factor
                room[b, j] = ahead - stop


@jit
def _screen(
    v: ConflictView, phantoms: Phantoms, envelope: CurveEnvelope, c: CertifiedConstants,
    out: BoolArray,
) -> None:  # fmt: skip
    present, zones = v.present, v.ego_cert_zone
    arrivals = np.empty(present.shape[1])
    for b in range(present.shape[0]):
        _arrivals(v, b, c, arrivals)
        s, speed = v.ego_progress[b], v.ego_speed[b]
        first = _first_entry(s, present, zones, arrivals, b, phantoms.ego_zone)
        top = speed + c.accel_max * c.dt
        out[b] = _settled(s, speed, first, c) and _stable_quick(
            s + top * c.dt * c.progress_factor + c.progress_jump, top + c.lag_gain_worst, c,
            envelope,
        )  # fmt: skip


@jit
def _certificate(
    v: ConflictView, phantoms: Phantoms, envelope: CurveEnvelope, pedals: FloatArray,
    t: Bounds, k: VehicleConstants, out: BoolArray,
) -> None:  # fmt: skip
    """Per episode: both certificates hold at the view's state (``pedals`` empty) or after
    one tick of ``pedals`` ``[B, 2]`` (the vehicles a tick closer, as :func:`_decide`
    judges)."""
    present, zones = v.present, v.ego_cert_zone
    arrivals = np.empty(present.shape[1])
    for b in range(present.shape[0]):
        _arrivals(v, b, t.c, arrivals)
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
        out[b] = (stop or clear) and _stable(high, speed, throttle, brake, t, envelope)


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
        curvature: The ego's route: its waypoint spacing [m] and ``|κ|`` at its waypoints
            [1/m] (``None``: a straight road, no curve to keep within).
    """

    reasons: tuple[str, ...] = (
        "learned",
        "backup_stop",
        "backup_clear",
        "no_certified_backup_brake",
        "no_certified_backup_clear",
        "backup_brake_for_curve",
    )
    assert reasons.index("backup_brake_for_curve") == CURVE

    def __init__(
        self,
        config: CertifiedConfig,
        vehicle: VehicleParams,
        dt: float,
        phantoms: Phantoms | None = None,
        curvature: tuple[float, FloatArray] | None = None,
    ) -> None:
        if config.curve_lateral_accel >= vehicle.friction_coefficient * GRAVITY:
            raise ValueError(
                f"certified.curve_lateral_accel={config.curve_lateral_accel!r} must be below "
                f"the tyres' μ·g = {vehicle.friction_coefficient * GRAVITY:.2f} m/s²"
            )
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
        # The lower bounds on the stop backup's deceleration tick by tick from the worst pedals
        # (full throttle, no brake), as _stop_distance has them.
        worst = (brake_max * (1.0 - brake_decay) - drive_max * throttle_decay) / p.mass
        lag_gain_worst = float(np.max(np.concatenate([[0.0], np.cumsum(-worst * dt)])))
        curve_decel = decel_tail_worst / config.progress_factor
        spacing, kappa = curvature if curvature is not None else (1.0, np.zeros(2))
        #: The speeds along the ego's route from which braking keeps its cornering within
        #: ``curve_lateral_accel``.
        self.envelope = CurveEnvelope.of_route(
            spacing, np.asarray(kappa, dtype=np.float64), config.curve_lateral_accel,
            curve_decel,
        )  # fmt: skip
        # The clear backup: to a speed whose peak — the throttle's lag after it closes, then a
        # stop's lag — stays within the sharpest curve's; once there, it never falls below the
        # speed it loses over a lag phase with the throttle closed.
        accel_max, lag_time = drive_max / p.mass, config.lag_ticks * dt
        sharpest = float(np.sqrt(np.min(self.envelope.curve)))
        hold = sharpest - lag_gain_worst - accel_max * lag_time
        coast = (p.max_engine_brake_force + resistance(max(hold, 0.0), plant)) / p.mass
        cap = min(config.clear_speed_cap, max(hold - coast * lag_time, 0.5))
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
            other_accel=config.other_max_accel,
            other_top=config.other_max_speed_kmh / 3.6,
            curve_decel=curve_decel,
            clear_hold=min(hold, config.clear_speed_cap),
            lag_gain_worst=lag_gain_worst,
            progress_factor=config.progress_factor,
            progress_jump=float(config.ego_max_lateral_m * np.tan(spacing * np.max(np.abs(kappa)))),
            time_margin=config.time_margin_s,
            lag_ticks=float(kk),
            sum_k=kk * (kk + 1) / 2.0,
            gt_last=float(gt[-1]),
            gb_last=float(gb[-1]),
            gt_sum=float(gt.sum()),
            gb_sum=float(gb.sum()),
            robust=1.0 if config.perception == "declared" else 0.0,
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
        _screen(view, self.phantoms, self.envelope, self._c, out)
        return out

    def safe(self, view: ConflictView) -> BoolArray:
        """The certificates at the view's state: some backup still avoids sharing a zone with
        any vehicle, and the state is within the curve envelope."""
        out = np.empty(view.batch_size, dtype=np.bool_)
        _certificate(
            view, self.phantoms, self.envelope, np.empty((0, 2)), self.bounds, self._plant, out
        )
        return out

    def accepts(self, view: ConflictView, pedals: FloatArray) -> BoolArray:
        """The certificate after one tick of ``pedals`` ``[B, 2]`` (throttle, brake), with the
        vehicles a tick closer: exactly what :meth:`decide` requires of a learned action the
        screen does not settle."""
        out = np.empty(view.batch_size, dtype=np.bool_)
        pedals = np.ascontiguousarray(pedals, dtype=np.float64)
        _certificate(view, self.phantoms, self.envelope, pedals, self.bounds, self._plant, out)
        return out

    def predict(
        self, view: ConflictView, pedals: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """The ego one tick ahead under ``pedals`` ``[B, 2]`` (throttle, brake), with the plant's
        own longitudinal model: progress bounds (low, high), speed, throttle and brake."""
        out = np.empty((view.batch_size, 5))
        _predict_all(view, np.asarray(pedals, dtype=np.float64), self._c, self._plant, out)
        return out[:, 0], out[:, 1], out[:, 2], out[:, 3], out[:, 4]

    def margins(self, view: ConflictView) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Per conflict ``[B, C]``: the earliest time the vehicle can enter its zone within the
        assumptions [s] (0 inside, ``inf`` once it has left or where there is no conflict);
        the certificate's slack for it [s]: that time less the margin and the clear backup's
        time to leave the ego's zone from now (negative: full throttle now would not clear it
        in time); and the stop backup's room before the ego's zone [m]: the distance the
        certificate counts to its entry less the full brake's stopping distance from the
        current speed and pedals (negative: braking now would not stop before it; ``inf``
        where the slack is)."""
        arrival = np.full(view.present.shape, np.inf)
        slack = np.full(view.present.shape, np.inf)
        room = np.full(view.present.shape, np.inf)
        _margins(view, self.bounds, arrival, slack, room)
        return arrival, slack, room

    def decide(self, state: ConflictView, learned: FloatArray, safe: FloatArray) -> Decision:
        batch = learned.shape[0]
        use = np.zeros(batch, dtype=np.bool_)
        reason = np.zeros(batch, dtype=np.int8)
        action = np.zeros((batch, 2))
        _decide(
            state, self.phantoms, self.envelope, learned, self.bounds, self._plant, use, reason,
            action,
        )  # fmt: skip
        return Decision(use, reason, action)


def certified_logic(scene: LogicScene) -> CertifiedSwitching:
    """Factory of the ``certified`` logic for a left-turn scene (the name is registered by
    :func:`safeswitch.logics.certified_logic`, which serves highway-env too): its assumptions
    and margins from the scene's configuration, and the scene's phantoms."""
    if not isinstance(scene, LogicScene):
        raise LogicContextError(
            "the 'certified' switching logic supervises the left-turn task, not "
            f"{context_name(scene)}"
        )
    c = scene.config
    return CertifiedSwitching(
        c.certified, c.vehicle, c.episode.dt, scene.phantoms(), scene.ego_curvature()
    )
