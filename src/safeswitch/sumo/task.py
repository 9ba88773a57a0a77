"""The left-turn task on SUMO: ``safeswitch/LeftTurnSumo-v0`` and its worker-process VecEnv.

:class:`LeftTurnSumoTask` is the paper's task (:class:`~safeswitch.leftturn.task.LeftTurnTask`)
with SUMO as the plant of the north car: every tick the ego's pose goes to SUMO, SUMO steps,
and the north car's pose and speed come back into the task state before the rewards, the
observation and the next decision of the switching logic — so the Table I controllers, the
logics and the learned policy act exactly as on the embedded simulator, on the same pedal-level
ego. Collisions are ours (footprints); SUMO's own (junctions included) are counted beside them
(:attr:`LeftTurnSumoTask.sumo_collisions`) for a cross-check.

The certified logic assumes the north car accelerates at most ``north_max_accel`` and drives at
most ``north_max_speed_kmh``; what SUMO's north car actually does is measured every tick and an
episode in which it broke either is counted (:attr:`LeftTurnSumoTask.assumption_breaks`), not
hidden.

One scene per process (libsumo); :func:`make_sumo_vec_env` runs ``n`` environments in worker
processes (Stable-Baselines3's ``SubprocVecEnv``, started with ``spawn``; a worker exits when
its pipe closes, so none outlives a crashed or interrupted parent). Traffic from every leg is
not available on SUMO yet (refused by name).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.env import LeftTurnEnv
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.task import LeftTurnTask, TaskState, build_task
from safeswitch.sim.collision import separation as footprint_gap
from safeswitch.sim.geometry import FloatArray, locate
from safeswitch.sim.world import WorldState
from safeswitch.sumo.network import network_file
from safeswitch.sumo.plant import SumoPlant


class ScenarioError(ValueError):
    """A scenario SUMO cannot run here (the message names it)."""


class LeftTurnSumoTask(LeftTurnTask):
    """The left-turn task with SUMO driving the north car (see the module docstring).

    Args:
        config: The task's configuration.
        seed: SUMO's random seed (its drivers are deterministic here; kept for completeness).
    """

    def __init__(self, config: LeftTurnConfig, seed: int = 0) -> None:
        super().__init__(config)
        self.seed = seed
        c = config
        self.plant = SumoPlant(
            network_file(c.geometry), c.episode.dt, c.vehicle.length, c.vehicle.width
        )
        #: Collisions SUMO reported in the current episode.
        self.sumo_collisions = 0
        #: Whether SUMO's north car broke the certified logic's assumptions this episode.
        self.assumption_breaks = False
        #: The north car's largest acceleration [m/s²] and speed [m/s] this episode.
        self.north_max_accel = 0.0
        self.north_max_speed = 0.0

    def initial(self, scenarios: Scenarios) -> TaskState:
        batch = int(np.shape(scenarios.ego_speed)[0])
        if batch != 1:
            raise ValueError(
                f"SUMO runs one scene per process, got a batch of {batch}; use "
                "make_sumo_vec_env for several environments"
            )
        state = super().initial(scenarios)
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
            float(state.scenarios.north_speed[0]), yields=False,
        )  # fmt: skip
        self.plant.add_ego("south->west", float(world.progress[0, 0]), 0.0)
        v = world.vehicles
        heading = math.atan2(v.sin_yaw[0, 0], v.cos_yaw[0, 0])
        for _ in range(early + 1):  # the last step inserts the ego
            self.plant.place("ego", float(v.x[0, 0]), float(v.y[0, 0]), heading)
            self.plant.step()
        self.sumo_collisions, self.assumption_breaks = 0, False
        self.north_max_accel, self.north_max_speed = 0.0, north_speed
        self._sync_north(world)
        return state

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
        accel = (pose.speed - before) / self.config.episode.dt
        self.north_max_accel = max(self.north_max_accel, accel)
        self.north_max_speed = max(self.north_max_speed, pose.speed)
        c = self.config.certified
        if accel > c.north_max_accel + 1e-6 or pose.speed > c.north_max_speed_kmh / 3.6 + 1e-6:
            self.assumption_breaks = True

    def advance_others(
        self, state: TaskState, new_world: WorldState, separation: FloatArray
    ) -> tuple[Any, FloatArray]:
        v = new_world.vehicles
        self.plant.place(
            "ego", float(v.x[0, 0]), float(v.y[0, 0]), math.atan2(v.sin_yaw[0, 0], v.cos_yaw[0, 0])
        )
        before = len(self.plant.collisions)
        self.plant.step()
        self.sumo_collisions += len(self.plant.collisions) - before
        self._sync_north(new_world)
        p = self.config.vehicle
        gap = footprint_gap(
            float(v.x[0, 1] - v.x[0, 0]), float(v.y[0, 1] - v.y[0, 0]), float(v.cos_yaw[0, 0]),
            float(v.sin_yaw[0, 0]), p.length, p.width, float(v.cos_yaw[0, 1]),
            float(v.sin_yaw[0, 1]), p.length, p.width,
        )  # fmt: skip
        return None, np.array([gap])

    def close(self) -> None:
        self.plant.close()


def sumo_task(
    config: LeftTurnConfig | dict[str, Any] | None = None, traffic: Any = None, **overrides: Any
) -> LeftTurnSumoTask:
    """The SUMO task of a configuration (as :func:`~safeswitch.leftturn.task.build_task`).

    Raises:
        ScenarioError: ``traffic`` is set (not available on SUMO yet).
    """
    if traffic is not None:
        raise ScenarioError(
            f"traffic={traffic!r} on SUMO: traffic from every leg runs on the embedded "
            "simulator only (safeswitch/LeftTurnTraffic-v0); SUMO has the paper's scene"
        )
    return LeftTurnSumoTask(build_task(None, config, **overrides).config)


class LeftTurnSumoEnv(LeftTurnEnv):
    """``safeswitch/LeftTurnSumo-v0``: :class:`~safeswitch.leftturn.env.LeftTurnEnv` with SUMO
    driving the north car (same arguments; ``traffic`` is refused). Its ``info`` adds
    ``sumo_collisions`` and ``assumption_breaks`` at the end of an episode."""

    def make_task(self, render_mode: str | None, config: Any, learned_scope: str,
                  traffic: Any, **overrides: Any) -> LeftTurnTask:  # fmt: skip
        base = build_task(render_mode, config, learned_scope, None, **overrides)
        return sumo_task(base.config, traffic)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = super().step(action)
        if terminated or truncated:
            task = self.task
            assert isinstance(task, LeftTurnSumoTask)
            info["sumo_collisions"] = task.sumo_collisions
            info["assumption_breaks"] = task.assumption_breaks
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        task = self.task
        if isinstance(task, LeftTurnSumoTask):
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
