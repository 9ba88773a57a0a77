"""The left-turn task as batched functions: initial state, one tick, observation.

The Gymnasium ``Env`` and the Stable-Baselines3 ``VecEnv`` are thin shells over
:class:`LeftTurnTask`; one code path serves a batch of 1 and a batch of 10,000.

One tick (paper Fig. 3 and Algorithm 1):

1. All controllers run side by side: ``PID_th`` (throttle to the speed limit), ``PID_b`` (the
   Safety controller: brake to track ``a_max``), ``PID_lka`` (steering, both cars), the north
   car's autopilot, and the learned action ``a ∈ [-1, 1]`` → throttle ``(a + 1) / 2``.
2. Who proposes the ego's pedals: the learned controller while both cars are at the
   intersection (or always, with ``learned_scope="episode"``), ``PID_th`` otherwise.
3. The switching logic, wrapped by :func:`safeswitch.core.switching.supervise`, executes the
   proposal or the safety action; a NaN/inf learned action is never executed.
4. The plant advances 20 ms; the five reward terms are computed from the new state.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import columns
from safeswitch.core.pid import PIDState, pid_step
from safeswitch.core.switching import NeverSwitch, SwitchingLogic, reason_names, supervise
from safeswitch.leftturn.certified import CertifiedSwitching
from safeswitch.leftturn.config import LeftTurnConfig, resolve_config
from safeswitch.leftturn.rewards import REWARD_TERMS, reward_terms
from safeswitch.leftturn.scenarios import (
    Scenarios,
    counter_uniforms,
    named_scenarios,
    sample_scenarios,
)
from safeswitch.leftturn.switching import ConflictState, PaperSwitching
from safeswitch.sim.conflict import ConflictGeometry, conflict_geometry
from safeswitch.sim.geometry import FloatArray, Route
from safeswitch.sim.road import Intersection
from safeswitch.sim.traffic import AutopilotParams, autopilot_pedals
from safeswitch.sim.vehicle import steady_state_throttle
from safeswitch.sim.world import World, WorldState, preview_offsets

BoolArray = NDArray[np.bool_]

#: Who proposed the executed action: codes of :attr:`StepRecord.controller`.
CONTROLLERS: tuple[str, ...] = ("learned", "rule", "safety")
#: Codes of :attr:`TaskState.outcome`.
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

    @property
    def batch_size(self) -> int:
        return int(self.tick.shape[0])

    def replace_at(self, index: NDArray[np.intp], other: TaskState) -> None:
        """Overwrite episodes ``index`` with the ``len(index)`` episodes of ``other``, in place
        (auto-reset of the episodes that ended)."""
        _replace_arrays(self, index, other)


def _replace_arrays(target: object, index: NDArray[np.intp], source: object) -> None:
    """``target.f[index] = source.f`` for every array field, recursing into dataclasses."""
    for f in fields(target):  # type: ignore[arg-type]
        mine, theirs = getattr(target, f.name), getattr(source, f.name)
        if isinstance(mine, np.ndarray):
            mine[index] = theirs
        else:
            _replace_arrays(mine, index, theirs)


@dataclass
class StepRecord:
    """Everything that happened on one tick, each field ``[B]`` (``observation``: ``[B, 6]``).

    Attributes:
        observation: The state after the tick (x_e, y_e, v_e, x_n, y_n, v_n), float32.
        reward: Sum of the reward terms (plus the collision penalty, if configured).
        terms: The five reward terms of Eq. 5, keyed by :data:`REWARD_TERMS`.
        terminated: The episode ended in a collision.
        truncated: The episode hit its time horizon or the end of the ego's route.
        collision: The cars' footprints touch or overlap.
        safety_active: The safety action was executed (the paper's ``s*``).
        reason: Reason code of the switching decision, into :attr:`LeftTurnTask.reasons`.
        controller: Who proposed the executed action, a code of :data:`CONTROLLERS`.
        both_at_intersection: Algorithm 1's While condition held at the start of the tick.
        learned_throttle: Throttle the learned action asked for (NaN if it was NaN).
        safety_brake: Brake the Safety controller ``PID_b`` computed.
        throttle: Executed throttle command.
        brake: Executed brake command.
        ego_speed: Ego speed after the tick [m/s].
        north_speed: North car speed after the tick [m/s].
        accel_lon: Ego longitudinal acceleration over the tick [m/s²].
        accel_lat: Ego lateral acceleration [m/s²].
        lateral: Ego lateral deviation from its route [m].
        separation: Gap between the two footprints [m] (``<= 0``: collision).
        outcome: Who crossed first so far, a code of :data:`OUTCOMES`.
        ego_cleared: The ego has left its conflict zone.
    """

    observation: NDArray[np.float32]
    reward: FloatArray
    terms: dict[str, FloatArray]
    terminated: BoolArray
    truncated: BoolArray
    collision: BoolArray
    safety_active: BoolArray
    reason: NDArray[np.int8]
    controller: NDArray[np.int8]
    both_at_intersection: BoolArray
    learned_throttle: FloatArray
    safety_brake: FloatArray
    throttle: FloatArray
    brake: FloatArray
    ego_speed: FloatArray
    north_speed: FloatArray
    accel_lon: FloatArray
    accel_lat: FloatArray
    lateral: FloatArray
    separation: FloatArray
    outcome: NDArray[np.int8]
    ego_cleared: BoolArray


def make_switching(
    config: LeftTurnConfig, ego_route: Route, north_route: Route
) -> SwitchingLogic[ConflictState]:
    """The switching logic named by ``config.switching``."""
    if config.switching == "paper":
        return PaperSwitching(config.paper, config.controllers.emergency_decel)
    if config.switching == "certified":
        footprint = (config.vehicle.length, config.vehicle.width)
        zones = conflict_geometry(
            ego_route, north_route, footprint, footprint, margin=config.certified.zone_margin_m
        )
        return CertifiedSwitching(
            config.certified, config.vehicle, config.episode.dt, zones.zone_a, zones.zone_b
        )
    return NeverSwitch()


class LeftTurnTask:
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
        self.switching = make_switching(config, *self.world.routes)
        self.reasons = reason_names(self.switching)
        self.autopilot = AutopilotParams(steer_gains=config.controllers.lane_pid)
        self._ego_route_end = self.world.routes[0].length - 1.0

    # -- pure functions -------------------------------------------------------------------

    def draw_scenarios(
        self, seed: int, env_ids: NDArray[np.int64], episodes: NDArray[np.int64]
    ) -> Scenarios:
        """The scenarios of episodes ``episodes`` of environments ``env_ids`` under ``seed``:
        the configured named scenario, or draws from the random distribution."""
        if self.config.scenario is not None:
            return named_scenarios(self.config.scenario, len(env_ids))
        return sample_scenarios(self.config.scenarios, counter_uniforms(seed, env_ids, episodes, 4))

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
            raise ValueError(
                "a scenario starts a car before the start of its route; "
                "shorten ego_start_distance_m or arrival_offset_s"
            )
        speed = np.stack([scenarios.ego_speed, scenarios.north_speed], axis=1)
        world = self.world.place(progress, speed)
        # Bumpless start: PID_th's integral holds the throttle that cruises at the speed limit.
        gains = c.controllers.throttle_pid
        cruise = float(steady_state_throttle(c.vehicle, np.asarray(v_lim)))
        pid_throttle = PIDState.zeros((batch,), cruise / gains.ki if gains.ki > 0 else 0.0)
        return TaskState(
            world=world,
            scenarios=Scenarios(*(getattr(scenarios, f.name).copy() for f in fields(Scenarios))),
            pid_throttle=pid_throttle,
            pid_brake=PIDState.zeros((batch,), self.brake_feedforward()),
            pid_lane=PIDState.zeros((batch, 2)),
            pid_north=PIDState.zeros((batch,)),
            accel_lon=np.zeros(batch),
            tick=np.zeros(batch, dtype=np.int64),
            outcome=np.zeros(batch, dtype=np.int8),
        )

    def brake_feedforward(self) -> float:
        """Initial integral of ``PID_b``: the brake that decelerates at ``a_max`` on a level
        road, divided by ``ki`` (bumpless start)."""
        c = self.config
        brake = c.controllers.emergency_decel * c.vehicle.mass / c.vehicle.max_brake_force
        ki = c.controllers.brake_pid.ki
        return min(brake, 1.0) / ki if ki > 0 else 0.0

    def observe(self, state: TaskState) -> NDArray[np.float32]:
        """The paper's state ``s = (x_e, y_e, v_e, x_n, y_n, v_n)``, ``[B, 6]`` float32."""
        v = state.world.vehicles
        out = np.empty((state.batch_size, 6), dtype=np.float32)
        for j, (field, slot) in enumerate(_OBSERVED):
            out[:, j] = getattr(v, field)[:, slot]
        return out

    def conflict_state(self, state: TaskState) -> ConflictState:
        """Distances and speeds relative to the conflict point, for the switching logics."""
        geo, approach = self.conflict, self.config.episode.approach_distance_m
        s_e, s_n = state.world.progress[:, 0], state.world.progress[:, 1]
        ego_to_conflict = geo.s_point_a - s_e
        north_to_conflict = geo.s_point_b - s_n
        ego_at = (ego_to_conflict <= approach) & (s_e <= geo.zone_a[1])
        north_at = (north_to_conflict <= approach) & (s_n <= geo.zone_b[1])
        v = state.world.vehicles
        return ConflictState(
            ego_to_conflict=ego_to_conflict,
            ego_to_stop=geo.zone_a[0] - s_e,
            ego_speed=v.speed[:, 0],
            north_to_conflict=north_to_conflict,
            north_speed=v.speed[:, 1],
            both_at_intersection=ego_at & north_at,
            ego_progress=s_e,
            north_progress=s_n,
            ego_throttle=v.throttle[:, 0],
            ego_brake=v.brake[:, 0],
        )

    def step(self, state: TaskState, action: FloatArray) -> tuple[TaskState, StepRecord]:
        """Advance every episode by one tick.

        Args:
            state: Current state (not modified).
            action: Learned actions in [-1, 1], shape ``[B]`` or ``[B, 1]``; out-of-range values
                are clipped, NaN/inf ones are never executed.

        Returns:
            The next state and the record of the tick. Episodes that ended are not reset here.
        """
        c, dt = self.config, self.config.episode.dt
        ctrl = c.controllers
        world = state.world
        ego_speed = world.vehicles.speed[:, 0]
        batch = state.batch_size

        # 1. Every controller, side by side.
        rule_throttle, pid_throttle = pid_step(
            ctrl.throttle_pid, state.pid_throttle, ctrl.speed_limit - ego_speed, dt
        )
        safety_brake, pid_brake = pid_step(
            ctrl.brake_pid, state.pid_brake, ctrl.emergency_decel + state.accel_lon, dt
        )
        steer, pid_lane = pid_step(
            ctrl.lane_pid,
            state.pid_lane,
            preview_offsets(self.world, world, ctrl.lane_lookahead_m),
            dt,
        )
        north_throttle, north_brake, pid_north = autopilot_pedals(
            self.autopilot,
            c.vehicle,
            world.vehicles.speed[:, 1],
            state.scenarios.north_speed,
            state.pid_north,
            dt,
        )
        learned_throttle = 0.5 * (np.asarray(action, dtype=np.float64).reshape(batch) + 1.0)

        # 2. Who proposes the ego's pedals.
        conflict = self.conflict_state(state)
        if c.episode.learned_scope == "window":
            learned_in_charge = conflict.both_at_intersection
        else:
            learned_in_charge = np.full(batch, c.episode.learned_scope == "episode")
        zeros = np.zeros(batch)
        proposed_throttle = np.where(learned_in_charge, learned_throttle, rule_throttle)

        # 3. The switching logic decides.
        sup = supervise(
            self.switching,
            conflict,
            columns(proposed_throttle, zeros),
            columns(zeros, safety_brake),
            0.0,
            1.0,
        )
        throttle, brake = sup.executed[:, 0], sup.executed[:, 1]
        controller = np.where(sup.safety_active, 2, np.where(learned_in_charge, 0, 1))

        # 4. The plant.
        new_world, outputs, separation = self.world.step(
            world, columns(throttle, north_throttle), columns(brake, north_brake), steer
        )
        collision = separation <= 0.0
        speed = new_world.vehicles.speed
        terms = reward_terms(
            c.rewards,
            speed=speed[:, 0],
            lateral=new_world.lateral[:, 0],
            accel_lon=outputs.accel_lon[:, 0],
            accel_lat=outputs.accel_lat[:, 0],
            safety_active=sup.safety_active,
            adas_enabled=c.adas_penalty,
        )
        reward: FloatArray = np.sum([terms[name] for name in REWARD_TERMS], axis=0)
        if c.rewards.collision_penalty:
            reward = reward + np.where(collision, c.rewards.collision_penalty, 0.0)

        tick = state.tick + 1
        terminated = collision
        truncated = ~terminated & (
            (tick >= c.episode.horizon_ticks) | (new_world.progress[:, 0] >= self._ego_route_end)
        )
        geo = self.conflict
        ego_cleared = new_world.progress[:, 0] > geo.zone_a[1]
        north_cleared = new_world.progress[:, 1] > geo.zone_b[1]
        outcome = np.where(
            state.outcome != 0,
            state.outcome,
            np.where(ego_cleared, 1, np.where(north_cleared, 2, 0)),
        ).astype(np.int8)

        new_state = TaskState(
            new_world,
            state.scenarios,
            pid_throttle,
            pid_brake,
            pid_lane,
            pid_north,
            outputs.accel_lon[:, 0],
            tick,
            outcome,
        )
        record = StepRecord(
            observation=self.observe(new_state),
            reward=reward,
            terms=terms,
            terminated=terminated,
            truncated=truncated,
            collision=collision,
            safety_active=sup.safety_active,
            reason=sup.reason,
            controller=controller.astype(np.int8),
            both_at_intersection=conflict.both_at_intersection,
            learned_throttle=learned_throttle,
            safety_brake=safety_brake,
            throttle=throttle,
            brake=brake,
            ego_speed=speed[:, 0],
            north_speed=speed[:, 1],
            accel_lon=outputs.accel_lon[:, 0],
            accel_lat=outputs.accel_lat[:, 0],
            lateral=new_world.lateral[:, 0],
            separation=separation,
            outcome=outcome,
            ego_cleared=ego_cleared,
        )
        return new_state, record


def build_task(
    render_mode: str | None, config: LeftTurnConfig | dict[str, Any] | None, **overrides: Any
) -> LeftTurnTask:
    """The task behind an environment: ``render_mode`` checked, ``config`` resolved with the
    constructor's keyword arguments (see :func:`~safeswitch.leftturn.config.resolve_config`)."""
    if render_mode not in (None, "rgb_array"):
        raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
    return LeftTurnTask(resolve_config(config, **overrides))
