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
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import clamp
from safeswitch.core.switching import BoolArray, Decision, FloatArray
from safeswitch.leftturn.config import CertifiedConfig
from safeswitch.leftturn.switching import ConflictState
from safeswitch.sim.vehicle import (
    AIR_DENSITY,
    GRAVITY,
    VehicleParams,
    lag_factor,
    longitudinal_force,
)

STOP, CLEAR = 1, 2


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
        self._alpha_throttle = lag_factor(p.throttle_time_constant, dt)
        self._alpha_brake = lag_factor(p.brake_time_constant, dt)
        k = np.arange(1, config.lag_ticks + 1, dtype=np.float64)
        self._throttle_decay = (1.0 - self._alpha_throttle) ** k  # ρ_t^k, [K]
        self._brake_decay = (1.0 - self._alpha_brake) ** k  # ρ_b^k, [K]
        # Forces that bound the backups [N].
        self._drive_max = min(p.max_drive_force, grip * p.driven_axle_load_fraction)
        self._brake_max = min(p.max_brake_force, grip)
        cap = config.clear_speed_cap
        self._drive_at_cap = min(self._drive_max, p.max_power / cap)
        self._resist_at_cap = (
            p.rolling_resistance * p.mass * GRAVITY + 0.5 * AIR_DENSITY * p.drag_area * cap * cap
        )
        self._north_max_speed = config.north_max_speed_kmh / 3.6
        # Closed forms of the stop bound (see stop_distance): the deceleration on tick k is
        # A − B·ρ_b^k − C·ρ_t^k, so its partial sums and their sums are constants times B, C.
        kk = config.lag_ticks
        self._decel_full = self._brake_max / p.mass  # A
        gb, gt = np.cumsum(self._brake_decay), np.cumsum(self._throttle_decay)
        self._sum_k = kk * (kk + 1) / 2.0  # sum_k k
        self._gb_last, self._gt_last = float(gb[-1]), float(gt[-1])
        self._gb_sum, self._gt_sum = float(gb.sum()), float(gt.sum())
        # A cheap, looser stop bound for the easy cases (far from the zone): from the worst
        # pedal positions (throttle 1, brake 0), accelerate at the largest drive force for the
        # whole lag phase, then brake at the lag phase's last (weakest) deceleration.
        self._lag_time = config.lag_ticks * dt
        self._accel_max = self._drive_max / p.mass
        self._decel_tail_worst = (
            self._brake_max * (1.0 - self._brake_decay[-1])
            - self._drive_max * self._throttle_decay[-1]
        ) / p.mass
        if self._decel_tail_worst <= 0:
            raise ValueError(
                f"certified.lag_ticks={config.lag_ticks} is too short: after it the brake "
                "cannot yet overcome a fully open throttle; increase it"
            )

    # -- bounds ------------------------------------------------------------------------------

    def stop_distance(
        self, speed: FloatArray, throttle: FloatArray, brake: FloatArray
    ) -> FloatArray:
        """Upper bound on the distance driven under full brake until standstill [m].

        On tick ``k`` of the lag phase the deceleration is at least ``A − B·ρ_b^k − C·ρ_t^k``
        (brake force building up, drive force of the decaying throttle at its maximum,
        resistances ignored). Where the car is still moving at the end of the lag phase the
        sums have closed forms; where it stops within it, :meth:`_stop_distance_by_tick` follows
        the ticks.

        Args:
            speed: Current speed [m/s] ``[N]``.
            throttle: Actual throttle position ``[N]`` (it decays with the actuator lag).
            brake: Actual brake position ``[N]`` (it builds up with the lag).
        """
        dt, kk = self.dt, self.config.lag_ticks
        b = self._decel_full * (1.0 - brake)  # B
        c = (self._drive_max / self.vehicle.mass) * throttle  # C
        v_end = speed - dt * (kk * self._decel_full - b * self._gb_last - c * self._gt_last)
        v_sum = kk * speed - dt * (
            self._sum_k * self._decel_full - b * self._gb_sum - c * self._gt_sum
        )
        decel_end = self._decel_full - b * self._brake_decay[-1] - c * self._throttle_decay[-1]
        distance = dt * (v_sum + 0.5 * (speed - v_end)) + v_end * v_end / (2.0 * decel_end)
        stops_early = np.flatnonzero(v_end <= 0.0)
        if stops_early.size:
            distance[stops_early] = self._stop_distance_by_tick(
                speed[stops_early], throttle[stops_early], brake[stops_early]
            )
        return distance

    def _stop_distance_by_tick(
        self, speed: FloatArray, throttle: FloatArray, brake: FloatArray
    ) -> FloatArray:
        """:meth:`stop_distance` tick by tick (also right when the car stops in the lag)."""
        p, dt = self.vehicle, self.dt
        # Deceleration lower bound on tick k: brake force minus the largest drive force.
        decel = (
            self._brake_max * (1.0 - (1.0 - brake)[:, None] * self._brake_decay)
            - self._drive_max * throttle[:, None] * self._throttle_decay
        ) / p.mass
        # It grows with k, so once the speed reaches 0 it stays there: clamping is exact.
        v = np.maximum(speed[:, None] - dt * np.cumsum(decel, axis=1), 0.0)
        # Trapezoids: sum_k (v_{k-1} + v_k) / 2 = sum_k v_k + (v_0 - v_K) / 2.
        lag_distance = dt * (v.sum(axis=1) + 0.5 * (speed - v[:, -1]))
        return lag_distance + v[:, -1] ** 2 / (2.0 * decel[:, -1])

    def quick_stop_distance(self, speed: FloatArray) -> FloatArray:
        """A looser upper bound on :meth:`stop_distance`, valid for any pedal positions [m]."""
        t, a = self._lag_time, self._accel_max
        top = speed + a * t
        return (speed + 0.5 * a * t) * t + top * top / (2.0 * self._decel_tail_worst)

    def clear_time(
        self, distance: FloatArray, speed: FloatArray, throttle: FloatArray, brake: FloatArray
    ) -> FloatArray:
        """Upper bound on the time to drive ``distance`` [m] under full throttle [s].

        On tick ``k`` of the lag phase the acceleration is at least ``A − P·ρ_t^k − Q·ρ_b^k``
        (throttle building up, brake releasing; drive force at the clearing speed cap, full
        engine braking of the closed part, resistances at the cap). Where no clamp of the speed
        bound (at 0 or at the cap) can act and the distance is not covered within the lag phase,
        the sums have closed forms; elsewhere :meth:`_clear_time_by_tick` follows the ticks.
        """
        p, dt, kk, cap = self.vehicle, self.dt, self.config.lag_ticks, self.config.clear_speed_cap
        a_full = (self._drive_at_cap - self._resist_at_cap) / p.mass  # A
        q_throttle = (1.0 - throttle) * (self._drive_at_cap + p.max_engine_brake_force) / p.mass
        q_brake = brake * self._brake_max / p.mass
        first = a_full - q_throttle * self._throttle_decay[0] - q_brake * self._brake_decay[0]
        v_end = speed + dt * (kk * a_full - q_throttle * self._gt_last - q_brake * self._gb_last)
        v_sum = kk * speed + dt * (
            self._sum_k * a_full - q_throttle * self._gt_sum - q_brake * self._gb_sum
        )
        covered = dt * (v_sum + 0.5 * (speed - v_end))
        a_end = a_full - q_throttle * self._throttle_decay[-1] - q_brake * self._brake_decay[-1]
        # The bound's acceleration only grows with k, so the speed bound is valley-shaped: it
        # cannot reach 0 if even K ticks at the first (lowest) acceleration would not, and its
        # largest value is at an end of the lag phase.
        stays_positive = speed + kk * dt * np.minimum(first, 0.0) >= 0.0
        simple = stays_positive & (np.maximum(speed, v_end) <= cap) & (covered < distance)
        time = np.empty_like(distance)
        time[simple] = self._lag_time + self._tail_time(
            distance[simple] - covered[simple], v_end[simple], a_end[simple]
        )
        rest = np.flatnonzero(~simple)
        if rest.size:
            time[rest] = self._clear_time_by_tick(
                distance[rest], speed[rest], throttle[rest], brake[rest]
            )
        return time

    def _tail_time(self, rest: FloatArray, v: FloatArray, a: FloatArray) -> FloatArray:
        """Time to drive ``rest`` [m] from speed ``v`` at constant acceleration ``a`` up to
        the clearing speed cap, then at the cap [s]."""
        cap = self.config.clear_speed_cap
        with np.errstate(divide="ignore", invalid="ignore"):
            to_cap = np.where(a > 0, (cap * cap - v * v) / (2.0 * a), np.inf)
            accelerating = np.where(
                a > 0,
                (np.sqrt(v * v + 2.0 * a * rest) - v) / a,
                np.where(v > 0, rest / v, np.inf),
            )
            capped = np.where(a > 0, (cap - v) / a + (rest - to_cap) / cap, np.inf)
        return np.where(rest <= to_cap, accelerating, capped)

    def _clear_time_by_tick(
        self, distance: FloatArray, speed: FloatArray, throttle: FloatArray, brake: FloatArray
    ) -> FloatArray:
        """:meth:`clear_time` tick by tick (also right when a clamp acts or the distance is
        covered within the lag phase)."""
        p, dt, cap = self.vehicle, self.dt, self.config.clear_speed_cap
        throttle_k = 1.0 - (1.0 - throttle)[:, None] * self._throttle_decay
        brake_k = brake[:, None] * self._brake_decay
        engine_brake = p.max_engine_brake_force * (1.0 - throttle_k)
        accel = (
            throttle_k * self._drive_at_cap
            - engine_brake
            - brake_k * self._brake_max
            - self._resist_at_cap
        ) / p.mass
        # Lower bound on the speed (clamping at 0 and at the cap only lowers it further).
        v = clamp(speed[:, None] + dt * np.cumsum(accel, axis=1), 0.0, cap)
        # Trapezoids up to tick k: sum_{j<=k} v_j + (v_0 - v_k) / 2.
        covered = dt * (np.cumsum(v, axis=1) + 0.5 * (speed[:, None] - v))
        reached = covered >= distance[:, None]
        time = np.where(reached.any(axis=1), (np.argmax(reached, axis=1) + 1) * dt, np.inf)
        rest = np.maximum(distance - covered[:, -1], 0.0)
        tail = self._tail_time(rest, v[:, -1], accel[:, -1])
        return np.where(np.isfinite(time), time, self._lag_time + tail)

    def north_arrival(self, progress: FloatArray, speed: FloatArray) -> FloatArray:
        """Earliest time the north car can enter its conflict zone, within the assumptions [s]
        (0 if it is inside, ``inf`` if it has left)."""
        a = self.config.north_max_accel
        top = np.maximum(self._north_max_speed, speed)  # best effort if already faster
        distance = np.maximum(self.north_zone[0] - progress, 0.0)
        to_top = (top * top - speed * speed) / (2.0 * a)
        time = np.where(
            distance <= to_top,
            (np.sqrt(speed * speed + 2.0 * a * distance) - speed) / a,
            (top - speed) / a + (distance - to_top) / top,
        )
        return np.where(progress > self.north_zone[1], np.inf, time)

    # -- the certificate --------------------------------------------------------------------

    def stop_feasible(
        self, progress: FloatArray, speed: FloatArray, throttle: FloatArray, brake: FloatArray
    ) -> BoolArray:
        """Full braking ends before the ego's conflict-zone entry."""
        room = (self.ego_zone[0] - progress) / self.config.progress_factor
        ok = self.quick_stop_distance(speed) <= room
        near = np.flatnonzero(~ok & (room >= 0))
        if near.size:
            ok[near] = self.stop_distance(speed[near], throttle[near], brake[near]) <= room[near]
        return ok

    def clear_feasible(
        self,
        progress: FloatArray,
        speed: FloatArray,
        throttle: FloatArray,
        brake: FloatArray,
        north_arrival: FloatArray,
    ) -> BoolArray:
        """Full throttle leaves the ego's zone ``time_margin_s`` before the north car can enter."""
        distance = self.config.progress_factor * np.maximum(self.ego_zone[1] - progress, 0.0)
        deadline = north_arrival - self.config.time_margin_s
        return self.clear_time(distance, speed, throttle, brake) <= deadline

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
        backup is judged at the highest progress, the clear backup at the lowest. Cheap tests
        first; the exact bounds run only on what they leave undecided."""
        ok = np.isinf(north_arrival) | (progress_low > self.ego_zone[1])
        rest = np.flatnonzero(~ok)
        if rest.size:
            ok[rest] = self.stop_feasible(
                progress_high[rest], speed[rest], throttle[rest], brake[rest]
            )
            rest = rest[~ok[rest]]
        if rest.size:
            ok[rest] = self.clear_feasible(
                progress_low[rest], speed[rest], throttle[rest], brake[rest], north_arrival[rest]
            )
        return ok

    def predict(
        self, state: ConflictState, pedals: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """The ego one tick ahead under ``pedals`` ``[B, 2]`` (throttle, brake), with the plant's
        own longitudinal model: progress bounds (low, high), speed, throttle and brake."""
        p, dt = self.vehicle, self.dt
        throttle = state.ego_throttle + self._alpha_throttle * (pedals[:, 0] - state.ego_throttle)
        brake = state.ego_brake + self._alpha_brake * (pedals[:, 1] - state.ego_brake)
        accel = longitudinal_force(p, state.ego_speed, throttle, brake) / p.mass
        speed = np.maximum(state.ego_speed + accel * dt, 0.0)
        step = 0.5 * (state.ego_speed + speed) * dt
        f = self.config.progress_factor
        return (
            state.ego_progress + step / f,
            state.ego_progress + step * f,
            speed,
            throttle,
            brake,
        )

    def settled(self, state: ConflictState) -> BoolArray:
        """Elements the learned action cannot make unsafe, whatever it is: the conflict is over
        (the north car has left its zone, or the ego its own), or even after a tick of the
        hardest acceleration the plant can give, a full brake (loose bound) still stops before
        the ego's zone. A cheap screen; :meth:`decide` certifies only the rest."""
        f, dt = self.config.progress_factor, self.dt
        top = state.ego_speed + self._accel_max * dt  # no pedal accelerates the car harder
        room = (self.ego_zone[0] - (state.ego_progress + top * dt * f)) / f
        return (
            (self.quick_stop_distance(top) <= room)
            | (state.north_progress > self.north_zone[1])
            | (state.ego_progress > self.ego_zone[1])
        )

    def decide(self, state: ConflictState, learned: FloatArray, safe: FloatArray) -> Decision:
        batch = learned.shape[0]
        use = np.zeros(batch, dtype=bool)
        rest = np.flatnonzero(~self.settled(state))
        if rest.size:
            sub = state if rest.size == batch else state.take(rest)
            pedals = learned if rest.size == batch else learned[rest]
            arrival = self.north_arrival(sub.north_progress, sub.north_speed)
            low, high, speed, throttle, brake = self.predict(sub, pedals)
            # The north car may arrive one tick sooner after the learned tick.
            use[rest] = ~self._certify(low, high, speed, throttle, brake, arrival - self.dt)
        reason = np.zeros(batch, dtype=np.int8)
        action = np.zeros((batch, 2))
        idx = np.flatnonzero(use)
        if idx.size:
            arrival = self.north_arrival(state.north_progress[idx], state.north_speed[idx])
            reason[idx], action[idx] = self._backup(state, arrival, idx)
        return Decision(use, reason, action)

    def _backup(
        self, s: ConflictState, arrival: FloatArray, idx: NDArray[np.intp]
    ) -> tuple[NDArray[np.int8], FloatArray]:
        """Reason codes and pedals of the backup for the elements ``idx`` (``arrival``: the
        north car's earliest arrival for those elements)."""
        args = (s.ego_progress[idx], s.ego_speed[idx], s.ego_throttle[idx], s.ego_brake[idx])
        stop = self.stop_feasible(*args)
        clear = ~stop & self.clear_feasible(*args, arrival)
        before_zone = s.ego_progress[idx] < self.ego_zone[0]
        reason = np.where(stop, 1, np.where(clear, 2, np.where(before_zone, 3, 4)))
        go = (reason == 2) | (reason == 4)
        pedals = np.stack([go.astype(np.float64), (~go).astype(np.float64)], axis=1)
        return reason.astype(np.int8), pedals
