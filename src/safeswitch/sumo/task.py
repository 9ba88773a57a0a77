"""The left-turn task on SUMO: ``safeswitch/LeftTurnSumo-v0`` and its worker-process VecEnv,
in the paper's scene and in traffic from every leg.

:class:`LeftTurnSumoTask` is the paper's task (:class:`~safeswitch.leftturn.task.LeftTurnTask`)
with SUMO as the plant of the north car: every tick the ego's pose goes to SUMO, SUMO steps,
and the north car's pose and speed come back into the task state before the rewards, the
observation and the next decision of the switching logic — so the Table I controllers, the
logics and the learned policy act exactly as on the embedded simulator, on the same pedal-level
ego. Collisions are ours (footprints); SUMO's own (junctions included) are counted beside them
(:attr:`LeftTurnSumoTask.sumo_collisions`) for a cross-check.

The certified logic assumes the north car accelerates at most ``other_max_accel`` and drives at
most ``other_max_speed_kmh``; what SUMO's north car actually does is measured every tick and an
episode in which it broke either is counted (:attr:`LeftTurnSumoTask.assumption_breaks`), not
hidden.

One scene per process (libsumo); :func:`make_sumo_vec_env` runs ``n`` environments in worker
processes (Stable-Baselines3's ``SubprocVecEnv``, started with ``spawn``; a worker exits when
its pipe closes, so none outlives a crashed or interrupted parent).

With ``traffic`` (:class:`LeftTurnSumoTrafficTask`) SUMO drives every other vehicle of the
embedded traffic scene (the same vehicles at the start and the same arrivals), and the
certified assumptions are checked against every one of them. The oracle and the logic-aware
limit plan against the embedded scene's drivers.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from safeswitch.leftturn.config import LeftTurnConfig, TrafficConfig
from safeswitch.leftturn.env import LeftTurnEnv
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.task import ConflictTimeline, LeftTurnTask, TaskState, WithoutEgo
from safeswitch.leftturn.traffic import LeftTurnTrafficTask, TrafficTaskState
from safeswitch.sim.collision import separation as footprint_gap
from safeswitch.sim.geometry import FloatArray, locate
from safeswitch.sim.streams import TrafficState
from safeswitch.sim.world import WorldState
from safeswitch.sumo.network import network_file
from safeswitch.sumo.plant import Pose, SumoPlant


class _SumoScene:
    """What both SUMO tasks share: the plant, the north car SUMO drives, the ego's pose pushed
    to SUMO every tick, SUMO's collisions counted and the certified assumptions checked."""

    config: LeftTurnConfig
    world: Any

    def _open_plant(self, seed: int) -> None:
        c = self.config
        self.seed = seed
        self.plant = SumoPlant(
            network_file(c.geometry), c.episode.dt, c.vehicle.length, c.vehicle.width
        )
        #: Collisions SUMO reported in the current episode.
        self.sumo_collisions = 0
        #: Whether a vehicle SUMO drives broke the certified logic's assumptions this episode.
        self.assumption_breaks = False
        #: The largest acceleration [m/s²] and speed [m/s] of a vehicle SUMO drives this
        #: episode (the north car, and in traffic every other vehicle).
        self.north_max_accel = 0.0
        self.north_max_speed = 0.0

    #: Whom the north car ignores at the junction (``None``: every foe, see :class:`SumoPlant`;
    #: else it also starts where the scene has it, whatever SUMO's insertion checks say).
    _north_ignores: str | None = None

    def _start(self, state: TaskState, before_last: Any = None) -> None:
        """A new SUMO scene with the north car and the ego of ``state``; ``before_last()`` is
        called before SUMO's last start-up step (the one that inserts the ego)."""
        batch = int(np.shape(state.scenarios.ego_speed)[0])
        if batch != 1:
            raise ValueError(
                f"SUMO runs one scene per process, got a batch of {batch}; use "
                "make_sumo_vec_env for several environments"
            )
        world, dt = state.world, self.config.episode.dt
        north, north_speed = float(world.progress[0, 1]), float(world.vehicles.speed[0, 1])
        # SUMO inserts vehicles on an approach only: a north car that starts with its front
        # inside the junction is inserted earlier and driven there first (it holds its speed).
        half = self.config.vehicle.length / 2
        room = self.config.geometry.approach_length - 0.5 - half
        early = max(0, math.ceil((north - room) / max(north_speed * dt, 1e-9)))
        self.plant.reset(self.seed)
        self.plant.add(
            "north", "north->south", north - north_speed * dt * (early + 1), north_speed,
            float(state.scenarios.north_speed[0]), yields=False, ignores=self._north_ignores,
            force=self._north_ignores is not None,
        )  # fmt: skip
        self.plant.add_ego("south->west", float(world.progress[0, 0]), 0.0)
        v = world.vehicles
        heading = math.atan2(v.sin_yaw[0, 0], v.cos_yaw[0, 0])
        for k in range(early + 1):  # the last step inserts the ego
            if k == early and before_last is not None:
                before_last()
            self.plant.place("ego", float(v.x[0, 0]), float(v.y[0, 0]), heading)
            self.plant.step()
        self.sumo_collisions, self.assumption_breaks = 0, False
        self.north_max_accel, self.north_max_speed = 0.0, north_speed
        self._sync_north(world)

    def _observe_driver(self, speed: float, before: float) -> None:
        """Record one tick of a vehicle SUMO drives against the certified assumptions."""
        accel = (speed - before) / self.config.episode.dt
        self.north_max_accel = max(self.north_max_accel, accel)
        self.north_max_speed = max(self.north_max_speed, speed)
        c = self.config.certified
        if accel > c.other_max_accel + 1e-6 or speed > c.other_max_speed_kmh / 3.6 + 1e-6:
            self.assumption_breaks = True

    def _sync_north(self, world: WorldState) -> None:
        """Overwrite the north car of ``world`` (in place) with SUMO's."""
        v = world.vehicles
        pose = self.plant.read("north")
        if pose is None:  # it has left the network: drive on
            world.progress[0, 1] += v.speed[0, 1] * self.config.episode.dt
            return
        before = float(v.speed[0, 1])
        v.x[0, 1], v.y[0, 1] = pose.x, pose.y
        v.cos_yaw[0, 1], v.sin_yaw[0, 1] = math.cos(pose.heading), math.sin(pose.heading)
        v.speed[0, 1] = pose.speed
        routes = self.world.route_set
        _, world.progress[0, 1], _, _ = locate(
            routes.tables, routes.spacing, routes.size - 2, 4, int(self.world.route_base[1]),
            pose.x, pose.y, float(world.progress[0, 1]),
        )  # fmt: skip
        world.lateral[0, 1] = 0.0
        self._observe_driver(pose.speed, before)

    def _step_plant(self, new_world: WorldState) -> None:
        """Push the ego's new pose, step SUMO, count its collisions, read the north car."""
        v = new_world.vehicles
        self.plant.place(
            "ego", float(v.x[0, 0]), float(v.y[0, 0]), math.atan2(v.sin_yaw[0, 0], v.cos_yaw[0, 0])
        )
        before = len(self.plant.collisions)
        self.plant.step()
        self.sumo_collisions += len(self.plant.collisions) - before
        self._sync_north(new_world)

    def _north_gap(self, new_world: WorldState) -> FloatArray:
        """The ego's separation from the north car (its pose now SUMO's) [m] ``[1]``."""
        v, p = new_world.vehicles, self.config.vehicle
        gap = footprint_gap(
            float(v.x[0, 1] - v.x[0, 0]), float(v.y[0, 1] - v.y[0, 0]), float(v.cos_yaw[0, 0]),
            float(v.sin_yaw[0, 0]), p.length, p.width, float(v.cos_yaw[0, 1]),
            float(v.sin_yaw[0, 1]), p.length, p.width,
        )  # fmt: skip
        return np.array([gap])

    def close(self) -> None:
        self.plant.close()


