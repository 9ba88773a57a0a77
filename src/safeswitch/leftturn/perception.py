"""Perception of the other vehicles: a sensor with noise, latency, missed detections and a sight
distance, and the tracker that turns its sightings into what the ego's software knows.

The paper assumes perfect perception (its Remark 2). Here the plant, collisions and every metric
keep the truth, and everything that decides reads what is seen (:class:`PerceptionConfig`):

* **Sensor** (the world's side). On every tick it reports each other vehicle as it was
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
  time keeps its propagated interval; the north car, never seen yet, was beyond the sight edge
  ``latency_s + dropout_max_s`` (and a tick) ago, at most at the top speed since; a vehicle of
  the streams never seen is left to the certified logic's phantoms, brought closer by the same
  reach (:meth:`Perception.phantom_entry`). A vehicle that takes a freed slot starts over.

One compiled loop per tick (:func:`_sense`) does all of it for every vehicle of every episode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import jit
from safeswitch.leftturn.scenarios import splitmix64

if TYPE_CHECKING:
    from safeswitch.leftturn.config import LeftTurnConfig

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Stand-in for an unbounded distance behind (a vehicle never seen): finite, so that a logic
#: that ignores the tracker can multiply it by 0.
FAR = 1.0e9


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
        other_accel: Assumed largest acceleration of a vehicle [m/s²].
        other_top: Assumed top speed [m/s].
        unseen_speed: Speed of the point estimate of a vehicle never seen [m/s].
        unseen_reach: How far a vehicle never seen may have come since it was beyond the sight
            distance or not yet in the scene: ``other_top · (latency + dropout + 1) · dt`` [m].
    """

    dt: float
    latency: int
    dropout_ticks: int
    dropout_prob: float
    position_error: float
    speed_error: float
    sight: float
    adversarial: bool
    other_accel: float
    other_top: float
    unseen_speed: float
    unseen_reach: float


class Sighted(NamedTuple):
    """The vehicles a tick of the sensor looks at, ``[B, V]`` each (``V``: the north car, then
    in traffic every slot).

    Attributes:
        progress: True arc length along its route [m].
        speed: True speed [m/s].
        exists: The vehicle is in the scene.
        fresh: A new vehicle took the slot on this tick (its sensor and track start over).
        point: Its conflict point with the ego on its route [m] (``nan``: its route does not
            cross the ego's).
        exit: Exit of its conflict zone on its route [m] (where adversarial errors turn).
        bounded: A vehicle never seen is known to be no farther on than the sight edge plus
            ``unseen_reach`` (the paper's north car, always in the scene); else it is left to
            the phantoms of the certified logic (a vehicle of the streams).
    """

    progress: FloatArray
    speed: FloatArray
    exists: BoolArray
    fresh: BoolArray
    point: FloatArray
    exit: FloatArray
    bounded: BoolArray


@dataclass
class PerceptionState:
    """The sensor's and the tracker's state for ``B`` episodes and ``V`` vehicles (column 0 the
    north car, then in traffic every slot), arrays ``[B, V]``.

    Attributes:
        history: The true (progress, speed, in the scene) of the last ``latency + 1`` ticks, a
            ring indexed by tick ``[B, V, L + 1, 3]``.
        key: The episode's random key ``[B]``.
        missed: Ticks of the current miss still to come (0: none; -1: a miss just ended, the
            vehicle is seen this tick).
        ever: The vehicle has been seen.
        seen: It was seen on the last tick.
        progress: Point estimate of its progress [m].
        speed: Point estimate of its speed [m/s].
        low: Lower bound on its true progress [m] (``-FAR``: unknown).
        high: Upper bound on its true progress [m].
        speed_high: Upper bound on its true speed [m/s].
    """

    history: FloatArray
    key: NDArray[np.uint64]
    missed: NDArray[np.int64]
    ever: BoolArray
    seen: BoolArray
    progress: FloatArray
    speed: FloatArray
    low: FloatArray
    high: FloatArray
    speed_high: FloatArray

    def copy(self) -> PerceptionState:
        """A copy to advance (the key is shared: it never changes)."""
        return PerceptionState(
            self.history.copy(), self.key, self.missed.copy(), self.ever.copy(),
            self.seen.copy(), self.progress.copy(), self.speed.copy(), self.low.copy(),
            self.high.copy(), self.speed_high.copy(),
        )  # fmt: skip


