"""The left-turn task as batched functions: initial state, one tick, observation.

The Gymnasium ``Env`` and the Stable-Baselines3 ``VecEnv`` are thin shells over
:class:`LeftTurnTask`; one code path serves a batch of 1 and a batch of 10,000.

One tick (paper Fig. 3 and Algorithm 1):

1. All controllers run side by side: ``PID_th`` (throttle to the speed limit), ``PID_b`` (the
   Safety controller: brake to track ``a_max``), ``PID_lka`` (steering, both cars), the north
   car's autopilot, and the learned action ``a ∈ [-1, 1]`` → throttle ``(a + 1) / 2`` (or, as
   the scene's ``controllers`` choose, a speed set point or both pedals: :meth:`learned_pedals`).
2. Who proposes the ego's pedals: the learned controller while both cars are at the
   intersection (or always, with ``learned_scope="episode"``), ``PID_th`` otherwise.
3. The switching logic — the registered logic named by ``config.switching`` — decides through
   the framework's one supervision step, :func:`safeswitch.core.switching.supervise`: a NaN/inf
   learned action is never executed — the pedals are held where they are (a zero-order hold of
   the last command, as the actuators have it) and the logic judges that as any proposal —
   and the proposal or the safety action reaches the plant.
4. The plant advances 20 ms; the five reward terms are computed from the new state.

Steps 1, 4 and the bookkeeping are loops compiled with numba over the episodes
(:func:`_controllers`, the world's tick, :func:`_after_plant`), built from the same scalar
functions the numpy-facing API runs (``pid_tick``, ``vehicle_tick``, ``tick_terms``, …); the
logics' ``decide`` runs its own compiled loop. A tick costs a few dozen Python calls whatever
the batch size, so the Gymnasium ``Env`` is fast too.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, fields, replace
from functools import cached_property
from typing import Any, NamedTuple, cast

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import clamp, columns, jit, plain, put_rows, take_rows
from safeswitch.core.config import ConfigError
from safeswitch.core.pid import PIDState, pid_tick
from safeswitch.core.pid_gains import PIDKernel
from safeswitch.core.registry import make_logic
from safeswitch.core.switching import Supervision, SwitchingLogic, reason_names, supervise
from safeswitch.leftturn.config import LeftTurnConfig, ScenarioConfig
from safeswitch.leftturn.go_model import GoModel
from safeswitch.leftturn.perception import Perception, PerceptionState, Sighted, episode_keys
from safeswitch.leftturn.rewards import REWARD_TERMS, reward_tables, tick_terms
from safeswitch.leftturn.scenarios import (
    Scenarios,
    counter_uniforms,
    farthest_starts,
    named_scenarios,
    sample_scenarios,
    scenario_uniforms,
)
from safeswitch.leftturn.views import (
    ConflictView,
    NorthConflict,
    Phantoms,
    approaching,
    at_intersection,
    north_view,
)
from safeswitch.sim.autopilot import AutopilotParams, autopilot_tick
from safeswitch.sim.conflict import ConflictGeometry, conflict_geometry
from safeswitch.sim.geometry import FloatArray, IntArray, preview
from safeswitch.sim.road import Intersection
from safeswitch.sim.vehicle import VehicleConstants, steady_state_throttle
from safeswitch.sim.world import World, WorldState

BoolArray = NDArray[np.bool_]

#: Who proposed the executed action: codes of :attr:`StepRecord.controller`.
CONTROLLERS: tuple[str, ...] = ("learned", "rule", "safety")
#: Reason of a tick on which ``PID_th`` proposed (outside the learned controller's scope) and
#: the switching logic accepted it.
RULE_IN_CHARGE = "rule_in_charge"
#: Codes of :attr:`TaskState.outcome`: decided on the tick the ego clears its conflict zone
#: with the north car — ``cut`` if the north car has not yet left its own zone then, ``yield``
#: if it has; ``undecided`` until then (at an episode's end: the ego never cleared), so that
#: cut + yield = cleared in every count.
OUTCOMES: tuple[str, ...] = ("undecided", "cut", "yield")

#: (vehicle field, slot) of each observation column: (x_e, y_e, v_e, x_n, y_n, v_n).
_OBSERVED = (("x", 0), ("y", 0), ("speed", 0), ("x", 1), ("y", 1), ("speed", 1))
#: Bounds of the observation (x_e, y_e, v_e, x_n, y_n, v_n) [m, m, m/s, m, m, m/s].
OBSERVATION_LOW = np.array([-150, -150, 0, -150, -150, 0], dtype=np.float32)
OBSERVATION_HIGH = np.array([150, 150, 60, 150, 150, 60], dtype=np.float32)


@dataclass
class TaskState:
    """State of ``B`` episodes.

    Attributes:
        world: The plant: ego (slot 0) and north car (slot 1), arrays ``[B, 2]``.
        scenarios: Scenario parameters ``[B]``.
        pid_throttle: ``PID_th`` memory ``[B]``.
        pid_brake: ``PID_b`` memory ``[B]``.
        pid_lane: ``PID_lka`` memory, both cars ``[B, 2]``.
        pid_north: Autopilot speed controller memory ``[B]``.
        accel_lon: Ego's longitudinal acceleration measured on the last tick [m/s²] ``[B]``
            (``PID_b``'s feedback).
        tick: Ticks since the episode started ``[B]``.
        outcome: Who crossed first, a code of :data:`OUTCOMES` ``[B]``.
        perception: What the ego's sensor and tracker know of the other vehicles, column 0 the
            north car (:mod:`~safeswitch.leftturn.perception`); ``None`` with perfect
            perception.
    """

    world: WorldState
    scenarios: Scenarios
    pid_throttle: PIDState
    pid_brake: PIDState
    pid_lane: PIDState
    pid_north: PIDState
    accel_lon: FloatArray
    tick: NDArray[np.int64]
    outcome: NDArray[np.int8]
    perception: PerceptionState | None

    @property
    def batch_size(self) -> int:
        return int(self.tick.shape[0])

    def replace_at(self, index: NDArray[np.intp], other: TaskState) -> None:
        """Overwrite episodes ``index`` with the ``len(index)`` episodes of ``other``, in place
        (auto-reset of the episodes that ended)."""
        put_rows(self, index, other)

    def take(self, index: NDArray[np.intp]) -> TaskState:
        """A copy of episodes ``index`` (steps exactly as they would in the full batch: every
        episode is simulated on its own)."""
        return cast(TaskState, take_rows(self, index))


@dataclass
class ConflictArrays:
    """The ego's conflict zones with every other vehicle, for measures taken at them
    (:mod:`safeswitch.evaluation.surrogate`); ``C`` conflicts per episode.

    Attributes:
        ego_progress: Ego's arc length [m] ``[B]``.
        ego_speed: Ego's speed [m/s] ``[B]``.
        present: The conflict exists (its vehicle is there and crosses the ego's route)
            ``[B, C]``.
        ego_zone: The ego's conflict zone ``(enter, exit)`` [m] ``[B, C, 2]``.
        other_progress: The other vehicle's arc length [m] ``[B, C]``.
        other_speed: Its speed [m/s] ``[B, C]``.
        other_zone: Its conflict zone [m] ``[B, C, 2]``.
    """

    ego_progress: FloatArray
    ego_speed: FloatArray
    present: BoolArray
    ego_zone: FloatArray
    other_progress: FloatArray
    other_speed: FloatArray
    other_zone: FloatArray


class ConflictTimeline(NamedTuple):
    """The ego's conflicts on every tick of an episode in which the others drive as if the ego
    were not there, as the paper logic sees them: what the logic-aware limit plans against
    (:mod:`safeswitch.evaluation.logic_limit`). Arrays ``[B, H + 1, C]`` unless noted.

    Attributes:
        start: The ego's start ``(s0, v0)`` [m, m/s] ``[B, 2]``.
        present: The conflict exists (its vehicle is there and crosses the ego's route).
        ego_entry: Where the ego's conflict zone begins on its route [m].
        ego_exit: Where it ends [m].
        ego_point: The conflict point on the ego's route [m].
        other_distance: The other vehicle's path distance to its conflict point [m].
        other_inside: The other vehicle is inside its conflict zone.
        other_window: It is "at the intersection" in Algorithm 1's sense: within the approach
            distance of its conflict point and not past its zone.
        other_speed: Its speed [m/s].
    """

    start: FloatArray
    present: BoolArray
    ego_entry: FloatArray
    ego_exit: FloatArray
    ego_point: FloatArray
    other_distance: FloatArray
    other_inside: BoolArray
    other_window: BoolArray
    other_speed: FloatArray


class WithoutEgo(NamedTuple):
    """The other vehicles' world on every tick of an episode as if the ego were not there
    (nobody gives way to it or follows it; it holds a zero action): what the oracle plans
    against (:mod:`safeswitch.evaluation.oracle`). In the paper's scene the north car never
    reacts to the ego, so this is any rollout's north car.

    Attributes:
        start: The ego's start ``(s0, v0)`` [m, m/s] ``[B, 2]``.
        north: The north car's arc length [m] ``[B, H + 1]``.
        north_speed: Its speed [m/s] ``[B, H + 1]``.
        occupied: Per movement of :meth:`LeftTurnTask.crossing_zones`, whether a vehicle on it
            is inside its conflict zone with the ego's route ``[B, R, H + 1]`` (``R = 0`` in the
            paper's scene).
        zones: The ego's zone with each of those movements, on its route [m] ``[R, 2]``.
    """

    start: FloatArray
    north: FloatArray
    north_speed: FloatArray
    occupied: BoolArray
    zones: FloatArray


@dataclass
class StepRecord:
    """Everything that happened on one tick, each field ``[B]`` (``observation``: ``[B, 6]``).

    Attributes:
        observation: The state after the tick (x_e, y_e, v_e, x_n, y_n, v_n), float32;
            ``None`` where :meth:`LeftTurnTask.step` was asked not to observe it.
        reward: Sum of the reward terms (plus the collision penalty, if configured).
        terms: The five reward terms of Eq. 5, keyed by :data:`REWARD_TERMS`.
        terminated: The episode ended in a failure: a collision or a loss of control.
        truncated: The episode hit its time horizon or the end of the ego's route.
        collision: The cars' footprints touch or overlap.
        lost_control: The ego left its lane: more than half a lane width off its route (its
            tyres slid, :mod:`safeswitch.sim.vehicle`).
        safety_active: The safety action was executed (the paper's ``s*``).
        reason: Reason code of the switching decision, into :attr:`LeftTurnTask.reasons`.
        controller: Who proposed the executed action, a code of :data:`CONTROLLERS`.
        both_at_intersection: Algorithm 1's While condition held at the start of the tick.
        learned_throttle: Throttle the learned action asked for (NaN if it was NaN; outside
            [0, 1] if the action was outside [-1, 1]).
        learned_brake: Brake the learned action asked for, in [0, 1] (always 0 but with
            ``controllers.learned_brake``; on its ticks ``learned_throttle`` is 0).
        action_clipped: The learned action was outside [-1, 1] and was clipped (where the
            learned controller was in charge).
        safety_brake: Brake the Safety controller ``PID_b`` computed.
        throttle: Executed throttle command.
        brake: Executed brake command.
        ego_speed: Ego speed after the tick [m/s].
        north_speed: North car speed after the tick [m/s].
        accel_lon: Ego longitudinal acceleration over the tick [m/s²].
        accel_lat: Ego lateral acceleration [m/s²] (what its tyres gave).
        grip_demand: The combined acceleration the ego's pedals and steering asked for, as a
            share of the tyres' ``μ·g`` (above 1: they slid this tick).
        lateral: Ego lateral deviation from its route [m].
        separation: Gap between the two footprints [m] (``<= 0``: collision).
        outcome: Who crossed first so far, a code of :data:`OUTCOMES`.
        ego_cleared: The ego has left its conflict zone.
    """

    observation: NDArray[np.float32] | None
    reward: FloatArray
    terms: dict[str, FloatArray]
    terminated: BoolArray
    truncated: BoolArray
    collision: BoolArray
    lost_control: BoolArray
    safety_active: BoolArray
    reason: NDArray[np.int8]
    controller: NDArray[np.int8]
    both_at_intersection: BoolArray
    learned_throttle: FloatArray
    learned_brake: FloatArray
    action_clipped: BoolArray
    safety_brake: FloatArray
    throttle: FloatArray
    brake: FloatArray
    ego_speed: FloatArray
    north_speed: FloatArray
    accel_lon: FloatArray
    accel_lat: FloatArray
    grip_demand: FloatArray
    lateral: FloatArray
    separation: FloatArray
    outcome: NDArray[np.int8]
    ego_cleared: BoolArray

    @property
    def observed(self) -> NDArray[np.float32]:
        """The observation, which :meth:`LeftTurnTask.hold` always takes.

        Raises:
            RuntimeError: The tick was stepped without it (``step(..., observe=False)``).
        """
        if self.observation is None:
            raise RuntimeError("this tick was stepped with observe=False: it has no observation")
        return self.observation


class _SceneThenLogic(type):
    """Constructs a task, then builds its switching logic: the logic's factory reads the scene's
    typed hooks (:class:`~safeswitch.leftturn.views.LogicScene`), so it runs once the whole
    scene — a subclass's included — is built, and a logic that does not fit it, or an
    ``episode.end_on_reasons`` it does not have, is refused at construction."""

    def __call__(cls, *args: Any, **kwargs: Any) -> Any:
        task = super().__call__(*args, **kwargs)
        task.check_logic()
        return task


class LeftTurnTask(metaclass=_SceneThenLogic):
    """The unprotected left turn as batched functions over :class:`TaskState`.

    Args:
        config: The full configuration.
    """

    def __init__(self, config: LeftTurnConfig) -> None:
        self.config = config
        self.intersection = Intersection(config.geometry)
        self.world = World(
            [self.intersection.route("south", "west"), self.intersection.route("north", "south")],
            config.vehicle,
            config.episode.dt,
        )
        footprint = (config.vehicle.length, config.vehicle.width)
        self.conflict: ConflictGeometry = conflict_geometry(
            self.world.routes[0],
            self.world.routes[1],
            footprint,
            footprint,
            margin=config.episode.conflict_margin_m,
        )
        cert = conflict_geometry(
            self.world.routes[0], self.world.routes[1], footprint, footprint,
            margin=config.certified.zone_margin_m,
        )  # fmt: skip
        #: The geometry of the ego's conflict with the north car (both margins).
        self.north_conflict = NorthConflict(
            self.conflict.s_point_a, self.conflict.zone_a, cert.zone_a, self.conflict.s_point_b,
            self.conflict.zone_b, cert.zone_b, config.episode.approach_distance_m,
        )  # fmt: skip
        if config.scenario is None:
            self.check_scenarios(config.scenarios)
        #: The ego's sensor and tracker of the other vehicles (``None``: perfect perception).
        self.perception: Perception | None = None
        if not config.perception.perfect:
            self.perception = Perception(config)
        self.autopilot = AutopilotParams(steer_gains=config.controllers.lane_pid)
        self._ego_route_end = self.world.routes[0].length - 1.0
        ctrl = config.controllers
        #: What the compiled controllers read: PID_th, PID_b, PID_lka and the north car's speed
        #: controller, and the plant's constants (for its feed-forward).
        self._gains = ControllerGains(
            ctrl.throttle_pid.kernel,
            ctrl.brake_pid.kernel,
            ctrl.lane_pid.kernel,
            self.autopilot.speed_gains.kernel,
        )
        self._plant = self.world.vehicle_constants
        r, geo = config.rewards, self.conflict
        self._reward_tables = reward_tables(r)
        ep = config.episode
        self._scope_code = LEARNED_SCOPES.index(ep.learned_scope)
        self._limits = EpisodeLimits(
            ep.horizon_ticks, self._ego_route_end, geo.zone_a[1], geo.zone_b[1],
            config.geometry.lane_width / 2.0,
        )  # fmt: skip
        routes = self.world.route_set
        #: Everything the compiled controllers read that stays fixed for the task (plain
        #: tuples at the kernel's entry, see plain).
        self._controller_constants = plain(ControllerConstants(
            self._gains, ep.dt, ctrl.speed_limit, ctrl.emergency_decel, ctrl.lane_lookahead_m,
            self._plant, routes.tables, routes.spacing, routes.size - 2, self.world.route_base,
            self.north_conflict, self._scope_code,
        ))  # fmt: skip
        #: The learned controller's speed limiter (``None`` if off): its speed [m/s], the
        #: throttle that holds that speed and the gain (see ControllerConfig).
        self._limiter: tuple[float, float, float] | None = None
        if ctrl.learned_speed_limiter_kmh is not None:
            v_cap = ctrl.learned_speed_limiter_kmh / 3.6
            hold = float(steady_state_throttle(config.vehicle, np.asarray(v_cap)))
            self._limiter = (v_cap, hold, ctrl.learned_speed_limiter_gain)
        #: The curve limiter's cap along the ego's route (``None`` if off): the waypoint
        #: spacing [m], the cap at each waypoint [m/s] and the throttle that holds it.
        self._curve_caps: tuple[float, FloatArray, FloatArray] | None = None
        if ctrl.learned_curve_accel is not None and self._limiter is not None:
            spacing, caps = self.curve_speed_caps(
                ctrl.learned_curve_accel, ctrl.learned_curve_decel, self._limiter[0]
            )
            self._curve_caps = (spacing, caps, steady_state_throttle(config.vehicle, caps))
        #: The learned action's speed command (``None``: the action is the throttle): the
        #: speed of ``a = 1`` [m/s] and the tracking gain (see ControllerConfig).
        self._command: tuple[float, float] | None = None
        if ctrl.learned_speed_command_kmh is not None:
            self._command = (ctrl.learned_speed_command_kmh / 3.6, ctrl.learned_speed_command_gain)
        self._throttle_action = ctrl.throttle_action

    # -- the switching logic, built once the whole scene (a subclass's too) is ---------------

    @cached_property
    def _bookkeeping_constants(self) -> tuple[Any, ...]:
        """Everything the compiled bookkeeping reads that stays fixed for the task, as plain
        tuples (the rule's reason code comes from the logic, so it is built on first use)."""
        r = self.config.rewards
        return plain(BookkeepingConstants(
            self._reward_tables, r.adas_penalty if self.config.adas_penalty else 0.0,
            r.collision_penalty, self._limits, len(self.reasons) - 1,
        ))  # fmt: skip

    @cached_property
    def switching(self) -> SwitchingLogic[ConflictView]:
        """The switching logic: the registered logic named by ``config.switching``, built from
        the finished scene (its factory reads the scene's typed hooks,
        :class:`~safeswitch.leftturn.views.LogicScene`)."""
        return make_logic(self.config.switching, self, self.config.logic_params)

    @cached_property
    def reasons(self) -> tuple[str, ...]:
        """Reason names of :attr:`StepRecord.reason`: the logic's, ``invalid_learned_action``,
        then :data:`RULE_IN_CHARGE` (the logic accepted ``PID_th``'s proposal because the
        learned controller was not in charge; ``"learned"`` always means the learned action
        itself ran)."""
        return (*reason_names(self.switching), RULE_IN_CHARGE)

    @cached_property
    def _ends_episode(self) -> BoolArray | None:
        """Per reason code: its safety action ends the episode (``episode.end_on_reasons``)."""
        ends = self.config.episode.end_on_reasons
        unknown = sorted(set(ends) - set(self.reasons[1:-1]))
        if unknown:
            raise ValueError(
                f"episode.end_on_reasons: {unknown} not reasons of the switching logic "
                f"{self.config.switching!r} (its reasons: {', '.join(self.reasons[1:-1])})"
            )
        return np.isin(np.array(self.reasons), ends) if ends else None

    def _ended_as_terminal(
        self,
        safety_active: BoolArray,
        reason: NDArray[np.int8],
        truncated: BoolArray,
        tick: NDArray[np.int64],
    ) -> BoolArray | None:
        """Per episode: the step ends it as a termination the plant's own rules do not — a
        safety action of a reason in ``episode.end_on_reasons``, or its horizon with
        ``episode.horizon_terminates`` (``None``: neither option is on)."""
        ended = None
        if self._ends_episode is not None:
            ended = safety_active & self._ends_episode[reason]
        if self.config.episode.horizon_terminates:
            at_horizon = truncated & (tick >= self.config.episode.horizon_ticks)
            ended = at_horizon if ended is None else ended | at_horizon
        return ended

    def check_logic(self) -> None:
        """Build the switching logic and check ``episode.end_on_reasons`` against its reasons
        (run by the constructor, after the scene is built)."""
        _ = self._ends_episode

    # -- pure functions -------------------------------------------------------------------

    def draw_scenarios(
        self, seed: int, env_ids: NDArray[np.int64], episodes: NDArray[np.int64]
    ) -> Scenarios:
        """The scenarios of episodes ``episodes`` of environments ``env_ids`` under ``seed``:
        the configured named scenario, or draws from the random distribution."""
        if self.config.scenario is not None:
            return named_scenarios(self.config.scenario, len(env_ids))
        draws = counter_uniforms(seed, env_ids, episodes, scenario_uniforms(self.config.scenarios))
        return sample_scenarios(self.config.scenarios, draws)

    def check_scenarios(self, scenarios: ScenarioConfig) -> None:
        """Refuse a scenario distribution that would start a car before the start of its
        route, before any episode runs.

        Raises:
            ConfigError: Naming the values that do not fit and the largest that would.
        """
        v_lim = self.config.controllers.speed_limit
        ego, north, offset = farthest_starts(scenarios, v_lim)
        ego_room, north_room = self.conflict.s_point_a, self.conflict.s_point_b
        if ego > ego_room:
            raise ConfigError(
                f"scenarios.ego_start_distance_m: up to {ego:g} m, but the ego's route starts "
                f"{ego_room:.1f} m before the conflict point (geometry.approach_length "
                f"{self.config.geometry.approach_length:g} m)"
            )
        if north > north_room:
            speed = scenarios.north_speed_kmh[1]
            if scenarios.focus_share > 0:
                speed = max(speed, scenarios.focused("north_speed_kmh")[1])
            ego_arrival = ego / v_lim
            fits_speed = math.floor(north_room / (ego_arrival + offset) * 3.6 * 10) / 10
            fits_offset = math.floor((north_room / (speed / 3.6) - ego_arrival) * 10) / 10
            raise ConfigError(
                f"scenarios: the north car at up to {speed:g} km/h, arriving up to {offset:g} s "
                f"after the ego (arrival_offset_s; the ego starting up to {ego:g} m out at the "
                f"{v_lim * 3.6:g} km/h limit), starts up to {north:.1f} m before the conflict "
                f"point, but its route starts {north_room:.1f} m before it: lower "
                f"(focus_)north_speed_kmh's upper end to at most {fits_speed:g} km/h or "
                f"arrival_offset_s's to at most {fits_offset:g} s"
            )

    def named(self, name: str, batch: int, seed: int = 0) -> Scenarios:
        """A named scenario of the paper (``cut``, ``yield1``, ``yield2``) ``batch`` times; a
        scene with other vehicles draws them around it from ``seed`` (here there are none)."""
        return named_scenarios(name, batch)

    def scenario_set(self, seed: int, count: int) -> Scenarios:
        """A fixed set of ``count`` scenarios under ``seed`` (the first episode of environments
        ``0 … count-1``): what an evaluation, a validation or a benchmark drives."""
        return self.draw_scenarios(seed, np.arange(count), np.zeros(count, dtype=np.int64))

    def initial(self, scenarios: Scenarios) -> TaskState:
        """Episodes at their start: both cars on their routes at the scenario's speeds."""
        c = self.config
        batch = scenarios.ego_speed.shape[0]
        v_lim = c.controllers.speed_limit
        progress = np.stack(
            [
                self.conflict.s_point_a - scenarios.ego_start_distance,
                self.conflict.s_point_b - scenarios.north_start_distance(v_lim),
            ],
            axis=1,
        )
        if np.any(progress < 0):
            row, car = (int(i) for i in np.argwhere(progress < 0)[0])
            raise ValueError(
                f"a scenario starts a car before the start of its route: scenario {row} starts "
                f"the {('ego', 'north car')[car]} {-progress[row, car]:.1f} m before (ego start "
                f"{scenarios.ego_start_distance[row]:g} m, north car at "
                f"{scenarios.north_speed[row] * 3.6:g} km/h arriving "
                f"{scenarios.arrival_offset[row]:g} s after the ego); shorten "
                "ego_start_distance_m or arrival_offset_s"
            )
        speed = np.stack([scenarios.ego_speed, scenarios.north_speed], axis=1)
        world = self.world.place(progress, speed)
        memory = self.controller_memory(batch)
        perception = None
        if self.perception is not None:
            key = episode_keys([getattr(scenarios, f.name) for f in fields(Scenarios)])
            sighted = self.sighted(world, self.others_at_start(scenarios), None)
            perception = self.perception.initial(sighted, key)
        return TaskState(
            world=world,
            scenarios=Scenarios(*(getattr(scenarios, f.name).copy() for f in fields(Scenarios))),
            pid_throttle=memory.throttle,
            pid_brake=memory.brake,
            pid_lane=memory.lane,
            pid_north=memory.north,
            accel_lon=np.zeros(batch),
            tick=np.zeros(batch, dtype=np.int64),
            outcome=np.zeros(batch, dtype=np.int8),
            perception=perception,
        )

    def controller_memory(self, batch: int) -> ControllerMemory:
        """The controllers' memory at the start of ``batch`` episodes, bumpless: ``PID_th``'s
        integral holds the throttle that cruises at the speed limit, ``PID_b``'s the brake of
        :meth:`brake_feedforward`."""
        c = self.config
        gains = c.controllers.throttle_pid
        cruise = float(steady_state_throttle(c.vehicle, np.asarray(c.controllers.speed_limit)))
        return ControllerMemory(
            PIDState.zeros((batch,), cruise / gains.ki if gains.ki > 0 else 0.0),
            PIDState.zeros((batch,), self.brake_feedforward()),
            PIDState.zeros((batch, 2)),
            PIDState.zeros((batch,)),
        )

    def brake_feedforward(self) -> float:
        """Initial integral of ``PID_b``: the brake that decelerates at ``a_max`` on a level
        road, divided by ``ki`` (bumpless start)."""
        c = self.config
        brake = c.controllers.emergency_decel * c.vehicle.mass / c.vehicle.max_brake_force
        ki = c.controllers.brake_pid.ki
        return min(brake, 1.0) / ki if ki > 0 else 0.0

    def curve_speed_caps(self, accel: float, decel: float, top: float) -> tuple[float, FloatArray]:
        """The curve limiter's cap along the ego's route: at each waypoint the highest speed
        [m/s] from which slowing at ``decel`` [m/s²] keeps ``v² |κ| <= accel`` at every
        waypoint ahead, and no more than ``top``; with the waypoint spacing [m]."""
        # The same backward pass as the traffic drivers' curve envelope
        # (safeswitch.sim.streams.curve_envelope), here on speeds, not their squares: the
        # shipped traffic-certified policy was trained with these caps, and caps from the
        # envelope differ in their last bits (23 of 517 waypoints), enough to change its run
        # from the second rollout on. Merge the two when that policy is next retrained.
        spacing, kappa = self.ego_curvature()
        at_curve = np.sqrt(accel / np.maximum(kappa, 1e-9))
        caps = np.minimum(at_curve, top)
        for i in range(len(caps) - 2, -1, -1):  # backward: the cap a coast still meets
            caps[i] = min(caps[i], float(np.sqrt(caps[i + 1] ** 2 + 2.0 * decel * spacing)))
        return spacing, caps

    def limit_speed(
        self, throttle: FloatArray, speed: FloatArray, progress: FloatArray | None = None
    ) -> FloatArray:
        """The learned controller's speed limiter (``controllers.learned_speed_limiter_kmh``):
        ``throttle`` no higher than the limiter's cap at ``speed`` (NaN stays NaN); with the
        curve limiter (``controllers.learned_curve_accel``), the cap at the ego's route
        ``progress`` [m]; without a limiter, ``throttle`` unchanged."""
        if self._limiter is None:
            return throttle
        top, held, gain = self._limiter
        v_cap: FloatArray | float = top
        hold: FloatArray | float = held
        if self._curve_caps is not None and progress is not None:
            spacing, caps, holds = self._curve_caps
            index = np.clip(np.rint(progress / spacing).astype(np.int64), 0, len(caps) - 1)
            v_cap, hold = caps[index], holds[index]
        return np.minimum(throttle, np.clip(hold + gain * (v_cap - speed), 0.0, 1.0))

    def learned_pedals(self, action: FloatArray, speed: FloatArray) -> LearnedPedals:
        """The learned controller's pedals for ``action`` at the ego's ``speed`` [m/s]: the
        paper's throttle ``(a + 1) / 2``; with ``controllers.learned_speed_command_kmh``, the
        throttle that tracks the commanded speed; with ``controllers.learned_brake``, the
        throttle ``a ≥ 0`` or the brake ``−a``. NaN/inf stays NaN/inf (refused by the logic)."""
        if self._throttle_action:
            return LearnedPedals(0.5 * (action + 1.0), None, None)
        finite = np.isfinite(action)
        over = finite & (np.abs(action) > 1.0)
        a = clamp(action, -1.0, 1.0)
        brake = None
        if self._command is None:  # both pedals
            throttle, brake = np.maximum(a, 0.0), np.maximum(-a, 0.0)
        else:
            v_top, gain = self._command
            target = 0.5 * (a + 1.0) * v_top
            throttle = steady_state_throttle(self.config.vehicle, target) + gain * (target - speed)
            throttle = clamp(throttle, 0.0, 1.0)
        throttle[~finite] = action[~finite]
        return LearnedPedals(throttle, brake, over)

    @property
    def scene_observation_bounds(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Lower and upper bounds of what the observation holds of the scene (here the paper's
        six values; a task in traffic adds its other vehicles)."""
        return OBSERVATION_LOW, OBSERVATION_HIGH

    @property
    def observation_bounds(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Lower and upper bounds of :meth:`observe`'s values: the scene's, then, with
        ``episode.observe_time_left``, the time left [0, horizon] s, then, with a go
        predictor (:attr:`go_model`), its probability in [0, 1]."""
        low, high = self._bounds_before_go()
        if self.go_model is None:
            return low, high
        return np.append(low, np.float32(0.0)), np.append(high, np.float32(1.0))

    def _bounds_before_go(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        low, high = self.scene_observation_bounds
        if self.config.episode.observe_time_left:
            low = np.append(low, np.float32(0.0))
            high = np.append(high, np.float32(self.config.episode.horizon_s))
        return low, high

    @property
    def go_model_setting(self) -> tuple[str, str | None]:
        """The setting that names the task's go predictor, and its value (``None``: none)."""
        return "episode.go_model", self.config.episode.go_model

    @cached_property
    def go_model(self) -> GoModel | None:
        """The learned go predictor whose probability ends the observation (ours;
        :class:`~safeswitch.leftturn.go_model.GoModel`), or ``None``."""
        setting, path = self.go_model_setting
        if path is None:
            return None
        return GoModel(path, self._bounds_before_go()[0].shape[0], setting)

    def observe(self, state: TaskState) -> NDArray[np.float32]:
        """The paper's state ``s = (x_e, y_e, v_e, x_n, y_n, v_n)``, ``[B, 6]`` float32 (the
        north car as the ego sees it), completed by :meth:`complete_observation`."""
        v = state.world.vehicles
        out = np.empty((state.batch_size, 6), dtype=np.float32)
        for j, (field, slot) in enumerate(_OBSERVED):
            out[:, j] = getattr(v, field)[:, slot]
        return self.complete_observation(state, self.seen_north(state, out))

    def complete_observation(
        self, state: TaskState, observation: NDArray[np.float32]
    ) -> NDArray[np.float32]:
        """The observation from the plant's six values (as the ego sees them): the task's
        :meth:`extend_observation`, then, with ``episode.observe_time_left``, the time left in
        the episode [s] (ours, off by default: the horizon is part of the state of a
        fixed-horizon task — Pardo et al., "Time Limits in Reinforcement Learning", ICML 2018),
        then, with a go predictor (:attr:`go_model`), its probability on all of that as the
        last value."""
        out = self.extend_observation(state, observation)
        episode = self.config.episode
        if episode.observe_time_left:
            left = np.maximum(episode.horizon_ticks - state.tick, 0) * episode.dt
            out = np.concatenate([out, left.astype(np.float32)[:, None]], axis=1)
        if self.go_model is not None:
            out = np.concatenate([out, self.go_model(out)[:, None]], axis=1)
        return out

    def seen_north(self, state: TaskState, observation: NDArray[np.float32]) -> NDArray[np.float32]:
        """``observation`` with the north car's values as the ego sees them (in place; within
        the observation's bounds: a car not yet seen stands at the edge of the sight distance,
        which may lie beyond them)."""
        seen = state.perception
        if seen is not None:
            progress = seen.progress[:, 0]
            x, y, _ = self.world.route_set.pose_at_flat(self.world.route_base[1], progress)
            low, high = OBSERVATION_LOW[3:], OBSERVATION_HIGH[3:]
            observation[:, 3:] = np.clip(np.stack([x, y, seen.speed[:, 0]], 1), low, high)
        return observation

    def sighted(self, world: WorldState, others: Any, before: TaskState | None) -> Sighted:
        """What the sensor looks at after a tick that led to ``world`` (and ``others``, the
        other traffic; ``before``: the state before the tick, ``None`` at an episode's start):
        here the north car alone, always in the scene."""
        batch = world.progress.shape[0]
        column = self._north_column(batch)
        return Sighted(
            world.progress[:, 1:2], world.vehicles.speed[:, 1:2], column.exists, column.fresh,
            column.point, column.exit, column.exists,
        )  # fmt: skip

    def _north_column(self, batch: int) -> Sighted:
        """The fixed columns of the north car's :class:`Sighted` for ``batch`` episodes."""
        cached = self.__dict__.get("_north_sighted")
        if cached is None or cached.exists.shape[0] != batch:
            ones = np.ones((batch, 1), dtype=np.bool_)
            cached = Sighted(
                np.empty((batch, 1)), np.empty((batch, 1)), ones, np.zeros_like(ones),
                np.full((batch, 1), self.conflict.s_point_b),
                np.full((batch, 1), self.conflict.zone_b[1]), ones,
            )  # fmt: skip
            self.__dict__["_north_sighted"] = cached
        return cast(Sighted, cached)

    def both_at_intersection(self, ego_progress: FloatArray, north_progress: FloatArray) -> Any:
        """Algorithm 1's While condition for arc lengths of any (common) shape."""
        return at_intersection(ego_progress, north_progress, self.north_conflict)

    def view(
        self, state: TaskState, window: BoolArray | None = None, truth: bool = False
    ) -> ConflictView:
        """What the switching logics see of ``state``: the ego and its conflicts (here one, the
        north car's), the others as perceived (``truth``: as they are, for measures).
        ``window``: Algorithm 1's While condition if already known."""
        v, progress, seen = state.world.vehicles, state.world.progress, state.perception
        if seen is None or truth:
            return north_view(
                self.north_conflict, progress[:, 0], v.speed[:, 0], v.throttle[:, 0],
                v.brake[:, 0], progress[:, 1], v.speed[:, 1], state.scenarios.north_speed, window,
            )  # fmt: skip
        return north_view(
            self.north_conflict, progress[:, 0], v.speed[:, 0], v.throttle[:, 0], v.brake[:, 0],
            seen.progress[:, 0], seen.speed[:, 0], state.scenarios.north_speed, window,
            tuple(a[:, 0] for a in Perception.uncertainty(seen)),  # type: ignore[arg-type]
        )  # fmt: skip

    def phantoms(self) -> Phantoms:
        """The vehicles still to come that the certificate must beat: none in the paper's
        scene."""
        return Phantoms.none()

    def ego_curvature(self) -> tuple[float, FloatArray]:
        """The ego's route: its waypoint spacing [m] and ``|κ|`` at each waypoint [1/m] (what
        the certified logic keeps the ego's cornering within)."""
        route = self.world.routes[0]
        return route.spacing, np.abs(route.curvature)

    @property
    def embedded(self) -> LeftTurnTask:
        """The same scene on the embedded simulator (what the oracle plans on, batched): the
        task itself here; a task on another simulator returns its embedded twin."""
        return self

    def crossing_zones(self) -> FloatArray:
        """The ego's conflict zone with each movement of other vehicles besides the north car,
        on its route [m] ``[R, 2]``: none in the paper's scene."""
        return np.empty((0, 2))

    def initial_without_ego(self, scenarios: Scenarios) -> TaskState:
        """The initial state of an episode in which the others drive as if the ego were not
        there: in the paper's scene any episode's (the north car never reacts to the ego)."""
        return self.initial(scenarios)

    def mark_occupied(self, state: TaskState, tick: int, occupied: BoolArray) -> None:
        """Set ``occupied[b, r, tick]`` where a vehicle on movement ``r`` of
        :meth:`crossing_zones` is inside its conflict zone with the ego's route: no movement
        here."""

    def states_without_ego(self, scenarios: Scenarios) -> Iterator[TaskState]:
        """The state on every tick ``0..H`` of an episode in which the others drive as if the
        ego were not there (it holds a zero action)."""
        state = self.initial_without_ego(scenarios)
        hold = np.zeros(state.batch_size)
        for tick in range(self.config.episode.horizon_ticks + 1):
            if tick:
                state, _ = self.step(state, hold, observe=False)
            yield state

    def without_ego(self, scenarios: Scenarios) -> WithoutEgo:
        """The others' world without the ego, tick by tick (:class:`WithoutEgo`)."""
        batch, ticks = len(scenarios.ego_speed), self.config.episode.horizon_ticks + 1
        zones = self.crossing_zones()
        occupied = np.zeros((batch, zones.shape[0], ticks), dtype=np.bool_)
        north, north_speed, start = np.empty((batch, ticks)), np.empty((batch, ticks)), None
        for tick, state in enumerate(self.states_without_ego(scenarios)):
            if start is None:
                start = np.stack([state.world.progress[:, 0], state.world.vehicles.speed[:, 0]], 1)
            north[:, tick] = state.world.progress[:, 1]
            north_speed[:, tick] = state.world.vehicles.speed[:, 1]
            self.mark_occupied(state, tick, occupied)
        assert start is not None
        return WithoutEgo(start, north, north_speed, occupied, zones)

    def conflict_timeline(self, scenarios: Scenarios) -> ConflictTimeline:
        """Every conflict of the ego on every tick of the others' world without the ego, as the
        paper logic sees it through :meth:`view` (:class:`ConflictTimeline`; in the paper's
        scene the one conflict with the north car): what the logic-aware limit plans
        against."""
        batch, ticks = len(scenarios.ego_speed), self.config.episode.horizon_ticks + 1
        approach = self.config.episode.approach_distance_m
        start = np.empty((batch, 2))
        arrays: list[NDArray[Any]] = []
        for tick, state in enumerate(self.states_without_ego(scenarios)):
            view = self.view(state, truth=True)
            if not tick:
                start[:, 0] = state.world.progress[:, 0]
                start[:, 1] = state.world.vehicles.speed[:, 0]
                shape = (batch, ticks, view.present.shape[1])
                arrays = [np.empty(shape, dtype=np.bool_) for _ in range(3)]
                arrays += [np.empty(shape) for _ in range(5)]
            present, inside, window, entry, exit_, point, distance, speed = arrays
            s, zone = view.other_progress, view.other_zone
            present[:, tick] = view.present
            distance[:, tick] = view.other_point - s
            inside[:, tick] = (s >= zone[..., 0]) & (s <= zone[..., 1])
            window[:, tick] = approaching(s, view.other_point, zone[..., 1], approach)
            entry[:, tick] = view.ego_zone[..., 0]
            exit_[:, tick] = view.ego_zone[..., 1]
            point[:, tick] = view.ego_point
            speed[:, tick] = view.other_speed
        present, inside, window, entry, exit_, point, distance, speed = arrays
        return ConflictTimeline(start, present, entry, exit_, point, distance, inside, window,
                                speed)  # fmt: skip

    def conflicts(self, state: TaskState) -> ConflictArrays:
        """The ego's conflict with every other vehicle, for measures taken at them (the
        truth, whatever the ego perceives)."""
        v = self.view(state, truth=True)
        return ConflictArrays(
            ego_progress=v.ego_progress.copy(), ego_speed=v.ego_speed.copy(),
            present=v.present, ego_zone=v.ego_zone, other_progress=v.other_progress.copy(),
            other_speed=v.other_speed.copy(), other_zone=v.other_zone,
        )  # fmt: skip

    def hold(
        self,
        state: TaskState,
        action: FloatArray,
        on_tick: Callable[[StepRecord, BoolArray], None] | None = None,
    ) -> tuple[TaskState, StepRecord]:
        """One decision of the learned controller: ``episode.decision_interval`` ticks with
        ``action`` held, stopping early once every episode has ended. The record merges the
        ticks (see :func:`merge_tick`): an episode's reward and reward terms are summed over
        its ticks up to the one it ended on; collision, safety activation and clipping hold if
        they held on any of them; the rest is the last tick's (the ending one for an episode
        that ended). ``on_tick(record, live)`` sees every tick with the episodes still live."""
        ticks = self.config.episode.decision_interval
        live = np.ones(state.batch_size, dtype=np.bool_)
        state, record = self.step(state, action, observe=True if ticks == 1 else live)
        if on_tick is not None:
            on_tick(record, live)
        if ticks == 1:
            return state, record
        merged = replace(record, terms=dict(record.terms))
        live = live & ~(record.terminated | record.truncated)
        for k in range(ticks - 1):
            if not live.any():
                break
            # The observation only where the decision ends: the last tick, or an episode's end.
            state, record = self.step(state, action, observe=True if k == ticks - 2 else live)
            if on_tick is not None:
                on_tick(record, live)
            merge_tick(merged, record, live)
            live = live & ~(record.terminated | record.truncated)
        return state, merged

    # -- hooks of a task with more traffic (LeftTurnTrafficTask overrides them) ----------------

    def others_at_start(self, scenarios: Scenarios) -> Any:
        """The other traffic at an episode's start (what :meth:`sighted` looks at): none."""
        return None

    def advance_others(
        self, state: TaskState, new_world: WorldState, separation: FloatArray
    ) -> tuple[Any, FloatArray]:
        """Advance any other traffic over the tick; returns its new state and the ego's
        separation from the nearest vehicle of all [m]. Here there is none."""
        return None, separation

    def make_state(self, base: TaskState, others: Any) -> TaskState:
        """The next state from its plant part and the other traffic's."""
        return base

    def extend_observation(
        self, state: TaskState, observation: NDArray[np.float32]
    ) -> NDArray[np.float32]:
        """The observation from the plant's six values: here exactly those."""
        return observation

    def switch(self, state: TaskState, action: FloatArray) -> Switched:
        """Steps 1–3 of a tick: every controller side by side, who proposes the ego's pedals,
        and the switching logic's decision — everything that decides what reaches the plant,
        without advancing it (what :meth:`step` and the deployment runtime,
        :mod:`safeswitch.runtime`, both run).

        Args:
            state: Current state (not modified).
            action: Learned actions in [-1, 1], shape ``[B]`` or ``[B, 1]``.
        """
        world = state.world
        batch = state.batch_size

        # 1. Every controller side by side, who proposes the ego's pedals, and what the
        # switching logic sees (one compiled loop, see _controllers).
        v = world.vehicles
        pedals = self.learned_pedals(
            np.asarray(action, dtype=np.float64).reshape(batch), v.speed[:, 0]
        )
        learned_throttle = pedals.throttle
        th, br, no, la = state.pid_throttle, state.pid_brake, state.pid_north, state.pid_lane
        seen, seen_progress = state.perception, world.progress
        if seen is not None:  # the north car where the ego sees it
            seen_progress = world.progress.copy()
            seen_progress[:, 1] = seen.progress[:, 0]
        out = ControllerOutputs.empty(batch)
        _controllers_entry(
            self._controller_constants,
            tuple(ControllerInputs(
                learned_throttle, v.x, v.y, v.cos_yaw, v.sin_yaw, v.speed, world.progress,
                seen_progress, state.accel_lon, state.scenarios.north_speed, v.throttle, v.brake,
                (th.integral, th.prev_error, th.derivative, br.integral, br.prev_error,
                 br.derivative, no.integral, no.prev_error, no.derivative),
                (la.integral, la.prev_error, la.derivative),
            )),
            tuple(out),
        )  # fmt: skip
        proposed = out.proposed
        if pedals.brake is not None:  # the learned brake, where the learned controller proposes
            proposed[out.in_charge, 1] = pedals.brake[out.in_charge]
        cut_over_range = None
        if self._limiter is not None:
            # The learned controller's speed limiter cuts its finite throttle (NaN/inf is left
            # for the logic to refuse); one above 1 that it cut still counts as clipped.
            raw = proposed[:, 0]  # a view: the cut is written into the proposal in place
            cut = self.limit_speed(raw, v.speed[:, 0], world.progress[:, 0])
            limited = out.in_charge & np.isfinite(raw) & (cut < raw)
            cut_over_range = limited & (raw > 1.0)
            raw[limited] = cut[limited]
        # 2. The switching logic decides through the framework's one supervision step: the
        # proposal (learned while in charge, else PID_th), PID_b's brake as the safety action,
        # and the pedals held where they are in place of an invalid learned action (braking
        # instead, wherever the car is, stopped it in the north car's path: 266 collisions in
        # 2,500 random episodes with 30 % NaN ticks under the paper logic; holding, 1 — as many
        # as without the NaN ticks).
        view = self.view(state, out.both)
        sup = supervise(self.switching, view, proposed, out.safe, 0.0, 1.0, out.fallback)
        clipped = sup.clipped
        for over in (cut_over_range, pedals.over_range):
            if over is not None:
                clipped = clipped | over
        learned_brake = np.zeros(batch) if pedals.brake is None else pedals.brake
        return Switched(learned_throttle, out, sup, clipped, learned_brake)

    def step(
        self, state: TaskState, action: FloatArray, observe: bool | BoolArray = True
    ) -> tuple[TaskState, StepRecord]:
        """Advance every episode by one tick.

        Args:
            state: Current state (not modified).
            action: Learned actions in [-1, 1], shape ``[B]`` or ``[B, 1]``; out-of-range values
                are clipped, NaN/inf ones are never executed.
            observe: Whether the record carries the observation after the tick: ``True``;
                ``False``: not (``record.observation`` is ``None``: nobody reads it before the
                next tick, e.g. while the learned action is held); a boolean array ``[B]``
                (the episodes still live): only if one of them ended on this tick, whose last
                observation it is. In traffic the observation is most of a tick's cost.

        Returns:
            The next state and the record of the tick. Episodes that ended are not reset here.
        """
        world = state.world
        batch = state.batch_size
        switched = self.switch(state, action)
        out, sup = switched.controllers, switched.supervision
        north_throttle, north_brake = out.north_throttle, out.north_brake
        pid_throttle, pid_brake = PIDState(*out.pid_throttle), PIDState(*out.pid_brake)
        pid_north, pid_lane = PIDState(*out.pid_north), PIDState(*out.pid_lane)
        throttle, brake = sup.executed[:, 0], sup.executed[:, 1]

        # 4. The plant (and, in traffic, the other vehicles).
        new_world, outputs, separation = self.world.step(
            world, columns(throttle, north_throttle), columns(brake, north_brake), out.steer
        )
        others, separation = self.advance_others(state, new_world, separation)
        nv = new_world.vehicles
        speed = nv.speed
        book = Bookkeeping.empty(batch)
        _after_plant_entry(
            self._bookkeeping_constants,
            tuple(AfterPlant(
                sup.safety_active, sup.use_safety, sup.valid, out.in_charge, sup.reason,
                separation,
                nv.x, nv.y, speed, new_world.progress, new_world.lateral, outputs.accel_lon,
                outputs.accel_lat, state.tick, state.outcome,
            )),
            tuple(book),
        )  # fmt: skip
        terms_out, reward, tick = book.terms, book.reward, book.tick
        outcome, controller, reason, observation = (
            book.outcome,
            book.controller,
            book.reason,
            book.observation,
        )
        terms = dict(zip(REWARD_TERMS, terms_out, strict=True))
        collision, terminated, truncated = book.collision, book.terminated, book.truncated
        ego_cleared, lost_control = book.ego_cleared, book.lost_control
        ended = self._ended_as_terminal(sup.safety_active, reason, truncated, tick)
        if ended is not None:
            terminated, truncated = terminated | ended, truncated & ~ended
        perception = None
        if self.perception is not None:
            assert state.perception is not None
            perception = self.perception.sense(
                state.perception, tick, self.sighted(new_world, others, state)
            )

        new_state = self.make_state(
            TaskState(
                new_world,
                state.scenarios,
                pid_throttle,
                pid_brake,
                pid_lane,
                pid_north,
                outputs.accel_lon[:, 0],
                tick,
                outcome,
                perception,
            ),
            others,
        )
        if not isinstance(observe, bool):
            observe = bool(((terminated | truncated) & observe).any())
        record = StepRecord(
            observation=(
                self.complete_observation(new_state, self.seen_north(new_state, observation))
                if observe
                else None
            ),
            reward=reward,
            terms=terms,
            terminated=terminated,
            truncated=truncated,
            collision=collision,
            lost_control=lost_control,
            safety_active=sup.safety_active,
            reason=reason,
            controller=controller,
            both_at_intersection=out.both,
            learned_throttle=switched.learned_throttle,
            learned_brake=switched.learned_brake,
            action_clipped=switched.clipped,
            safety_brake=out.safety_brake,
            throttle=throttle,
            brake=brake,
            ego_speed=speed[:, 0],
            north_speed=speed[:, 1],
            accel_lon=outputs.accel_lon[:, 0],
            accel_lat=outputs.accel_lat[:, 0],
            grip_demand=outputs.grip_demand[:, 0],
            lateral=new_world.lateral[:, 0],
            separation=separation,
            outcome=outcome,
            ego_cleared=ego_cleared,
        )
        return new_state, record


#: How :meth:`LeftTurnTask.hold` merges the records of the ticks of one decision: summed over
#: the episode's ticks, true if on any of them; every other field is the last tick's.
_SUMMED = ("reward",)
_ANY = ("collision", "lost_control", "safety_active", "action_clipped")


def merge_tick(merged: StepRecord, record: StepRecord, live: BoolArray) -> None:
    """Fold one more tick's ``record`` into ``merged`` for the episodes that were ``live``
    during it (in place)."""
    merged.reward = merged.reward + np.where(live, record.reward, 0.0)
    merged.terms = {
        name: merged.terms[name] + np.where(live, record.terms[name], 0.0) for name in merged.terms
    }
    for name in _ANY:
        setattr(merged, name, getattr(merged, name) | (getattr(record, name) & live))
    for f in fields(StepRecord):
        if f.name in (*_SUMMED, *_ANY, "terms"):
            continue
        new, old = getattr(record, f.name), getattr(merged, f.name)
        if new is None:  # an observation not taken: the merged one stands
            continue
        if old is None:  # none taken before: every episode was live until now
            setattr(merged, f.name, new)
            continue
        mask = live[:, None] if new.ndim == 2 else live
        setattr(merged, f.name, np.where(mask, new, old))


def learned_actions(action: Any, batch: int) -> FloatArray:
    """The learned actions of a step as ``[batch]`` float64 (NaN/inf and out-of-range values
    pass: the supervision step handles them).

    Raises:
        ValueError: ``None``, or not ``batch`` numbers (the message names the value).
    """
    if action is None:
        raise ValueError("the action is None; pass an array of shape (1,) per environment")
    try:
        values = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"the action {action!r} is not numeric") from exc
    if values.size != batch:
        raise ValueError(
            f"{values.size} action value(s) of shape {values.shape} for {batch} environment(s); "
            "expected one throttle action in [-1, 1] each"
        )
    return values.reshape(batch)


class ControllerMemory(NamedTuple):
    """The controllers' memory: ``PID_th``, ``PID_b`` ``[B]``, ``PID_lka`` of both cars
    ``[B, 2]`` and the north car's speed PID ``[B]``."""

    throttle: PIDState
    brake: PIDState
    lane: PIDState
    north: PIDState


class LearnedPedals(NamedTuple):
    """The learned controller's pedals for a step's actions (:meth:`LeftTurnTask.learned_pedals`).

    Attributes:
        throttle: ``[B]`` (NaN/inf where the action was).
        brake: ``[B]``, or ``None`` where the action has no brake (the pedal stays released).
        over_range: Where an action out of [-1, 1] was clipped ``[B]``, or ``None`` where the
            action is the throttle itself (the logic sees and counts it).
    """

    throttle: FloatArray
    brake: FloatArray | None
    over_range: NDArray[np.bool_] | None


class Switched(NamedTuple):
    """What decides a tick's ego pedals (:meth:`LeftTurnTask.switch`).

    Attributes:
        learned_throttle: The learned controller's throttle ``[B]``
            (:meth:`LeftTurnTask.learned_pedals`).
        controllers: Every controller's output and new memory.
        supervision: The switching logic's decision and the executed pedals.
        clipped: The learned throttle was out of range and was clipped (by the supervision or
            the speed limiter) ``[B]``.
        learned_brake: The learned controller's brake ``[B]`` (zeros but with
            ``controllers.learned_brake``).
    """

    learned_throttle: FloatArray
    controllers: ControllerOutputs
    supervision: Supervision
    clipped: BoolArray
    learned_brake: FloatArray


class ControllerGains(NamedTuple):
    """The PID gains the compiled controllers read."""

    throttle: PIDKernel
    brake: PIDKernel
    lane: PIDKernel
    north_speed: PIDKernel


class EpisodeLimits(NamedTuple):
    """When an episode ends and when a car has left its zone, as the compiled tick reads them.

    Attributes:
        horizon_ticks: Episode length [ticks].
        ego_route_end: Progress at which the ego's route ends [m].
        ego_zone_exit: Exit of the ego's conflict zone [m].
        north_zone_exit: Exit of the north car's conflict zone [m].
        lost_control_m: The ego has lost control this far off its route [m] (half a lane
            width: its centre at the lane's edge).
    """

    horizon_ticks: int
    ego_route_end: float
    ego_zone_exit: float
    north_zone_exit: float
    lost_control_m: float


#: Values of ``EpisodeConfig.learned_scope``, in the order of the compiled tick's codes.
LEARNED_SCOPES: tuple[str, ...] = ("window", "episode", "never")


class ControllerConstants(NamedTuple):
    """What the compiled controllers read that stays fixed for a task.

    Attributes:
        gains: PID_th, PID_b, PID_lka and the autopilot's speed PID.
        dt: Tick [s].
        speed_limit: PID_th's target speed [m/s].
        emergency_decel: PID_b's deceleration target [m/s²].
        lookahead: PID_lka's look-ahead distance [m].
        plant: The vehicle model's constants (the autopilot's feed-forward).
        tables: The routes' waypoint tables (see :class:`~safeswitch.sim.road.RouteSet`).
        spacing: Waypoint spacing [m].
        k_max: Last waypoint segment index.
        base: Each car's route row in ``tables`` ``[2]``.
        north: The geometry of the conflict with the north car.
        scope: Who drives (:data:`LEARNED_SCOPES` code).
    """

    gains: ControllerGains
    dt: float
    speed_limit: float
    emergency_decel: float
    lookahead: float
    plant: VehicleConstants
    tables: FloatArray
    spacing: float
    k_max: int
    base: IntArray
    north: NorthConflict
    scope: int


class ControllerInputs(NamedTuple):
    """The state the compiled controllers read: ``[B]`` per episode, ``[B, 2]`` per car (ego,
    north car).

    Attributes:
        learned_throttle: The learned controller's throttle ``[B]`` (NaN/inf pass through).
        x: Position ``[B, 2]`` [m].
        y: Position ``[B, 2]`` [m].
        cos_yaw: Heading's cosine ``[B, 2]``.
        sin_yaw: Heading's sine ``[B, 2]``.
        speed: ``[B, 2]`` [m/s].
        progress: Arc length along each route ``[B, 2]`` [m].
        seen_progress: ``progress`` as the ego sees it ``[B, 2]`` [m] (Algorithm 1's window
            reads it; ``progress`` itself with perfect perception).
        accel_lon: The ego's last longitudinal acceleration ``[B]`` [m/s²].
        north_target: The north car's target speed ``[B]`` [m/s].
        throttle: The actual throttle ``[B, 2]`` (held in place of an invalid learned action).
        brake: The actual brake ``[B, 2]``.
        pids: (integral, previous error, derivative) of PID_th, PID_b and the autopilot's PID,
            nine ``[B]`` arrays.
        lane: (integral, previous error, derivative) of PID_lka, three ``[B, 2]`` arrays.
    """

    learned_throttle: FloatArray
    x: FloatArray
    y: FloatArray
    cos_yaw: FloatArray
    sin_yaw: FloatArray
    speed: FloatArray
    progress: FloatArray
    seen_progress: FloatArray
    accel_lon: FloatArray
    north_target: FloatArray
    throttle: FloatArray
    brake: FloatArray
    pids: tuple[FloatArray, ...]
    lane: tuple[FloatArray, ...]


class ControllerOutputs(NamedTuple):
    """What the compiled controllers write.

    Attributes:
        safety_brake: PID_b's brake, the safety action ``[B]``.
        north_throttle: The autopilot's throttle ``[B]``.
        north_brake: The autopilot's brake ``[B]``.
        pid_throttle: PID_th's new (integral, error, derivative) ``[3, B]``.
        pid_brake: PID_b's ``[3, B]``.
        pid_north: The autopilot's speed PID's ``[3, B]``.
        steer: PID_lka's steering of both cars ``[B, 2]``.
        pid_lane: PID_lka's new state ``[3, B, 2]``.
        proposed: The proposed ego pedals (throttle, brake) ``[B, 2]``: the learned throttle
            while the learned controller is in charge, else PID_th's.
        safe: The safety action's pedals ``[B, 2]``.
        fallback: The pedals held in place of an invalid learned action ``[B, 2]``.
        both: Both cars at the intersection (Algorithm 1's While condition) ``[B]``.
        in_charge: The learned controller is in charge ``[B]``.
    """

    safety_brake: FloatArray
    north_throttle: FloatArray
    north_brake: FloatArray
    pid_throttle: FloatArray
    pid_brake: FloatArray
    pid_north: FloatArray
    steer: FloatArray
    pid_lane: FloatArray
    proposed: FloatArray
    safe: FloatArray
    fallback: FloatArray
    both: BoolArray
    in_charge: BoolArray

    @classmethod
    def empty(cls, batch: int) -> ControllerOutputs:
        """Uninitialised outputs for ``batch`` episodes (an array each: cheaper than views of
        a few blocks at the batch of a single ``Env``)."""
        e, pair, three, flag = np.empty, (batch, 2), (3, batch), np.bool_
        return cls(
            e(batch), e(batch), e(batch), e(three), e(three), e(three), e(pair),
            e((3, batch, 2)), e(pair), e(pair), e(pair), e(batch, flag), e(batch, flag),
        )  # fmt: skip


@jit
def named_controller_constants(c: tuple[Any, ...]) -> ControllerConstants:
    """The inverse of ``plain`` for :class:`ControllerConstants` (in compiled code)."""
    g = c[0]
    gains = ControllerGains(PIDKernel(*g[0]), PIDKernel(*g[1]), PIDKernel(*g[2]),
                            PIDKernel(*g[3]))  # fmt: skip
    return ControllerConstants(gains, c[1], c[2], c[3], c[4], VehicleConstants(*c[5]), c[6],
                               c[7], c[8], c[9], NorthConflict(*c[10]), c[11])  # fmt: skip


@jit
def _controllers_entry(c: tuple[Any, ...], i: tuple[Any, ...], out: tuple[Any, ...]) -> None:
    """:func:`_controllers` called with plain tuples (see :func:`~safeswitch.core.arrays.plain`),
    named again here."""
    _controllers(named_controller_constants(c), ControllerInputs(*i), ControllerOutputs(*out))


@jit
def _controllers(c: ControllerConstants, i: ControllerInputs, out: ControllerOutputs) -> None:
    """Step 1 of the tick for every episode: ``PID_th`` on ``v_lim − v``, ``PID_b`` on
    ``a_max + a_lon``, ``PID_lka`` of both cars on the look-ahead offset of their route, the
    north car's autopilot (feed-forward throttle for its target speed plus a speed PID); then
    who proposes the ego's pedals (``scope`` codes :data:`LEARNED_SCOPES`: the learned throttle
    while in charge, else ``PID_th``'s) and the fallback for an invalid learned action (the
    actual pedals held)."""
    # The tuples' arrays taken out once (see jit: read through a tuple inside the loop, each
    # is fetched and reference-counted on every access).
    pid, lane, g, north = i.pids, i.lane, c.gains, c.north
    learned, x, y, cos_yaw, sin_yaw = i.learned_throttle, i.x, i.y, i.cos_yaw, i.sin_yaw
    speed, progress, accel_lon, target = i.speed, i.progress, i.accel_lon, i.north_target
    seen_progress = i.seen_progress
    held_throttle, held_brake = i.throttle, i.brake
    pid_th, pid_b, pid_n, pid_lka = out.pid_throttle, out.pid_brake, out.pid_north, out.pid_lane
    safety_brake, north_throttle, north_brake = (
        out.safety_brake,
        out.north_throttle,
        out.north_brake,
    )
    steer, proposed, safe, fallback = out.steer, out.proposed, out.safe, out.fallback
    both, charge = out.both, out.in_charge
    for b in range(x.shape[0]):
        error = c.speed_limit - speed[b, 0]
        rule, integral, derivative = pid_tick(g.throttle, c.dt, error, pid[0][b], pid[1][b],
                                              pid[2][b])  # fmt: skip
        pid_th[0, b], pid_th[1, b], pid_th[2, b] = integral, error, derivative
        error = c.emergency_decel + accel_lon[b]
        brake, integral, derivative = pid_tick(g.brake, c.dt, error, pid[3][b], pid[4][b],
                                               pid[5][b])  # fmt: skip
        safety_brake[b] = brake
        pid_b[0, b], pid_b[1, b], pid_b[2, b] = integral, error, derivative
        north_throttle[b], north_brake[b], pid_n[0, b], pid_n[1, b], pid_n[2, b] = autopilot_tick(
            g.north_speed, c.dt, c.plant, speed[b, 1], target[b], pid[6][b], pid[7][b], pid[8][b]
        )
        for j in range(2):
            error = preview(
                c.tables, c.spacing, c.k_max, c.base[j], progress[b, j], x[b, j], y[b, j],
                cos_yaw[b, j], sin_yaw[b, j], c.lookahead,
            )  # fmt: skip
            steer[b, j], integral, derivative = pid_tick(
                g.lane, c.dt, error, lane[0][b, j], lane[1][b, j], lane[2][b, j]
            )
            pid_lka[0, b, j], pid_lka[1, b, j], pid_lka[2, b, j] = integral, error, derivative
        at = at_intersection(progress[b, 0], seen_progress[b, 1], north)
        in_charge = at if c.scope == 0 else c.scope == 1
        both[b], charge[b] = at, in_charge
        proposed[b, 0], proposed[b, 1] = (learned[b] if in_charge else rule), 0.0
        safe[b, 0], safe[b, 1] = 0.0, brake
        fallback[b, 0], fallback[b, 1] = held_throttle[b, 0], held_brake[b, 0]


class BookkeepingConstants(NamedTuple):
    """What the compiled bookkeeping reads that stays fixed for a task.

    Attributes:
        tables: The reward terms' breakpoint tables.
        adas_penalty: ``R_ADAS`` per tick of safety action (0 with it off).
        collision_penalty: Added on a failure's tick.
        limits: When an episode ends.
        rule_code: The reason code reported where the rule's proposal ran.
    """

    tables: tuple[FloatArray, ...]
    adas_penalty: float
    collision_penalty: float
    limits: EpisodeLimits
    rule_code: int


class AfterPlant(NamedTuple):
    """The supervision's decision and the new plant state the bookkeeping reads.

    Attributes:
        safety_active: The safety side acted ``[B]``.
        use_safety: The logic chose its safety action ``[B]``.
        valid: The learned action was finite ``[B]``.
        in_charge: The learned controller was in charge ``[B]``.
        reason: The supervision's reason code ``[B]``.
        separation: Distance between the footprints ``[B]`` [m] (≤ 0: a collision).
        x: ``[B, 2]`` [m].
        y: ``[B, 2]`` [m].
        speed: ``[B, 2]`` [m/s].
        progress: ``[B, 2]`` [m].
        lateral: Offset from the route ``[B, 2]`` [m].
        accel_lon: ``[B, 2]`` [m/s²].
        accel_lat: ``[B, 2]`` [m/s²].
        tick: The tick before this one ``[B]``.
        outcome: Cut/yield so far ``[B]`` (0 undecided, 1 cut, 2 yield).
    """

    safety_active: BoolArray
    use_safety: BoolArray
    valid: BoolArray
    in_charge: BoolArray
    reason: NDArray[np.int8]
    separation: FloatArray
    x: FloatArray
    y: FloatArray
    speed: FloatArray
    progress: FloatArray
    lateral: FloatArray
    accel_lon: FloatArray
    accel_lat: FloatArray
    tick: NDArray[np.int64]
    outcome: NDArray[np.int8]


class Bookkeeping(NamedTuple):
    """What the compiled bookkeeping writes, ``[B]`` each.

    Attributes:
        terms: The five reward terms, in :data:`REWARD_TERMS` order.
        reward: Their sum (and the failure penalty).
        tick: The new tick.
        collision: The footprints touch.
        terminated: A failure (collision or lost control) ended the episode.
        truncated: The horizon or the end of the route.
        ego_cleared: The ego has left its conflict zone.
        lost_control: The ego left its lane.
        outcome: Cut/yield, decided as the ego clears.
        controller: Who proposed the executed pedals (:data:`CONTROLLERS`).
        reason: The tick's reason code.
        observation: The paper's six values ``[B, 6]``.
    """

    terms: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]
    reward: FloatArray
    tick: NDArray[np.int64]
    collision: BoolArray
    terminated: BoolArray
    truncated: BoolArray
    ego_cleared: BoolArray
    lost_control: BoolArray
    outcome: NDArray[np.int8]
    controller: NDArray[np.int8]
    reason: NDArray[np.int8]
    observation: NDArray[np.float32]

    @classmethod
    def empty(cls, batch: int) -> Bookkeeping:
        """Uninitialised outputs for ``batch`` episodes."""
        e, flag, code = np.empty, np.bool_, np.int8
        return cls(
            (e(batch), e(batch), e(batch), e(batch), e(batch)), e(batch), e(batch, np.int64),
            e(batch, flag), e(batch, flag), e(batch, flag), e(batch, flag), e(batch, flag),
            e(batch, code), e(batch, code), e(batch, code), e((batch, 6), np.float32),
        )  # fmt: skip


@jit
def named_bookkeeping_constants(c: tuple[Any, ...]) -> BookkeepingConstants:
    """The inverse of ``plain`` for :class:`BookkeepingConstants` (in compiled code)."""
    return BookkeepingConstants(c[0], c[1], c[2], EpisodeLimits(*c[3]), c[4])


@jit
def _after_plant_entry(c: tuple[Any, ...], i: tuple[Any, ...], out: tuple[Any, ...]) -> None:
    """:func:`_after_plant` called with plain tuples (see
    :func:`~safeswitch.core.arrays.plain`), named again here."""
    _after_plant(named_bookkeeping_constants(c), AfterPlant(*i), Bookkeeping(*out))


@jit
def _after_plant(c: BookkeepingConstants, i: AfterPlant, out: Bookkeeping) -> None:
    """Step 4's bookkeeping for every episode, from the new plant state: the five reward terms
    (Eq. 5) and their sum, collision, termination, truncation (horizon or end of route), the
    ego leaving its zone, who crossed first, who proposed the executed pedals (the safety side
    where the logic chose its safety action, the learned controller where it was in charge with
    a valid action, else the rule, whose reason code then replaces the supervision's), and the
    observation. A failure — a collision or a loss of control — ends the episode and gets
    ``collision_penalty``."""
    # The tuples' arrays taken out once (see jit).
    limits, (t0, t1, t2, t3, t4) = c.limits, out.terms
    safety_active, use_safety, valid, in_charge = (
        i.safety_active,
        i.use_safety,
        i.valid,
        i.in_charge,
    )
    separation, x, y, speed, progress = i.separation, i.x, i.y, i.speed, i.progress
    given = i.reason
    lateral, accel_lon, accel_lat, tick, outcome = (
        i.lateral,
        i.accel_lon,
        i.accel_lat,
        i.tick,
        i.outcome,
    )
    reward, new_tick, collided, terminated = out.reward, out.tick, out.collision, out.terminated
    truncated, ego_cleared, lost_control = out.truncated, out.ego_cleared, out.lost_control
    new_outcome, controller, reason, observation = (
        out.outcome, out.controller, out.reason, out.observation
    )  # fmt: skip
    for b in range(x.shape[0]):
        adas, lka, v, lon, lat = tick_terms(
            c.tables, c.adas_penalty, safety_active[b], lateral[b, 0], speed[b, 0],
            accel_lon[b, 0], accel_lat[b, 0],
        )  # fmt: skip
        t0[b], t1[b], t2[b], t3[b], t4[b] = adas, lka, v, lon, lat
        collision = separation[b] <= 0.0
        lost = abs(lateral[b, 0]) > limits.lost_control_m
        failed = collision or lost
        total = adas + lka + v + lon + lat
        if c.collision_penalty != 0.0:
            total = total + (c.collision_penalty if failed else 0.0)
        reward[b] = total
        t = tick[b] + 1
        new_tick[b] = t
        collided[b] = collision
        terminated[b] = failed
        truncated[b] = (not failed) and (
            t >= limits.horizon_ticks or progress[b, 0] >= limits.ego_route_end
        )
        cleared = progress[b, 0] > limits.ego_zone_exit
        ego_cleared[b] = cleared
        lost_control[b] = lost
        if outcome[b] != 0:
            new_outcome[b] = outcome[b]
        elif cleared:  # decided as the ego clears: before the north car left its zone, or after
            new_outcome[b] = 2 if progress[b, 1] > limits.north_zone_exit else 1
        else:
            new_outcome[b] = 0
        reason[b] = given[b]
        if use_safety[b]:
            controller[b] = 2
        elif in_charge[b] and valid[b]:
            controller[b] = 0
        else:
            controller[b] = 1
            if not in_charge[b]:
                reason[b] = c.rule_code
        for j in range(2):
            observation[b, 3 * j] = x[b, j]
            observation[b, 3 * j + 1] = y[b, j]
            observation[b, 3 * j + 2] = speed[b, j]
