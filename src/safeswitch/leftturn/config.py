"""Configuration of the left-turn case study: every value the paper leaves open, named.

Values from the paper carry "(paper)"; values we chose carry "(ours)" and a reason. All units
are SI unless the name says otherwise (``_kmh``).
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

from safeswitch.core.config import Bounds, ConfigError, check, check_bounds, from_dict, to_dict
from safeswitch.core.pid_gains import PIDGains
from safeswitch.core.registry import logic_names, logic_params
from safeswitch.sim.params import GRAVITY, IntersectionGeometry, VehicleParams

LearnedScope = Literal["window", "episode", "never"]
ScenarioName = Literal["cut", "yield1", "yield2"]

SCENARIO_NAMES: tuple[str, ...] = ("cut", "yield1", "yield2")


@dataclass(frozen=True)
class ControllerConfig:
    """The ego's rule-based controllers (paper Table I) and their set points.

    Attributes:
        speed_limit_kmh: Speed limit ``v_lim`` of the road, set point of ``PID_th`` (paper).
        throttle_pid: ``PID_th`` on ``v_lim − v`` [m/s] → throttle in [0, 0.7] (paper).
        brake_pid: ``PID_b``, the Safety controller, on ``a_max − a_decel`` [m/s²] → brake in
            [0, 1] (paper gains). ``a_decel`` is the measured deceleration (positive when
            slowing). Ours: a 0.2 s filter on the derivative term (unfiltered, kd·Δa/Δt of a
            per-tick acceleration makes the brake chatter between 0 and 1 every tick and the
            mean deceleration fall to 4.7 m/s²), and the integral starts at the brake that
            gives ``emergency_decel`` on a level road (bumpless start).
        lane_pid: ``PID_lka`` on the look-ahead lateral offset [m] → steering in [-1, 1]
            (paper gains).
        lane_lookahead_m: Look-ahead distance of ``PID_lka``'s error signal (ours: the paper
            does not define its "lka" error; the lateral offset of the route point 5 m ahead,
            in the car's frame, keeps the Table I gains within 0.41 m of the route through the
            11.75 m turn at 25 km/h; 4 m and 7 m give 0.78 m and 0.97 m).
        emergency_decel: ``a_max_lon``, the deceleration ``PID_b`` tracks and Eq. 3 uses
            [m/s²] (ours: above the 5 m/s² comfort limit — the Safety controller may sacrifice
            comfort — and well inside the tyres' μ·g = 8.8 m/s²).
        learned_speed_limiter_kmh: A speed limiter on the learned controller's throttle [km/h]
            (ours, off by default; the paper has none): above ``cap = clip(u_ss(v_cap) +
            gain · (v_cap − v), 0, 1)`` — ``u_ss`` the throttle that holds ``v_cap`` on a level
            road — the learned throttle is cut to ``cap``, as a production car's speed limiter
            (intelligent speed assistance) cuts the pedal. It is part of the learned
            controller: the switching logic sees and judges the limited throttle, and braking
            is never limited. ``None``: no limiter.
        learned_speed_limiter_gain: Throttle taken off per m/s of speed towards and over the
            limit (ours).
        learned_curve_accel: A curve speed limiter on the learned controller's throttle
            [m/s²] (ours, off by default; the paper has none): the speed limiter's cap, above,
            is lowered ahead of every curve of the ego's route to ``√(a / |κ|)`` at the curve,
            reached by closing the throttle (``learned_curve_decel``) — a production car's
            predictive curve speed control, on its map's route. Like the speed limiter it is
            part of the learned controller and never brakes; the learned action may still ask
            for less. At 2.8 m/s² full throttle takes the 11.75 m turn within the 3 m/s²
            comfort limit (at 2.99; a cap at 3.0 overshoots to 3.2 in the car's lags).
            ``None``: no curve limiter. Needs ``learned_speed_limiter_kmh``.
        learned_curve_decel: The deceleration the curve limiter plans with ahead of a curve
            [m/s²] (ours; closing the throttle slows the car by about 1.3 m/s² at 25 km/h).
        learned_speed_command_kmh: What the learned action commands (ours, off by default: the
            paper's action is the throttle, ``(a + 1) / 2``). If set, the action is a speed
            set point ``v* = (a + 1) / 2 · this`` [km/h], tracked by the learned controller's
            own throttle ``clip(u_ss(v*) + gain · (v* − v), 0, 1)`` (a cruise control): holding
            a speed is then one constant action, and a "go" one step of it. An action out of
            [-1, 1] is clipped to the range and counted as clipped; NaN/inf stays invalid for
            the logic to refuse. The limiter above, if set, still cuts the throttle.
        learned_speed_command_gain: Throttle per m/s of the set point's speed error (ours; the
            gap planner's 0.6).
        learned_brake: The learned action works both pedals (ours, off by default: the paper's
            learned controller has the throttle alone and can slow only by closing it, about
            1.3 m/s² at 25 km/h). If true, ``a ≥ 0`` is the throttle ``a`` and ``a < 0`` the brake
            ``−a`` with the throttle closed. The switching logic judges both pedals (the
            certified filter predicts the tick under any pedals); an action out of [-1, 1] is
            clipped and counted, NaN/inf refused. Not with a speed set point.
    """

    speed_limit_kmh: Annotated[float, Bounds(0, 130, low_open=True, unit="km/h")] = 25.0
    throttle_pid: PIDGains = field(default_factory=lambda: PIDGains(1.5, 0.05, 0.002, 0.0, 0.7))
    brake_pid: PIDGains = field(
        default_factory=lambda: PIDGains(0.3, 0.40, 0.100, 0.0, 1.0, derivative_filter_s=0.2)
    )
    lane_pid: PIDGains = field(default_factory=lambda: PIDGains(0.2, 0.01, 0.020, -1.0, 1.0))
    lane_lookahead_m: Annotated[float, Bounds(0, 30, low_open=True, unit="m")] = 5.0
    emergency_decel: Annotated[float, Bounds(0, 9, low_open=True, unit="m/s²")] = 6.0
    learned_speed_limiter_kmh: Annotated[float | None, Bounds(5, 130, unit="km/h")] = None
    learned_speed_limiter_gain: Annotated[float, Bounds(0, 10, low_open=True, unit="per m/s")] = 1.0
    learned_curve_accel: Annotated[float | None, Bounds(0.5, 10, unit="m/s²")] = None
    learned_curve_decel: Annotated[float, Bounds(0.1, 5, unit="m/s²")] = 1.0
    learned_speed_command_kmh: Annotated[float | None, Bounds(5, 130, unit="km/h")] = None
    learned_speed_command_gain: Annotated[float, Bounds(0, 10, low_open=True, unit="per m/s")] = 0.6
    learned_brake: bool = False

    def __post_init__(self) -> None:
        check_bounds(self, "controllers")
        both = self.learned_brake and self.learned_speed_command_kmh is not None
        check(not both, "controllers", "learned_brake", self.learned_brake,
              "must be false with a speed set point (learned_speed_command_kmh)")  # fmt: skip
        check(self.learned_curve_accel is None or self.learned_speed_limiter_kmh is not None,
              "controllers", "learned_curve_accel", self.learned_curve_accel,
              "lowers the speed limiter's cap: needs learned_speed_limiter_kmh")  # fmt: skip

    @property
    def throttle_action(self) -> bool:
        """The learned action is the paper's throttle, ``(a + 1) / 2`` (neither a speed set
        point nor both pedals); scripted drivers that output throttles reach the other actions
        through :func:`~safeswitch.leftturn.spaces.throttle_driver`."""
        return self.learned_speed_command_kmh is None and not self.learned_brake

    @property
    def speed_limit(self) -> float:
        """``v_lim`` [m/s]."""
        return self.speed_limit_kmh / 3.6


@dataclass(frozen=True)
class PaperSwitchingConfig:
    """The paper's emergency-braking switching logic (Algorithm 1, read as its text says).

    Attributes:
        ttr_threshold_s: Smallest ``TTR_n − TTR_e`` for which cutting in front counts as an
            option [s] (ours). At 25 km/h the ego needs about 1.1 s from the conflict point until
            its rear clears the north car's path, and a north car at up to 35 km/h reaches the
            conflict point about 0.5 s after its front enters the ego's path: 1.6 s, plus 0.4 s
            for the constant-speed assumption of Eq. 2.
        stop_margin_m: Distance added to ``d_safe`` (Eq. 3) before the stopping point [m]
            (ours): ``PID_b`` reaches its target deceleration only gradually; measured on the
            plant, its stop from 10 m/s with the throttle still at 1 is 0.8 m longer than
            ``d_safe + v·latency`` (``tests/leftturn/test_controllers.py``).
        latency_s: Time before full braking takes hold [s] (ours): one 20 ms tick plus the
            brake actuator's 80 ms lag; the car travels ``v·latency`` more.
        min_speed: Speed below which Eq. 2 uses this value instead (guard against v → 0)
            [m/s] (ours).
    """

    ttr_threshold_s: Annotated[float, Bounds(0, 20, unit="s")] = 2.0
    stop_margin_m: Annotated[float, Bounds(0, 20, unit="m")] = 1.5
    latency_s: Annotated[float, Bounds(0, 2, unit="s")] = 0.1
    min_speed: Annotated[float, Bounds(0, 5, low_open=True, unit="m/s")] = 0.1

    def __post_init__(self) -> None:
        check_bounds(self, "paper")


@dataclass(frozen=True)
class CertifiedConfig:
    """Assumptions and margins of the certified switching logic (all ours).

    The guarantee — no collision for any learned action sequence — holds while the assumptions
    hold. When they are broken the filter still acts (best effort: stop before the conflict zone
    when possible), and the benchmarks measure what then happens.

    Attributes:
        other_max_accel: Assumption: every other vehicle — the north car, and in traffic each
            vehicle of the streams — accelerates at most this much [m/s²] (a brisk but ordinary
            urban acceleration; the north car's autopilot holds its speed). Formerly
            ``north_max_accel`` (still read).
        other_max_speed_kmh: Assumption: no other vehicle ever drives faster [km/h] (20 km/h
            over the 30 km/h zone the scenarios use). Formerly ``north_max_speed_kmh``.
        ego_max_lateral_m: Assumption: the ego stays this close to its route [m]. It holds
            because the filter keeps the ego within ``curve_lateral_accel`` (below): there
            ``PID_lka`` tracks the route within 0.45 m, braking included
            (``tests/leftturn/test_certified.py``).
        zone_margin_m: Clearance added to both footprints when the certified conflict zones are
            computed [m]; at least ``2 · ego_max_lateral_m``.
        progress_factor: Bound on the ratio between the ego's progress along the route and the
            distance it drives (at 0.6 m inside an 11.75 m arc: 1.05) — stopping distances are
            scaled up by it, clearing distances likewise.
        time_margin_s: The ego must have cleared its zone this long before the north car can
            first enter its own [s].
        lag_ticks: Ticks of the actuator lags simulated exactly in the backups' bounds; beyond
            them the weakest remaining deceleration (or acceleration) is assumed.
        clear_speed_cap: Speed up to which the clearing bound's acceleration is valid [m/s].
        curve_lateral_accel: The cornering the filter allows the ego, ``v² |κ|`` along its
            route [m/s²] (ours): it accepts a learned action only if full braking from the
            next tick still keeps the ego within it at every curve ahead, so the tyres never
            slide (the friction circle, :mod:`safeswitch.sim.vehicle`) and the ego never loses
            control. 5 m/s² takes the 11.75 m turn at up to 27.6 km/h (above the speed limit
            and the paper's 3 m/s² comfort limit, so a comfortable driver never meets it) and
            leaves the tyres ``√((μ·g)² − 5²)`` = 7.3 m/s² for braking in it.
        perception: ``declared`` — the filter assumes the scene's ``perception`` bounds and
            keeps its guarantee for any errors within them (what it sees is widened into the
            set of states consistent with every sighting so far); ``perfect`` — it takes what it
            sees as the truth (the paper's Remark 2; a baseline that breaks under errors).
    """

    #: Old key → new key: configurations written before the rename still load.
    RENAMED: ClassVar[dict[str, str]] = {
        "north_max_accel": "other_max_accel",
        "north_max_speed_kmh": "other_max_speed_kmh",
    }

    other_max_accel: Annotated[float, Bounds(0, 10, low_open=True, unit="m/s²")] = 2.5
    other_max_speed_kmh: Annotated[float, Bounds(0, 200, low_open=True, unit="km/h")] = 50.0
    ego_max_lateral_m: Annotated[float, Bounds(0, 2, unit="m")] = 0.6
    zone_margin_m: Annotated[float, Bounds(0, 5, unit="m")] = 1.2
    progress_factor: Annotated[float, Bounds(1, 1.5)] = 1.05
    time_margin_s: Annotated[float, Bounds(0, 5, unit="s")] = 0.1
    lag_ticks: Annotated[int, Bounds(1, 100)] = 10
    clear_speed_cap: Annotated[float, Bounds(5, 60, unit="m/s")] = 20.0
    curve_lateral_accel: Annotated[float, Bounds(0, 10, low_open=True, unit="m/s²")] = 5.0
    perception: Literal["declared", "perfect"] = "declared"

    def __post_init__(self) -> None:
        check_bounds(self, "certified")
        check(self.perception in ("declared", "perfect"), "certified", "perception",
              self.perception, "must be 'declared' or 'perfect'")  # fmt: skip
        check(2 * self.ego_max_lateral_m <= self.zone_margin_m, "certified", "zone_margin_m",
              self.zone_margin_m, "must be at least 2 · ego_max_lateral_m")  # fmt: skip


PerceptionErrors = Literal["random", "adversarial"]


@dataclass(frozen=True)
class PerceptionConfig:
    """How the ego perceives the other vehicles (the paper assumes perfect perception, its
    Remark 2; every default here is perfect perception).

    The plant, collisions and every metric use the truth; the switching logic, the Safety
    controller's window and the policy's observation use what is seen
    (:mod:`safeswitch.leftturn.perception`). The same bounds are what the certified logic is
    told (``certified.perception: declared``): it keeps its guarantee for any errors within them.

    Attributes:
        position_error_m: Bound on ``|seen − true|`` position of another vehicle along its
            path [m].
        speed_error_mps: Bound on ``|seen − true|`` speed [m/s].
        latency_s: What is seen is exactly this old [s]; a whole number of ticks.
        dropout_prob: Chance per tick that a seen vehicle starts being missed.
        dropout_max_s: A missed vehicle is missed for at most this long [s] (then seen for at
            least one tick).
        sight_distance_m: Vehicles farther than this from their conflict point, along their
            path, are not seen [m] (``null``: no limit).
        errors: ``random`` — independent, uniform within the bounds on every tick, a miss
            lasting a uniform number of ticks up to ``dropout_max_s``; ``adversarial`` — on every
            tick the error within the bounds that makes the other vehicle look least dangerous
            (farther back and slower, until the error can show it past its conflict zone: then
            farther on and faster, as if it had left), every miss as long as allowed.
    """

    position_error_m: Annotated[float, Bounds(0, 50, unit="m")] = 0.0
    speed_error_mps: Annotated[float, Bounds(0, 20, unit="m/s")] = 0.0
    latency_s: Annotated[float, Bounds(0, 2, unit="s")] = 0.0
    dropout_prob: Annotated[float, Bounds(0, 1)] = 0.0
    dropout_max_s: Annotated[float, Bounds(0, 10, unit="s")] = 0.0
    sight_distance_m: Annotated[float | None, Bounds(0, 10_000, low_open=True, unit="m")] = None
    errors: PerceptionErrors = "random"

    def __post_init__(self) -> None:
        check_bounds(self, "perception")
        check(self.errors in ("random", "adversarial"), "perception", "errors", self.errors,
              "must be 'random' or 'adversarial'")  # fmt: skip
        check(self.dropout_prob == 0.0 or self.dropout_max_s > 0.0, "perception",
              "dropout_prob", self.dropout_prob,
              "needs dropout_max_s > 0 (a miss lasts at least one tick)")  # fmt: skip

    @property
    def perfect(self) -> bool:
        """Everything is seen exactly, at once."""
        return (
            self.position_error_m == 0.0 and self.speed_error_mps == 0.0
            and self.latency_s == 0.0 and self.dropout_prob == 0.0
            and self.sight_distance_m is None
        )  # fmt: skip

    def ticks(self, seconds: float, dt: float, name: str) -> int:
        """``seconds`` as a whole number of ticks of ``dt``; else a :class:`ConfigError`
        naming the key."""
        ticks = round(seconds / dt)
        check(abs(ticks * dt - seconds) <= 1e-9 * max(1.0, seconds), "perception", name,
              seconds, f"must be a whole number of ticks ({dt} s)")  # fmt: skip
        return ticks


def _check_piecewise(
    owner: str, name: str, points: tuple[float, ...], values: tuple[float, ...]
) -> None:
    check(
        len(points) >= 2 and len(points) == len(values),
        owner,
        name,
        points,
        f"needs >= 2 breakpoints and as many values ({len(values)})",
    )
    check(all(math.isfinite(p) for p in points + values), owner, name, points, "must be finite")
    check(
        all(b > a for a, b in itertools.pairwise(points)),
        owner,
        name,
        points,
        "must be strictly increasing",
    )


@dataclass(frozen=True)
class RewardConfig:
    """The five reward terms of Eq. 5, each piecewise linear through its breakpoints.

    The shapes of Fig. 4 are not in the text; SPEC §2 fixes them. Each term's best value is +1;
    outside the breakpoints the end values hold.

    Attributes:
        adas_penalty: ``R_ADAS`` on a tick where the safety action was executed (paper Eq. 4).
        speed_points_kmh: Breakpoints of ``R_v`` [km/h]: a penalty below 5 km/h, +1 at the 25 km/h
            limit, tolerated speeding to 30 km/h, 0 at 35 km/h and a penalty above (paper, SPEC).
        speed_values: ``R_v`` at those breakpoints.
        lateral_points_m: Breakpoints of ``R_lka`` on ``|lateral deviation|`` [m] (0 at 1.5 m).
        lateral_values: ``R_lka`` at those breakpoints.
        accel_lon_points: Breakpoints of ``R_a_lon`` on ``|a_lon|`` [m/s²] (0 at 5 m/s²). Beyond
            the limit the penalty is steep (ours: -2 at 1.5 m/s² over it): with a gentle slope,
            the 0.2 of ``R_v`` lost by slowing from 25 to 21 km/h outweighs the comfort gained
            in the 11.75 m turn, and PPO learns to take it at 4.2 m/s² lateral.
        accel_lon_values: ``R_a_lon`` at those breakpoints.
        accel_lat_points: Breakpoints of ``R_a_lat`` on ``|a_lat|`` [m/s²] (0 at 3 m/s²).
        accel_lat_values: ``R_a_lat`` at those breakpoints.
        collision_penalty: Reward on the tick of a collision (ours; 0 keeps Eq. 5 — a collision
            ends the episode, which already forfeits the positive reward of the remaining ticks).
        comfort_accel_lon: Comfort limit on ``|a_lon|`` [m/s²] (paper, after UN ECE guidance);
            a tick beyond it counts as a comfort violation in the metrics.
        comfort_accel_lat: Comfort limit on ``|a_lat|`` [m/s²] (paper).
    """

    adas_penalty: Annotated[float, Bounds(high=0)] = -25.0
    speed_points_kmh: tuple[float, ...] = (0.0, 5.0, 25.0, 30.0, 35.0, 45.0)
    speed_values: tuple[float, ...] = (-1.0, 0.0, 1.0, 1.0, 0.0, -1.0)
    lateral_points_m: tuple[float, ...] = (0.0, 1.5, 3.0)
    lateral_values: tuple[float, ...] = (1.0, 0.0, -1.0)
    accel_lon_points: tuple[float, ...] = (0.0, 5.0, 6.5)
    accel_lon_values: tuple[float, ...] = (1.0, 0.0, -2.0)
    accel_lat_points: tuple[float, ...] = (0.0, 3.0, 4.5)
    accel_lat_values: tuple[float, ...] = (1.0, 0.0, -2.0)
    collision_penalty: Annotated[float, Bounds(high=0)] = 0.0
    comfort_accel_lon: Annotated[float, Bounds(0, low_open=True, unit="m/s²")] = 5.0
    comfort_accel_lat: Annotated[float, Bounds(0, low_open=True, unit="m/s²")] = 3.0

    def __post_init__(self) -> None:
        o = "rewards"
        check_bounds(self, o)
        _check_piecewise(o, "speed_points_kmh", self.speed_points_kmh, self.speed_values)
        _check_piecewise(o, "lateral_points_m", self.lateral_points_m, self.lateral_values)
        _check_piecewise(o, "accel_lon_points", self.accel_lon_points, self.accel_lon_values)
        _check_piecewise(o, "accel_lat_points", self.accel_lat_points, self.accel_lat_values)

    @functools.cached_property
    def tolerated_speed(self) -> float:
        """The highest speed at which ``R_v`` is at its best [m/s] (the speed limit plus the
        tolerated speeding: 30 km/h by default). Faster counts as speeding in the metrics."""
        best = max(self.speed_values)
        points = zip(self.speed_points_kmh, self.speed_values, strict=True)
        return max(p for p, v in points if v == best) / 3.6


@dataclass(frozen=True)
class ScenarioConfig:
    """The random scenario distribution (each value uniform between its two bounds).

    The north car's arrival is set relative to the ego's: ``arrival_offset_s`` is the time
    between the ego reaching the conflict point (cruising at the speed limit from its start) and
    the north car reaching it (at its own constant speed). Negative: the north car arrives
    first. The default range makes cutting in front right in about 45 % of episodes, yielding in
    about 35 % and leaves the rest without interaction (measured by the tests).

    Attributes:
        ego_start_distance_m: Ego's path distance to the conflict point at the start [m].
        ego_speed_kmh: Ego's initial speed [km/h].
        north_speed_kmh: North car's (constant target) speed [km/h].
        arrival_offset_s: North arrival time minus ego arrival time [s].
        focus_share: Share of scenarios drawn from the focused ranges instead (ours; 0: none,
            the distribution above). A training distribution that dwells on where rare
            failures concentrate, or that mixes in a wider scene (``train_only.scenarios`` of
            the training configuration); evaluations keep the plain one.
        focus_arrival_offset_s: The focused range of the arrival offset [s].
        focus_ego_start_distance_m: The focused range of the ego's start distance [m]
            (``null``: the plain one).
        focus_ego_speed_kmh: The focused range of the ego's initial speed [km/h] (``null``:
            the plain one).
        focus_north_speed_kmh: The focused range of the north car's speed [km/h] (``null``:
            the plain one).
    """

    ego_start_distance_m: Annotated[tuple[float, float], Bounds(20, unit="m")] = (32.0, 40.0)
    ego_speed_kmh: Annotated[tuple[float, float], Bounds(0, 100, unit="km/h")] = (18.0, 25.0)
    north_speed_kmh: Annotated[tuple[float, float], Bounds(0, 100, True, unit="km/h")] = (
        20.0,
        32.0,
    )
    arrival_offset_s: Annotated[tuple[float, float], Bounds(-60, 60, unit="s")] = (-3.0, 5.0)
    focus_share: Annotated[float, Bounds(0, 1)] = 0.0
    focus_arrival_offset_s: Annotated[tuple[float, float], Bounds(-60, 60, unit="s")] = (
        1.8,
        3.0,
    )
    focus_ego_start_distance_m: Annotated[tuple[float, float] | None, Bounds(20, unit="m")] = None
    focus_ego_speed_kmh: Annotated[tuple[float, float] | None, Bounds(0, 100, unit="km/h")] = None
    focus_north_speed_kmh: Annotated[
        tuple[float, float] | None, Bounds(0, 100, True, unit="km/h")
    ] = None

    def __post_init__(self) -> None:
        check_bounds(self, "scenarios")

    def focused(self, name: str) -> tuple[float, float]:
        """The focused range of the scenario value ``name`` (e.g. ``"north_speed_kmh"``): its
        ``focus_`` setting, or the plain range where that is ``null``."""
        value: tuple[float, float] | None = getattr(self, f"focus_{name}")
        return getattr(self, name) if value is None else value


def check_go_model(value: str | None, section: str, writer: str) -> None:
    """A ``go_model`` setting is ``None`` or names an existing file (``writer`` writes one)."""
    if value is not None:
        check(isinstance(value, str) and Path(value).is_file(), section, "go_model", value,
              f"must be null or the path of an existing .npz ({writer} writes one)")  # fmt: skip


@dataclass(frozen=True)
class TrafficConfig:
    """Traffic from every leg (ours: the paper's scene has one other car). Each scene draws its
    flows, its share of non-yielding drivers and every driver's desired speed uniformly within
    these ranges.

    The north–south road has the right of way; the east–west road gives way (see
    :mod:`safeswitch.sim.network`). The paper's north car stays (its arrival set by the
    scenario); the others come as Poisson streams (headways ``min_headway_s`` plus an
    exponential) on every approach, followers behind the ego included.

    Attributes:
        main_flow_veh_h: Flow on each main-road approach (north, south) [veh/h].
        minor_flow_veh_h: Flow on each minor-road approach (east, west) [veh/h].
        non_yielding_share: Share of drivers who ignore the automated ego at conflicts (the
            paper's north car never yields); the others give way to it by the rules.
        speed_kmh: Desired speeds of the other drivers [km/h].
        turn_shares: Shares of (straight, right, left) of every stream.
        min_headway_s: Smallest time headway in a stream [s].
        patience_s: How long a yielding driver waits for an ego that is waiting too before it
            goes first (:mod:`safeswitch.sim.streams`) [s].
        action_step_s: How often each driver decides — its leader, whom it gives way to and its
            acceleration, which then holds until its next decision — [s] (SUMO's *action step
            length*; the plant, the ego and its switching logic keep the episode's tick). A
            multiple of the tick; one tick decides on every tick. Ours: 0.1 s, five times
            finer than human reaction times (about 1 s) and than SUMO's default one-second
            step, and about 1.7 times the throughput of deciding every 20 ms
            (``benchmarks/bench_traffic.py``).
        exit_distance_m: A vehicle leaves the scene this far past the box [m].
        horizon_s: Episode length in traffic [s], in place of ``episode.horizon_s`` (waiting
            for a gap takes longer than the paper's 12 s); ``None`` keeps the episode's.
        max_vehicles: Slots for other vehicles per scene (besides the paper's north car): the
            streams' farthest vehicles are dropped beyond it at the start, and a vehicle due
            to enter waits outside while every slot is taken.
        observed: How many other vehicles the observation holds (``K``).
        observe: What the observation holds of them: ``nearest`` (the ``K`` nearest by
            distance, in map coordinates: present, x, y, speed, heading) or ``conflicts`` (the
            ``K`` vehicles whose routes cross the ego's and that have not yet left their
            conflict zone with it, the north car included, soonest to reach that zone first, in
            conflict coordinates: present, the vehicle's distance to its zone and to the zone's
            end, its speed, the ego's distance to its own zone with it and to that zone's end;
            ours, :data:`~safeswitch.leftturn.traffic.CONFLICT_FEATURES`) or ``margins`` (the
            same vehicles with two more values each, what the certified filter reckons for
            them: the earliest they can enter their zone and its certificate's slack against
            them, in seconds; ours, :data:`~safeswitch.leftturn.traffic.MARGIN_FEATURES`) or
            ``backups`` (``margins`` and, per vehicle, the stop backup's room before the ego's
            zone in metres; ours, :data:`~safeswitch.leftturn.traffic.BACKUP_FEATURES`).
        go_model: A learned go predictor, an ``.npz`` written by
            ``experiments/go_predictor.py`` (:class:`~safeswitch.leftturn.go_model.GoModel`):
            its probability that the fast drive from the current state gets past every
            conflict zone without the certified filter acting is appended to the observation,
            after everything else (ours; ``None``: none). In a configuration file a relative
            path is read beside the file (else from the working directory). Like
            ``observe``, it belongs to the policy: an evaluation in other traffic keeps it.
    """

    main_flow_veh_h: Annotated[tuple[float, float], Bounds(0, 3000, unit="veh/h")] = (
        300.0,
        450.0,
    )
    minor_flow_veh_h: Annotated[tuple[float, float], Bounds(0, 3000, unit="veh/h")] = (
        150.0,
        250.0,
    )
    non_yielding_share: Annotated[tuple[float, float], Bounds(0, 1)] = (0.0, 0.5)
    speed_kmh: Annotated[tuple[float, float], Bounds(5, 80, unit="km/h")] = (25.0, 40.0)
    turn_shares: tuple[float, float, float] = (0.7, 0.2, 0.1)
    min_headway_s: Annotated[float, Bounds(0.5, 10, unit="s")] = 1.5
    patience_s: Annotated[float, Bounds(0, 60, unit="s")] = 2.0
    action_step_s: Annotated[float, Bounds(0, 1, low_open=True, unit="s")] = 0.1
    exit_distance_m: Annotated[float, Bounds(10, 100, unit="m")] = 40.0
    horizon_s: Annotated[float | None, Bounds(1, 120, unit="s")] = 30.0
    max_vehicles: Annotated[int, Bounds(1, 32)] = 12
    observed: Annotated[int, Bounds(0)] = 4
    observe: Literal["nearest", "conflicts", "margins", "backups"] = "nearest"
    go_model: str | None = None

    def __post_init__(self) -> None:
        o = "traffic"
        check_go_model(self.go_model, o, "experiments/go_predictor.py")
        check_bounds(self, o)
        check(
            len(self.turn_shares) == 3 and min(self.turn_shares) >= 0
            and abs(sum(self.turn_shares) - 1.0) < 1e-6,
            o, "turn_shares", self.turn_shares, "must be 3 non-negative shares summing to 1",
        )  # fmt: skip
        check(self.observed <= self.max_vehicles + 1, o, "observed", self.observed,
              f"must be in [0, max_vehicles + 1 = {self.max_vehicles + 1}]")  # fmt: skip
        check(self.observe in OBSERVATIONS, o, "observe", self.observe,
              f"must be one of {OBSERVATIONS}")  # fmt: skip


#: Values of ``traffic.observe``.
OBSERVATIONS = ("nearest", "conflicts", "margins", "backups")

#: The :class:`TrafficConfig` settings that shape a policy's observation: an evaluation in other
#: traffic keeps the trained policy's.
POLICY_OBSERVATION = ("observe", "observed", "go_model")

#: Named traffic settings: densities from light to heavy, and a train/test split of the space
#: (the test family is denser and less courteous than anything trained on).
TRAFFIC_PRESETS: dict[str, dict[str, Any]] = {
    "light": {"main_flow_veh_h": (100.0, 200.0), "minor_flow_veh_h": (50.0, 100.0)},
    "medium": {"main_flow_veh_h": (300.0, 450.0), "minor_flow_veh_h": (150.0, 250.0)},
    "heavy": {"main_flow_veh_h": (600.0, 800.0), "minor_flow_veh_h": (300.0, 400.0),
              "max_vehicles": 14},
    "train": {"main_flow_veh_h": (100.0, 500.0), "minor_flow_veh_h": (50.0, 250.0),
              "non_yielding_share": (0.0, 0.5)},
    "test": {"main_flow_veh_h": (500.0, 800.0), "minor_flow_veh_h": (250.0, 400.0),
             "non_yielding_share": (0.5, 1.0), "max_vehicles": 14},
}  # fmt: skip


def episode_horizon_s(episode: EpisodeConfig, traffic: TrafficConfig | None) -> float:
    """How long an episode lasts [s]: ``episode.horizon_s``, or in traffic the traffic's
    ``horizon_s`` where it sets one (waiting in traffic takes longer than the paper's 12 s)."""
    if traffic is not None and traffic.horizon_s is not None:
        return traffic.horizon_s
    return episode.horizon_s


def traffic_config(traffic: TrafficConfig | str | dict[str, Any] | None) -> TrafficConfig | None:
    """A :class:`TrafficConfig` from itself, a preset's name, a dict (a preset may be named
    under ``preset``, the other keys override it) or ``None`` (no traffic: the paper's scene).

    Raises:
        ConfigError: An unknown preset or key, or a value out of range (named).
    """
    if traffic is None or isinstance(traffic, TrafficConfig):
        return traffic
    if isinstance(traffic, str):
        if traffic not in TRAFFIC_PRESETS:
            raise ConfigError(
                f"traffic={traffic!r} is not a preset ({', '.join(TRAFFIC_PRESETS)}) or a dict"
            )
        return from_dict(TrafficConfig, TRAFFIC_PRESETS[traffic], where="traffic")
    if isinstance(traffic, dict):
        data = dict(traffic)
        preset = data.pop("preset", None)
        if preset is not None:
            if preset not in TRAFFIC_PRESETS:
                known = list(TRAFFIC_PRESETS)
                raise ConfigError(f"traffic.preset={preset!r} is not one of {known}")
            data = {**TRAFFIC_PRESETS[preset], **data}
        return from_dict(TrafficConfig, data, where="traffic")
    raise ConfigError(f"traffic must be None, a preset name or a dict, got {traffic!r}")


def observed_as(traffic: TrafficConfig, seen: TrafficConfig) -> TrafficConfig:
    """``traffic`` as a policy trained in ``seen`` observes it (``seen``'s
    :data:`POLICY_OBSERVATION` settings): the observation belongs to the policy, not to the
    scene."""
    return replace(traffic, **{k: getattr(seen, k) for k in POLICY_OBSERVATION})


@dataclass(frozen=True)
class EpisodeConfig:
    """Episode timing and who drives when.

    Attributes:
        dt: Control and simulation tick [s] (paper: 50 Hz).
        horizon_s: Fixed episode length [s] (ours). A fixed horizon means a faster safe crossing
            always earns more: its extra ticks are spent near the speed limit instead of slow
            (no reward for dawdling, SPEC §2). 12 s covers the approach, a yield of several
            seconds and the exit.
        approach_distance_m: A car is "at the intersection" from this path distance before its
            conflict point until it has left its conflict zone [m] (ours): at 35 km/h that is
            3.1 s ahead, more than the TTR threshold plus a full stop, so every conflict the rule
            must resolve starts inside the window.
        learned_scope: ``"window"`` — Algorithm 1: ``PID_th`` drives unless both cars are at the
            intersection, then the learned controller (under the switching logic);
            ``"episode"`` — the learned controller drives the whole episode; ``"never"`` —
            ``PID_th`` always proposes (the purely rule-based baseline; the switching logic
            still applies).
        conflict_margin_m: Clearance added to both footprints when the conflict zones are
            computed [m] (ours).
        decision_interval: Ticks for which the learned controller's action is held: one
            environment step of the Gymnasium ``Env`` and the ``VecEnv`` is this many ticks
            (ours; 1 = a decision every 20 ms tick, the paper's rate). The plant, the
            rule-based controllers and the switching logic keep their 50 Hz: the safety net
            acts on every tick.
        end_on_reasons: Reasons of the switching logic whose safety action ends the episode
            as a collision would (ours; none by default). For training alone (``train_only``):
            under ``guarded`` the certified filter's overrules of the paper logic's own braking
            (``guard:…:overrules_primary``) are where the paper logic alone would have stopped
            the ego in the north car's path; ending the episode there gives the policy the
            outcome it would meet deployed under ``paper``, without the crash.
        observe_time_left: Append the time left in the episode [s] to the observation (ours;
            off: the paper's state). The episode's horizon is fixed and an episode that has not
            cleared by then counts as never cleared, so without it the policy cannot tell an
            early wait from a late one.
        horizon_terminates: End the episode at its horizon as a termination (``terminated``,
            no ``TimeLimit.truncated``: PPO bootstraps nothing after it) instead of a
            truncation (ours; off: the horizon truncates). With the time left observed the
            horizon is part of the task, and Pardo et al. ("Time Limits in Reinforcement
            Learning", ICML 2018) show its last state should then be treated as terminal;
            needs ``observe_time_left`` (without the clock the terminal would be aliased with
            states that go on). The end of the route still truncates.
        go_model: A learned go predictor for the single-car scene, an ``.npz`` written by
            ``experiments/go_leftturn.py`` (:class:`~safeswitch.leftturn.go_model.GoModel`):
            its probability that the planners' fast drive from the current state clears the
            conflict zone without the certified filter acting is appended to the
            observation, after everything else (ours; ``None``: none). It reads only the
            observation and is fitted to simulated outcomes, not to any controller's actions.
            In a configuration file a relative path is read beside the file (else from the
            working directory). In traffic use ``traffic.go_model``.
    """

    dt: Annotated[float, Bounds(0, 0.1, low_open=True, unit="s")] = 0.02
    horizon_s: Annotated[float, Bounds(1, 120, unit="s")] = 12.0
    approach_distance_m: Annotated[float, Bounds(5, 100, unit="m")] = 30.0
    learned_scope: LearnedScope = "window"
    conflict_margin_m: Annotated[float, Bounds(0, 2, unit="m")] = 0.3
    decision_interval: Annotated[int, Bounds(1, 50, unit="ticks")] = 1
    end_on_reasons: tuple[str, ...] = ()
    observe_time_left: bool = False
    horizon_terminates: bool = False
    go_model: str | None = None

    def __post_init__(self) -> None:
        check_bounds(self, "episode")
        check_go_model(self.go_model, "episode", "experiments/go_leftturn.py")
        check(not self.horizon_terminates or self.observe_time_left, "episode",
              "horizon_terminates", self.horizon_terminates,
              "needs episode.observe_time_left (without the time left in the observation the "
              "horizon's terminal state looks like the states that go on)")  # fmt: skip

    @property
    def horizon_ticks(self) -> int:
        return round(self.horizon_s / self.dt)


@dataclass(frozen=True)
class LeftTurnConfig:
    """Everything that defines the left-turn environment.

    Attributes:
        switching: Name of a registered switching logic (:mod:`safeswitch.core.registry`):
            ``"paper"`` (Algorithm 1), ``"certified"`` (safety filter), ``"none"`` (the learned
            action always), or a plugin's.
        logic_params: Parameters of a plugin logic registered with the class of its parameters
            (``register_logic(name, factory, config=Params)``), as a mapping of its keys
            (``null``: its defaults). The built-in logics take theirs from ``paper`` and
            ``certified`` below.
        adas_penalty: Whether ``R_ADAS`` is part of the reward (off: the paper's ablation).
        scenario: ``None`` for the random distribution, or a named scenario of Section VI.
        episode: Timing and scope of the learned controller.
        controllers: The rule-based controllers.
        paper: Parameters of the paper's switching logic.
        certified: Assumptions and margins of the certified switching logic.
        rewards: Reward terms.
        scenarios: The random scenario distribution.
        geometry: The intersection.
        vehicle: Vehicle parameters (both cars).
        perception: How the ego sees the other vehicles (default: perfectly).
    """

    switching: str = "paper"
    logic_params: dict[str, Any] | None = None
    adas_penalty: bool = True
    scenario: ScenarioName | None = None
    episode: EpisodeConfig = field(default_factory=EpisodeConfig)
    controllers: ControllerConfig = field(default_factory=ControllerConfig)
    paper: PaperSwitchingConfig = field(default_factory=PaperSwitchingConfig)
    certified: CertifiedConfig = field(default_factory=CertifiedConfig)
    rewards: RewardConfig = field(default_factory=RewardConfig)
    scenarios: ScenarioConfig = field(default_factory=ScenarioConfig)
    geometry: IntersectionGeometry = field(default_factory=IntersectionGeometry)
    vehicle: VehicleParams = field(default_factory=VehicleParams)
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)

    def __post_init__(self) -> None:
        if not isinstance(self.switching, str) or self.switching not in logic_names():
            raise ConfigError(
                f"switching={self.switching!r} is not a registered switching logic "
                f"(known: {', '.join(logic_names())})"
            )
        if self.logic_params:  # checked against the logic's own parameter class
            logic_params(self.switching, self.logic_params, "logic_params")
        if self.scenario is not None and self.scenario not in SCENARIO_NAMES:
            raise ConfigError(
                f"scenario={self.scenario!r} is not None or one of {list(SCENARIO_NAMES)}"
            )
        if not isinstance(self.adas_penalty, bool):
            raise ConfigError(f"adas_penalty={self.adas_penalty!r} must be True or False")
        grip = self.vehicle.friction_coefficient * GRAVITY
        check(self.certified.curve_lateral_accel < grip, "certified", "curve_lateral_accel",
              self.certified.curve_lateral_accel,
              f"must be below the tyres' μ·g ({grip:.2f} m/s²): the filter's braking in a "
              "curve needs the rest")  # fmt: skip
        dt = self.episode.dt
        self.perception.ticks(self.perception.latency_s, dt, "latency_s")
        if self.perception.dropout_prob > 0.0:
            check(self.perception.dropout_max_s >= dt, "perception", "dropout_max_s",
                  self.perception.dropout_max_s, f"must be at least one tick ({dt} s)")  # fmt: skip

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> LeftTurnConfig:
        """Build from plain nested data (e.g. YAML); unknown keys raise :class:`ConfigError`."""
        return from_dict(cls, data)


class _FromConfig:
    """Default of the environments' keyword arguments: "keep the configuration's value"."""

    def __repr__(self) -> str:
        return "<from config>"


#: Sentinel default of ``switching``, ``adas_penalty`` and ``scenario`` in the environments'
#: constructors: the value then comes from ``config`` (whose defaults are ``"paper"``, ``True``
#: and ``None``). ``scenario=None`` must stay expressible, so ``None`` cannot be the sentinel.
FROM_CONFIG: Any = _FromConfig()


def resolve_config(
    config: LeftTurnConfig | dict[str, Any] | None = None, **overrides: Any
) -> LeftTurnConfig:
    """A config from a config, a dict or nothing, with top-level fields overridden (overrides
    equal to :data:`FROM_CONFIG` are ignored). An override replaces the whole field; it may be
    given as plain data (``episode={"horizon_s": 8}``) and is validated like a config file."""
    overrides = {k: v for k, v in overrides.items() if v is not FROM_CONFIG}
    if config is None:
        config = LeftTurnConfig()
    elif isinstance(config, dict):
        config = LeftTurnConfig.from_dict(config)
    elif not isinstance(config, LeftTurnConfig):
        raise ConfigError(f"config must be a LeftTurnConfig, a dict or None, got {config!r}")
    valid = {f.name for f in fields(LeftTurnConfig)}
    for key in overrides:
        if key not in valid:
            raise ConfigError(f"unknown environment argument {key!r} (valid: {sorted(valid)})")
    if not overrides:
        return config
    merged = to_dict(config) | {key: to_dict(value) for key, value in overrides.items()}
    return LeftTurnConfig.from_dict(merged)
