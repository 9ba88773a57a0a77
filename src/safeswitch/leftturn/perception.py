"""Perception of the other vehicle: a sensor with noise, latency, missed detections and a sight
distance, and the tracker that turns its sightings into what the ego's software knows.

The paper assumes perfect perception (its Remark 2). Here the plant, collisions and every metric
keep the truth, and everything that decides reads what is seen (:class:`PerceptionConfig`):

* **Sensor** (the world's side). On every tick it reports the other vehicle as it was
  ``latency_s`` ago (exactly: the episode's first ticks see the car's constant-speed approach
  before the episode, extrapolated back), with a position error within ``position_error_m``
  along its path and a speed error within ``speed_error_mps`` — independent and uniform, or, with
  ``errors: adversarial``, the worst case on every tick (farther back and slower, until the
  error can show it past its conflict zone: then farther on and faster, as if it had left); it
  misses a seen vehicle with probability ``dropout_prob`` per tick for up to ``dropout_max_s``,
  then sees it for at least a tick; it never sees a vehicle farther than ``sight_distance_m``
  from its conflict point. Random numbers are a pure function of the scenario and the tick, so
  a scenario replays exactly.
* **Point estimate** (what the paper's logic, the Safety controller's window and the policy's
  observation read): the latest sighting, held while the vehicle is missed; before the first
  one, a vehicle at the edge of the sight distance at the speed limit.
* **Tracker** (what the certified logic reads under ``certified.perception: declared``): the set
  of true states consistent with *every* sighting so far under the declared bounds and the
  certified logic's assumptions on other vehicles (acceleration at most ``other_max_accel``,
  speed at most ``other_max_speed_kmh``, never reversing). An interval ``[low, high]`` on the
  vehicle's progress and a bound ``speed_high`` on its speed: each tick the previous interval is
  propagated over the tick (the worst case accelerates), each sighting gives its own interval
  (its errors, then the latency propagated the same way), and the two are intersected. Because
  each tick's bounds are no worse than the previous tick's propagated, the certificate's
  induction holds as with perfect perception: the vehicle can arrive no sooner than the bound
  said a tick before, and once ``low`` is past its zone it has left. A vehicle missed for any
  time keeps its propagated interval; one never seen is beyond the sight edge ``latency_s +
  dropout_max_s`` (and a tick) ago, at most at the top speed since.

One compiled loop per tick (:func:`_sense`) does all of it for every episode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import jit
from safeswitch.sim.geometry import pose

if TYPE_CHECKING:
    from safeswitch.leftturn.config import LeftTurnConfig
    from safeswitch.sim.geometry import RouteSet

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Stand-in for an unbounded distance behind (a vehicle never seen): finite, so that a logic
#: that ignores the tracker can multiply it by 0.
FAR = 1.0e9

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


class PerceptionConstants(NamedTuple):
    """What the compiled sensor and tracker read (built by :class:`Perception`).

    Attributes:
        dt: Tick [s].
        latency: Latency in ticks.
        dropout_ticks: Longest miss in ticks.
        dropout_prob: Chance per tick that a miss starts.
        position_error: Bound on the position error [m].
        speed_error: Bound on the speed error [m/s].
        sight: Sight distance from the conflict point [m] (``inf``: none).
        adversarial: Worst-case errors instead of random ones.
        point: The vehicle's conflict point on its route [m].
        exit: Exit of its conflict zone on its route [m] (where adversarial errors turn).
        other_accel: Assumed largest acceleration of the vehicle [m/s²].
        other_top: Assumed top speed [m/s].
        unseen_high: Upper bound on the progress of a vehicle never seen [m].
        unseen_speed: Speed of the point estimate of a vehicle never seen [m/s].
        spacing: Waypoint spacing of the routes [m].
        k_max: Last segment index of a route.
        base: Flat index of the vehicle's route's first waypoint.
    """

    dt: float
    latency: int
    dropout_ticks: int
    dropout_prob: float
    position_error: float
    speed_error: float
    sight: float
    adversarial: bool
    point: float
    exit: float
    other_accel: float
    other_top: float
    unseen_high: float
    unseen_speed: float
    spacing: float
    k_max: int
    base: int


@dataclass
class PerceptionState:
    """The sensor's and the tracker's state for ``B`` episodes (the other vehicle, slot 1).

    Attributes:
        history: The true (progress, speed) of the last ``latency + 1`` ticks, a ring indexed
            by tick ``[B, L + 1, 2]``.
        key: The episode's random key ``[B]``.
        missed: Ticks of the current miss still to come (0: none; -1: a miss just ended, the
            vehicle is seen this tick) ``[B]``.
        ever: The vehicle has been seen ``[B]``.
        seen: It was seen on the last tick ``[B]``.
        progress: Point estimate of its progress [m] ``[B]``.
        speed: Point estimate of its speed [m/s] ``[B]``.
        x: The point estimate's position on the route [m] ``[B]``.
        y: ``[B]``.
        low: Lower bound on its true progress [m] ``[B]`` (``-FAR``: unknown).
        high: Upper bound on its true progress [m] ``[B]``.
        speed_high: Upper bound on its true speed [m/s] ``[B]``.
    """

    history: FloatArray
    key: NDArray[np.uint64]
    missed: NDArray[np.int64]
    ever: BoolArray
    seen: BoolArray
    progress: FloatArray
    speed: FloatArray
    x: FloatArray
    y: FloatArray
    low: FloatArray
    high: FloatArray
    speed_high: FloatArray


class Perception:
    """The sensor and the tracker of a left-turn scene with one other vehicle (the paper's).

    Args:
        config: The scene's configuration (its ``perception`` block, the certified logic's
            assumptions on other vehicles, the tick and the speed limit).
        routes: The world's routes (for the point estimate's position).
        point: The other vehicle's conflict point on its route [m].
        exit_: Exit of its conflict zone on its route [m].
        base: Flat index of its route's first waypoint.
    """

    def __init__(
        self, config: LeftTurnConfig, routes: RouteSet, point: float, exit_: float, base: int
    ) -> None:
        p, dt = config.perception, config.episode.dt
        self.config = p
        latency = p.ticks(p.latency_s, dt, "latency_s")
        dropout = math.floor(p.dropout_max_s / dt + 1e-9) if p.dropout_prob > 0 else 0
        top = config.certified.other_max_speed_kmh / 3.6
        sight = math.inf if p.sight_distance_m is None else p.sight_distance_m
        unseen = point - sight + top * (latency + dropout + 1) * dt
        self.constants = PerceptionConstants(
            dt=dt,
            latency=latency,
            dropout_ticks=dropout,
            dropout_prob=p.dropout_prob,
            position_error=p.position_error_m,
            speed_error=p.speed_error_mps,
            sight=sight,
            adversarial=p.errors == "adversarial",
            point=point,
            exit=exit_,
            other_accel=config.certified.other_max_accel,
            other_top=top,
            unseen_high=unseen,
            unseen_speed=config.controllers.speed_limit,
            spacing=routes.spacing,
            k_max=routes.size - 2,
            base=int(base),
        )
        self._tables = routes.tables

    def initial(
        self, progress: FloatArray, speed: FloatArray, key: NDArray[np.uint64]
    ) -> PerceptionState:
        """The state at an episode's start, the vehicle at ``progress`` with ``speed`` ``[B]``
        (driving at that speed before: the latency's history), its first sighting taken."""
        c = self.constants
        batch = progress.shape[0]
        back = np.arange(c.latency + 1)[None, :]  # ticks before the start
        slots = (-back) % (c.latency + 1)
        history = np.empty((batch, c.latency + 1, 2))
        history[:, slots[0], 0] = progress[:, None] - speed[:, None] * back * c.dt
        history[:, slots[0], 1] = speed[:, None]
        empty = np.zeros(batch)
        state = PerceptionState(
            history=history, key=np.asarray(key, dtype=np.uint64).copy(),
            missed=np.zeros(batch, dtype=np.int64), ever=np.zeros(batch, dtype=np.bool_),
            seen=np.zeros(batch, dtype=np.bool_), progress=empty.copy(), speed=empty.copy(),
            x=empty.copy(), y=empty.copy(), low=empty.copy(), high=empty.copy(),
            speed_high=empty.copy(),
        )  # fmt: skip
        self._sense(state, np.zeros(batch, dtype=np.int64), progress, speed, first=True)
        return state

    def sense(
        self, state: PerceptionState, tick: NDArray[np.int64], progress: FloatArray,
        speed: FloatArray,
    ) -> PerceptionState:  # fmt: skip
        """The state after the tick that brought the vehicle to ``progress`` and ``speed``
        (tick ``tick`` of each episode); ``state`` is not modified."""
        new = PerceptionState(
            history=state.history.copy(), key=state.key, missed=state.missed.copy(),
            ever=state.ever.copy(), seen=np.empty_like(state.seen),
            progress=state.progress.copy(), speed=state.speed.copy(), x=state.x.copy(),
            y=state.y.copy(), low=state.low.copy(), high=state.high.copy(),
            speed_high=state.speed_high.copy(),
        )  # fmt: skip
        self._sense(new, tick, progress, speed, first=False)
        return new

    def _sense(
        self, s: PerceptionState, tick: NDArray[np.int64], progress: FloatArray,
        speed: FloatArray, first: bool,
    ) -> None:  # fmt: skip
        _sense(
            self.constants, self._tables, first, np.ascontiguousarray(tick),
            np.ascontiguousarray(progress, dtype=np.float64),
            np.ascontiguousarray(speed, dtype=np.float64), s.history, s.key, s.missed, s.ever,
            s.seen, s.progress, s.speed, s.x, s.y, s.low, s.high, s.speed_high,
        )  # fmt: skip

    @staticmethod
    def uncertainty(state: PerceptionState) -> tuple[FloatArray, FloatArray, FloatArray]:
        """What the tracker knows beyond the point estimate ``[B]`` each: how far the vehicle
        may be ahead of it (``high − progress``) and behind it (``progress − low``, ``FAR`` if
        unknown) [m], and the bound on its speed [m/s]."""
        lead = state.high - state.progress
        lag = np.minimum(state.progress - state.low, FAR)
        return lead, lag, state.speed_high


def episode_keys(columns: list[FloatArray]) -> NDArray[np.uint64]:
    """A random key per episode from its scenario's values (a pure function of them)."""
    with np.errstate(over="ignore"):
        key = np.zeros(len(columns[0]), dtype=np.uint64)
        for column in columns:
            bits = np.ascontiguousarray(column, dtype=np.float64).view(np.uint64)
            key = _mix(key ^ bits)
    return key


def _mix(z: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """splitmix64's finaliser, vectorised."""
    z = z + _GOLDEN
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@jit
def _uniform(key: np.uint64, tick: int, j: int) -> float:
    """A uniform number in [0, 1), a pure function of ``(key, tick, j)`` (splitmix64)."""
    z = key + np.uint64(tick * 4 + j + 1) * np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@jit
def reach(speed: float, time: float, accel: float, top: float) -> float:
    """The farthest a vehicle at ``speed`` can drive in ``time`` accelerating at ``accel`` up to
    ``top`` (at its own speed if already faster) [m]."""
    if time <= 0.0:
        return 0.0
    if speed >= top:
        return speed * time
    to_top = (top - speed) / accel
    if time <= to_top:
        return speed * time + 0.5 * accel * time * time
    return speed * to_top + 0.5 * accel * to_top * to_top + top * (time - to_top)


@jit
def _speed_after(speed: float, time: float, accel: float, top: float) -> float:
    """The fastest a vehicle at ``speed`` can be after ``time`` (no faster than ``top``, or than
    ``speed`` if already faster)."""
    return min(speed + accel * time, max(speed, top))


@jit
def _sense(
    c: PerceptionConstants, tables: FloatArray, first: bool, tick: NDArray[np.int64],
    progress: FloatArray, speed: FloatArray, history: FloatArray, key: NDArray[np.uint64],
    missed: NDArray[np.int64], ever: BoolArray, seen: BoolArray, est_progress: FloatArray,
    est_speed: FloatArray, est_x: FloatArray, est_y: FloatArray, low: FloatArray,
    high: FloatArray, speed_high: FloatArray,
) -> None:  # fmt: skip
    """One tick of the sensor and the tracker for every episode, in place (see the module
    docstring)."""
    ring = c.latency + 1
    a, top = c.other_accel, c.other_top
    for b in range(progress.shape[0]):
        t = tick[b]
        if not first:
            history[b, t % ring, 0], history[b, t % ring, 1] = progress[b], speed[b]
        m = (t + 1) % ring  # the slot of tick t − latency
        true_p, true_v = history[b, m, 0], history[b, m, 1]
        visible = c.point - true_p <= c.sight
        # Missed detections: a miss starts with dropout_prob on a tick the vehicle is not
        # already missed, lasts up to dropout_ticks, and is followed by a tick seen.
        if missed[b] > 0:
            visible = False
            missed[b] -= 1
            if missed[b] == 0:
                missed[b] = -1
        elif missed[b] == -1:
            missed[b] = 0
        elif not first and c.dropout_ticks > 0 and _uniform(key[b], t, 0) < c.dropout_prob:
            visible = False
            length = c.dropout_ticks
            if not c.adversarial:
                length = 1 + min(int(_uniform(key[b], t, 1) * c.dropout_ticks), c.dropout_ticks - 1)
            missed[b] = length - 1 if length > 1 else -1
        # The tracker's interval, propagated over the tick (unknown before the first tick).
        if first:
            hi, lo, vh = math.inf, -FAR, max(top, true_v)
        else:
            hi = high[b] + reach(speed_high[b], c.dt, a, top)
            lo, vh = low[b], _speed_after(speed_high[b], c.dt, a, top)
        seen[b] = visible
        if visible:
            if c.adversarial:
                # Farther back and slower, until the error can show it past its zone: then
                # farther on and faster, as if it had left.
                sign = 1.0 if true_p + c.position_error > c.exit else -1.0
                ep, ev = sign * c.position_error, sign * c.speed_error
            else:
                ep = (2.0 * _uniform(key[b], t, 2) - 1.0) * c.position_error
                ev = (2.0 * _uniform(key[b], t, 3) - 1.0) * c.speed_error
            mp, mv = true_p + ep, max(true_v + ev, 0.0)
            est_progress[b], est_speed[b] = mp, mv
            ever[b] = True
            # What this sighting alone says about now: its errors, then the latency.
            age = c.latency * c.dt
            v_then = mv + c.speed_error
            hi = min(hi, mp + c.position_error + reach(v_then, age, a, top))
            vh = min(vh, _speed_after(v_then, age, a, top))
            lo = max(lo, mp - c.position_error)
        elif not ever[b]:
            est_progress[b], est_speed[b] = c.point - c.sight, c.unseen_speed
            hi = min(hi, c.unseen_high)
        high[b], low[b], speed_high[b] = hi, lo, vh
        est_x[b], est_y[b], _ = pose(tables, c.spacing, c.k_max, c.base, est_progress[b])