class Perception:
    """The sensor and the tracker of a left-turn scene.

    Args:
        config: The scene's configuration (its ``perception`` block, the certified logic's
            assumptions on other vehicles, the tick and the speed limit).
    """

    def __init__(self, config: LeftTurnConfig) -> None:
        p, dt = config.perception, config.episode.dt
        self.config = p
        latency = p.ticks(p.latency_s, dt, "latency_s")
        dropout = math.floor(p.dropout_max_s / dt + 1e-9) if p.dropout_prob > 0 else 0
        top = config.certified.other_max_speed_kmh / 3.6
        self.constants = PerceptionConstants(
            dt=dt,
            latency=latency,
            dropout_ticks=dropout,
            dropout_prob=p.dropout_prob,
            position_error=p.position_error_m,
            speed_error=p.speed_error_mps,
            sight=math.inf if p.sight_distance_m is None else p.sight_distance_m,
            adversarial=p.errors == "adversarial",
            other_accel=config.certified.other_max_accel,
            other_top=top,
            unseen_speed=config.controllers.speed_limit,
            unseen_reach=top * (latency + dropout + 1) * dt,
        )

    def phantom_entry(self, entry: FloatArray, point: FloatArray, zone_entry: FloatArray) -> Any:
        """The certified logic's phantoms under this perception: a vehicle not yet seen may be
        just beyond the sight edge, or have entered or come within sight ``latency + dropout``
        ticks ago — its distance to its zone (``entry`` from the start of its approach; its
        route's ``point`` and ``zone_entry``) shortened accordingly, never below 0 [m]."""
        c = self.constants
        beyond = zone_entry - (point - c.sight)
        return np.maximum(np.minimum(entry, beyond) - c.unseen_reach, 0.0)

    def initial(self, sighted: Sighted, key: NDArray[np.uint64]) -> PerceptionState:
        """The state at an episode's start, its first sighting taken: the vehicles in the scene
        drove at their speed before it (the latency's history)."""
        c = self.constants
        batch, count = sighted.progress.shape
        ring = c.latency + 1
        back = np.arange(ring)  # ticks before the start
        history = np.zeros((batch, count, ring, 3))
        slots = (-back) % ring
        history[:, :, slots, 0] = sighted.progress[..., None] - sighted.speed[..., None] * (
            back * c.dt
        )
        history[:, :, slots, 1] = sighted.speed[..., None]
        history[:, :, slots, 2] = sighted.exists[..., None]
        empty = np.zeros((batch, count))
        state = PerceptionState(
            history=history, key=np.asarray(key, dtype=np.uint64).copy(),
            missed=np.zeros((batch, count), dtype=np.int64),
            ever=np.zeros((batch, count), dtype=np.bool_),
            seen=np.zeros((batch, count), dtype=np.bool_), progress=empty.copy(),
            speed=empty.copy(), low=empty.copy(), high=empty.copy(), speed_high=empty.copy(),
        )  # fmt: skip
        self._sense(state, np.zeros(batch, dtype=np.int64), sighted, first=True)
        return state

    def sense(
        self, state: PerceptionState, tick: NDArray[np.int64], sighted: Sighted
    ) -> PerceptionState:
        """The state after the tick that brought the vehicles to ``sighted`` (tick ``tick`` of
        each episode); ``state`` is not modified."""
        new = state.copy()
        self._sense(new, tick, sighted, first=False)
        return new

    def _sense(self, s: PerceptionState, tick: NDArray[np.int64], v: Sighted, first: bool) -> None:
        f64 = np.float64
        _sense(
            self.constants, first, np.ascontiguousarray(tick),
            np.ascontiguousarray(v.progress, dtype=f64), np.ascontiguousarray(v.speed, dtype=f64),
            np.ascontiguousarray(v.exists), np.ascontiguousarray(v.fresh),
            np.ascontiguousarray(v.point, dtype=f64), np.ascontiguousarray(v.exit, dtype=f64),
            np.ascontiguousarray(v.bounded), s.history, s.key, s.missed, s.ever, s.seen,
            s.progress, s.speed, s.low, s.high, s.speed_high,
        )  # fmt: skip

    @staticmethod
    def uncertainty(state: PerceptionState) -> tuple[FloatArray, FloatArray, FloatArray]:
        """What the tracker knows beyond the point estimate ``[B, V]`` each: how far a vehicle
        may be ahead of it (``high − progress``) and behind it (``progress − low``, ``FAR`` if
        unknown) [m], and the bound on its speed [m/s]."""
        lead = np.minimum(state.high - state.progress, FAR)
        lag = np.minimum(state.progress - state.low, FAR)
        return lead, lag, state.speed_high