class LeftTurnSumoTask(_SumoScene, LeftTurnTask):
    """The left-turn task with SUMO driving the north car (see the module docstring).

    Args:
        config: The task's configuration.
        seed: SUMO's random seed (its drivers are deterministic here; kept for completeness).
    """

    def __init__(self, config: LeftTurnConfig, seed: int = 0) -> None:
        LeftTurnTask.__init__(self, config)
        self._open_plant(seed)

    def initial(self, scenarios: Scenarios) -> TaskState:
        state = LeftTurnTask.initial(self, scenarios)
        self._start(state)
        return state

    def advance_others(
        self, state: TaskState, new_world: WorldState, separation: FloatArray
    ) -> tuple[Any, FloatArray]:
        self._step_plant(new_world)
        return None, self._north_gap(new_world)


class LeftTurnSumoTrafficTask(_SumoScene, LeftTurnTrafficTask):
    """The left turn in traffic from every leg with SUMO driving every other vehicle.

    The scene is the embedded traffic task's (:class:`~safeswitch.leftturn.traffic.
    LeftTurnTrafficTask`: the same vehicles at the start, the same schedule of arrivals, routes,
    desired speeds and yielding drivers); SUMO drives them with its car-following and junction
    models — a yielding driver gives way by the network's priorities (the north–south road
    first), to the ego too where SUMO's rules say so; a non-yielding one, like the north car,
    ignores the ego at the junction and gives way to the others by SUMO's rules. The vehicles
    of the start are put where the scene has them (whatever SUMO's insertion checks say); a
    scheduled vehicle is handed to SUMO when its time comes and a slot is free, and SUMO
    inserts it when its lane has room (else on a later tick). Every tick each vehicle's pose
    and speed come back, its arc length on our route is found, and the task state is rebuilt,
    so the switching logics see SUMO's traffic through the same view as the embedded one. A
    vehicle is removed from SUMO where the embedded scene retires it. Our collision check runs
    on SUMO's poses; SUMO's own collisions are counted beside it, and every driver's speed and
    acceleration are checked against the certified assumptions.

    Args:
        config: The task's configuration.
        traffic: The traffic.
        seed: SUMO's random seed.
    """

    _north_ignores = "ego"

    def __init__(self, config: LeftTurnConfig, traffic: TrafficConfig, seed: int = 0) -> None:
        LeftTurnTrafficTask.__init__(self, config, traffic)
        self._open_plant(seed)
        self._names = [m.name for m in self.network.movements]
        #: SUMO id of the vehicle in each slot ('' for none).
        self._slot_ids: list[str] = []
        #: SUMO ids that have been in the simulation (a missing one has left, else it waits).
        self._seen: set[str] = set()
        self._arrived = 0
        self._poses: dict[int, Pose] = {}

    @functools.cached_property
    def embedded(self) -> LeftTurnTrafficTask:
        """The same scene on the embedded simulator (batched; what the oracle plans on)."""
        return LeftTurnTrafficTask(self.config, self.traffic)

    def without_ego(self, scenarios: Scenarios) -> WithoutEgo:
        """The embedded scene's others without the ego (what the oracle plans against: SUMO's
        drivers are not replayed, and SUMO runs one scene at a time)."""
        return self.embedded.without_ego(scenarios)

    def conflict_timeline(self, scenarios: Scenarios) -> ConflictTimeline:
        """The embedded scene's (see :meth:`without_ego`)."""
        return self.embedded.conflict_timeline(scenarios)

    def initial(self, scenarios: Scenarios) -> TrafficTaskState:
        state = LeftTurnTrafficTask.initial(self, scenarios)
        tr = state.traffic
        slots = tr.route.shape[1]
        self._slot_ids = [""] * slots
        self._seen, self._arrived = set(), 0
        dt = self.config.episode.dt

        def insert_initial() -> None:  # placed one tick back: the start-up step moves them
            for i in range(slots):
                if tr.active[0, i]:
                    vid = f"v{self._arrived}"
                    self._arrived += 1
                    self.plant.add(
                        vid, self._names[tr.route[0, i]],
                        float(tr.progress[0, i] - tr.speed[0, i] * dt), float(tr.speed[0, i]),
                        float(tr.desired[0, i]), bool(tr.yields[0, i]), force=True,
                        ignores="ego",
                    )  # fmt: skip
                    self._slot_ids[i] = vid

        self._start(state, insert_initial)
        self._read_traffic(tr, tr)
        self._place(tr)
        return state

    def _place(self, new: TrafficState) -> None:
        """Poses of the vehicles: SUMO's (for the collision check and the observation; every
        active vehicle has one)."""
        for i, pose in self._poses.items():
            new.x[0, i], new.y[0, i] = pose.x, pose.y
            new.cos_yaw[0, i], new.sin_yaw[0, i] = math.cos(pose.heading), math.sin(pose.heading)

    def _read_traffic(self, before: TrafficState, new: TrafficState) -> None:
        """Fill ``new`` (in place) with SUMO's vehicles; retire those past their exit."""
        present = set(self.plant.vehicles())
        exit_at = self.exit_at
        self._poses = {}
        for i, vid in enumerate(self._slot_ids):
            if vid and vid not in present and vid in self._seen:  # it has left the network
                self._slot_ids[i] = vid = ""
            if not vid or vid not in present:  # an empty slot, or one SUMO has yet to insert
                new.active[0, i] = False
                continue
            pose = self.plant.read(vid)
            assert pose is not None
            first = vid not in self._seen
            self._seen.add(vid)
            r = int(new.route[0, i])
            base = r * self.tables.size
            hint = 0.0 if first and before is not new else float(before.progress[0, i])
            _, s, _, _ = locate(
                self.tables.route_tables, self.tables.spacing, self.tables.k_max, 8, base,
                pose.x, pose.y, hint,
            )  # fmt: skip
            if not first:
                self._observe_driver(pose.speed, float(before.speed[0, i]))
            if s >= exit_at[r]:
                self.plant.remove(vid)
                self._slot_ids[i] = ""
                new.active[0, i] = False
                continue
            new.progress[0, i], new.speed[0, i], new.active[0, i] = s, pose.speed, True
            self._poses[i] = pose

    def _hand_over_arrivals(self, tr: TrafficState, new: TrafficState, now: float) -> None:
        """Give SUMO the scheduled vehicles whose time has come, while slots are free."""
        plan = tr.schedule
        legs, most = plan.time.shape[1], plan.time.shape[2]
        for leg in range(legs):
            n = int(new.entered[0, leg])
            if n >= most or plan.time[0, leg, n] > now:
                continue
            free = [i for i, vid in enumerate(self._slot_ids) if not vid]
            if not free:
                continue  # no slot: it waits outside the scene, as in the embedded one
            i = free[0]
            vid = f"v{self._arrived}"
            self._arrived += 1
            r = int(plan.route[0, leg, n])
            desired = float(plan.desired[0, leg, n])
            self.plant.add(vid, self._names[r], 0.0, desired, desired,
                           bool(plan.yields[0, leg, n]), safe_speed=True,
                           ignores="ego")  # fmt: skip
            self._slot_ids[i] = vid
            new.route[0, i], new.desired[0, i] = r, desired
            new.yields[0, i], new.waited[0, i] = plan.yields[0, leg, n], 0.0
            new.progress[0, i], new.speed[0, i], new.active[0, i] = 0.0, 0.0, False
            new.entered[0, leg] = n + 1

    def advance_others(
        self, state: TaskState, new_world: WorldState, separation: FloatArray
    ) -> tuple[Any, FloatArray]:
        assert isinstance(state, TrafficTaskState)
        tr = state.traffic
        new = tr.copy()
        now = float(state.tick[0] + 1) * self.config.episode.dt
        self._hand_over_arrivals(tr, new, now)
        self._step_plant(new_world)
        self._read_traffic(tr, new)
        self._place(new)
        return self.with_separations(state, new, new_world, self._north_gap(new_world))