def episode_keys(columns: list[FloatArray]) -> NDArray[np.uint64]:
    """A random key per episode from its scenario's values (a pure function of them)."""
    with np.errstate(over="ignore"):
        key = np.zeros(len(columns[0]), dtype=np.uint64)
        for column in columns:
            bits = np.ascontiguousarray(column, dtype=np.float64).view(np.uint64)
            key = splitmix64(key ^ bits)
    return key


@jit
def _uniform(key: np.uint64, tick: int, j: int) -> float:
    """A uniform number in [0, 1), a pure function of ``(key, tick, j)``: the finaliser of
    :func:`~safeswitch.leftturn.scenarios.splitmix64`, compiled for one number."""
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
    c: PerceptionConstants, first: bool, tick: NDArray[np.int64], progress: FloatArray,
    speed: FloatArray, exists: BoolArray, fresh: BoolArray, point: FloatArray,
    exit_: FloatArray, bounded: BoolArray, history: FloatArray, key: NDArray[np.uint64],
    missed: NDArray[np.int64], ever: BoolArray, seen: BoolArray, est_progress: FloatArray,
    est_speed: FloatArray, low: FloatArray, high: FloatArray, speed_high: FloatArray,
) -> None:  # fmt: skip
    """One tick of the sensor and the tracker for every vehicle of every episode, in place (see
    the module docstring)."""
    ring = c.latency + 1
    a, top = c.other_accel, c.other_top
    for b in range(progress.shape[0]):
        t = tick[b]
        for v in range(progress.shape[1]):
            k = key[b] ^ (np.uint64(v) * np.uint64(0xD1B54A32D192ED03))
            new = first or fresh[b, v]
            if fresh[b, v] and not first:
                # A new vehicle in the slot: nothing of it was there before.
                for j in range(ring):
                    history[b, v, j, 2] = 0.0
                missed[b, v], ever[b, v] = 0, False
            if not first:
                slot = t % ring
                history[b, v, slot, 0], history[b, v, slot, 1] = progress[b, v], speed[b, v]
                history[b, v, slot, 2] = 1.0 if exists[b, v] else 0.0
            m = (t + 1) % ring  # the slot of tick t − latency
            true_p, true_v = history[b, v, m, 0], history[b, v, m, 1]
            visible = history[b, v, m, 2] > 0.5 and point[b, v] - true_p <= c.sight
            # Missed detections: a miss starts with dropout_prob on a tick the vehicle is not
            # already missed, lasts up to dropout_ticks, and is followed by a tick seen.
            if missed[b, v] > 0:
                visible = False
                missed[b, v] -= 1
                if missed[b, v] == 0:
                    missed[b, v] = -1
            elif missed[b, v] == -1:
                missed[b, v] = 0
            elif not new and c.dropout_ticks > 0 and _uniform(k, t, 0) < c.dropout_prob:
                visible = False
                length = c.dropout_ticks
                if not c.adversarial:
                    draw = int(_uniform(k, t, 1) * c.dropout_ticks)
                    length = 1 + min(draw, c.dropout_ticks - 1)
                missed[b, v] = length - 1 if length > 1 else -1
            # The tracker's interval, propagated over the tick (unknown for a new vehicle).
            if new:
                hi, lo, vh = math.inf, -FAR, top
            else:
                hi = high[b, v] + reach(speed_high[b, v], c.dt, a, top)
                lo, vh = low[b, v], _speed_after(speed_high[b, v], c.dt, a, top)
            seen[b, v] = visible
            if visible:
                if c.adversarial:
                    # Farther back and slower, until the error can show it past its zone:
                    # then farther on and faster, as if it had left.
                    sign = 1.0 if true_p + c.position_error > exit_[b, v] else -1.0
                    ep, ev = sign * c.position_error, sign * c.speed_error
                else:
                    ep = (2.0 * _uniform(k, t, 2) - 1.0) * c.position_error
                    ev = (2.0 * _uniform(k, t, 3) - 1.0) * c.speed_error
                mp, mv = true_p + ep, max(true_v + ev, 0.0)
                est_progress[b, v], est_speed[b, v] = mp, mv
                ever[b, v] = True
                # What this sighting alone says about now: its errors, then the latency.
                age = c.latency * c.dt
                v_then = mv + c.speed_error
                hi = min(hi, mp + c.position_error + reach(v_then, age, a, top))
                vh = min(vh, _speed_after(v_then, age, a, top))
                lo = max(lo, mp - c.position_error)
            elif not ever[b, v]:
                est_progress[b, v], est_speed[b, v] = point[b, v] - c.sight, c.unseen_speed
                if bounded[b, v]:
                    hi = min(hi, point[b, v] - c.sight + c.unseen_reach)
            high[b, v], low[b, v], speed_high[b, v] = hi, lo, vh