def sumo_task(
    config: LeftTurnConfig | dict[str, Any] | None = None, traffic: Any = None, **overrides: Any
) -> LeftTurnSumoTask | LeftTurnSumoTrafficTask:
    """The SUMO task of a configuration (as :func:`~safeswitch.leftturn.make.build_task`):
    the paper's scene, or with ``traffic`` (a preset's name, a dict or a
    :class:`~safeswitch.leftturn.config.TrafficConfig`) traffic from every leg.

    Raises:
        ConfigError: An unknown preset or a bad traffic setting (named).
    """
    base = build_task(None, config, traffic=traffic, **overrides)
    if isinstance(base, LeftTurnTrafficTask):
        return LeftTurnSumoTrafficTask(base.config, base.traffic)
    return LeftTurnSumoTask(base.config)


class LeftTurnSumoEnv(LeftTurnEnv):
    """``safeswitch/LeftTurnSumo-v0``: :class:`~safeswitch.leftturn.env.LeftTurnEnv` with SUMO
    driving the north car, and with ``traffic`` every other vehicle (same arguments; the
    observation in traffic is ``safeswitch/LeftTurnTraffic-v0``'s). Its ``info`` adds
    ``sumo_collisions`` and ``assumption_breaks`` at the end of an episode."""

    def make_task(self, render_mode: str | None, config: Any, learned_scope: str,
                  traffic: Any, **overrides: Any) -> LeftTurnTask:  # fmt: skip
        base = build_task(render_mode, config, learned_scope, None, **overrides)
        return sumo_task(base.config, traffic)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = super().step(action)
        if terminated or truncated:
            task = self.task
            assert isinstance(task, _SumoScene)
            info["sumo_collisions"] = task.sumo_collisions
            info["assumption_breaks"] = task.assumption_breaks
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        task = self.task
        if isinstance(task, _SumoScene):
            task.close()
        super().close()


def _make_env(index: int, kwargs: dict[str, Any]) -> LeftTurnSumoEnv:
    return LeftTurnSumoEnv(env_index=index, **kwargs)


def make_sumo_vec_env(num_envs: int, seed: int | None = None, **kwargs: Any) -> Any:
    """``num_envs`` SUMO environments in worker processes (SB3's ``SubprocVecEnv``); keyword
    arguments as for ``gymnasium.make("safeswitch/LeftTurnSumo-v0", ...)``. Close it to end
    the workers."""
    from stable_baselines3.common.vec_env import SubprocVecEnv

    if num_envs < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}")
    env = SubprocVecEnv(
        [functools.partial(_make_env, i, kwargs) for i in range(num_envs)], start_method="spawn"
    )
    if seed is not None:
        env.seed(seed)
    return env
