"""A natively batched Stable-Baselines3 ``VecEnv`` of the left turn.

All environments advance in one call of :meth:`LeftTurnTask.step`; ended episodes are reset in
place with one call of :meth:`LeftTurnTask.initial` for just those. SB3 conventions hold: the
returned observation of an ended environment is the first of its next episode, and its info
carries ``terminal_observation``, ``TimeLimit.truncated`` and an ``episode`` summary (the keys
of SB3's ``Monitor`` — ``r``, ``l``, ``t`` — plus the safety and comfort statistics below).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray
from stable_baselines3.common.vec_env.base_vec_env import (
    VecEnv,
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
)

from safeswitch.leftturn.config import FROM_CONFIG, LeftTurnConfig
from safeswitch.leftturn.info import BatchInfos
from safeswitch.leftturn.rewards import REWARD_TERMS
from safeswitch.leftturn.spaces import action_space, observation_space
from safeswitch.leftturn.task import StepRecord, TaskState, build_task

#: Keys of the ``episode`` summary beyond SB3's ``r``, ``l`` and ``t``.
EPISODE_KEYS: tuple[str, ...] = (
    "collision",
    "safety_steps",
    "min_speed",
    "comfort_violation_steps",
    "outcome",
    "time_to_clear",
    "max_lateral_deviation",
    *(f"term_{name}" for name in REWARD_TERMS),
)


class EpisodeStatistics:
    """Running per-episode statistics of a batch of environments (arrays ``[B]``)."""

    def __init__(self, batch: int) -> None:
        self.ret = np.zeros(batch)
        self.length = np.zeros(batch, dtype=np.int64)
        self.collision = np.zeros(batch, dtype=bool)
        self.safety_steps = np.zeros(batch, dtype=np.int64)
        self.min_speed = np.full(batch, np.inf)
        self.comfort_violation_steps = np.zeros(batch, dtype=np.int64)
        self.time_to_clear = np.full(batch, np.nan)
        self.max_lateral = np.zeros(batch)
        self.terms = {name: np.zeros(batch) for name in REWARD_TERMS}

    def update(
        self, record: StepRecord, config: LeftTurnConfig, live: NDArray[np.bool_] | None = None
    ) -> None:
        """Add one tick; with ``live``, only the episodes it selects (the others have ended and
        keep their figures)."""
        r = record
        on = np.ones(r.reward.shape[0], dtype=bool) if live is None else live
        self.ret += np.where(on, r.reward, 0.0)
        self.length += on
        self.collision |= r.collision & on
        self.safety_steps += r.safety_active & on
        self.min_speed = np.where(on, np.minimum(self.min_speed, r.ego_speed), self.min_speed)
        self.comfort_violation_steps += on & (
            (np.abs(r.accel_lon) > config.rewards.comfort_accel_lon)
            | (np.abs(r.accel_lat) > config.rewards.comfort_accel_lat)
        )
        just_cleared = on & r.ego_cleared & np.isnan(self.time_to_clear)
        self.time_to_clear[just_cleared] = self.length[just_cleared] * config.episode.dt
        self.max_lateral = np.where(
            on, np.maximum(self.max_lateral, np.abs(r.lateral)), self.max_lateral
        )
        for name in REWARD_TERMS:
            self.terms[name] += np.where(on, r.terms[name], 0.0)

    def summary(
        self, index: NDArray[np.intp], record: StepRecord, elapsed: float
    ) -> dict[str, NDArray[Any]]:
        """Summaries of the episodes ``index`` (that just ended), arrays ``[len(index)]``."""
        out: dict[str, NDArray[Any]] = {
            "r": self.ret[index].copy(),
            "l": self.length[index].copy(),
            "t": np.full(len(index), round(elapsed, 6)),
            "collision": self.collision[index].copy(),
            "safety_steps": self.safety_steps[index].copy(),
            "min_speed": self.min_speed[index].copy(),
            "comfort_violation_steps": self.comfort_violation_steps[index].copy(),
            "outcome": record.outcome[index].copy(),
            "time_to_clear": self.time_to_clear[index].copy(),
            "max_lateral_deviation": self.max_lateral[index].copy(),
        }
        for name in REWARD_TERMS:
            out[f"term_{name}"] = self.terms[name][index].copy()
        return out

    def reset_at(self, index: NDArray[np.intp]) -> None:
        self.ret[index] = 0.0
        self.length[index] = 0
        self.collision[index] = False
        self.safety_steps[index] = 0
        self.min_speed[index] = np.inf
        self.comfort_violation_steps[index] = 0
        self.time_to_clear[index] = np.nan
        self.max_lateral[index] = 0.0
        for name in REWARD_TERMS:
            self.terms[name][index] = 0.0


class LeftTurnVecEnv(VecEnv):
    """``num_envs`` left-turn environments stepped as one batch.

    Environment ``i``'s ``k``-th episode plays the scenario drawn from ``(seed, i, k)``, so
    results do not depend on the batch size (see :mod:`safeswitch.leftturn.scenarios`).

    Args:
        num_envs: Number of environments.
        switching: ``"paper"``, ``"certified"`` or ``"none"``.
        adas_penalty: Whether ``R_ADAS`` is in the reward.
        scenario: ``None`` (random), ``"cut"``, ``"yield1"`` or ``"yield2"``.
        config: Full configuration (a :class:`LeftTurnConfig` or a dict). The three arguments
            above override its fields when given; left out, the configuration's values hold
            (by default ``"paper"``, ``True`` and ``None``).
        seed: Base seed; ``None`` draws one from the operating system.
        render_mode: ``None`` or ``"rgb_array"``.
    """

    def __init__(
        self,
        num_envs: int,
        switching: str = FROM_CONFIG,
        adas_penalty: bool = FROM_CONFIG,
        scenario: str | None = FROM_CONFIG,
        config: LeftTurnConfig | dict[str, Any] | None = None,
        seed: int | None = None,
        render_mode: str | None = None,
    ) -> None:
        if not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        self.task = build_task(
            render_mode, config, switching=switching, adas_penalty=adas_penalty, scenario=scenario
        )
        self.config = self.task.config
        self.render_mode = render_mode
        super().__init__(int(num_envs), observation_space(), action_space())
        self._seed = _fresh_seed() if seed is None else int(seed)
        self._env_ids = np.arange(self.num_envs, dtype=np.int64)
        self._episodes = np.zeros(self.num_envs, dtype=np.int64)
        self._state: TaskState | None = None
        self._actions: NDArray[np.float64] | None = None
        self._stats = EpisodeStatistics(self.num_envs)
        self._start = time.perf_counter()
        self.last_record: StepRecord | None = None

    @property
    def state(self) -> TaskState:
        """The batched task state (after :meth:`reset`)."""
        if self._state is None:
            raise RuntimeError("call reset() before stepping or reading the state")
        return self._state

    @property
    def episode_counters(self) -> NDArray[np.int64]:
        """How many episodes each environment has started (its next scenario's index)."""
        return self._episodes.copy()

    @episode_counters.setter
    def episode_counters(self, value: NDArray[np.int64]) -> None:
        value = np.asarray(value, dtype=np.int64)
        if value.shape != (self.num_envs,):
            raise ValueError(f"episode_counters needs shape ({self.num_envs},), got {value.shape}")
        self._episodes = value.copy()

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Set the base seed; the next :meth:`reset` starts every environment's episode count
        again from 0."""
        self._seed = _fresh_seed() if seed is None else int(seed)
        self._episodes[:] = 0
        return [self._seed] * self.num_envs

    def reset(self) -> VecEnvObs:
        scenarios = self.task.draw_scenarios(self._seed, self._env_ids, self._episodes)
        self._episodes += 1
        self._state = self.task.initial(scenarios)
        self._stats = EpisodeStatistics(self.num_envs)
        return self.task.observe(self._state)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions, dtype=np.float64).reshape(self.num_envs)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        self._state, record = self.task.step(self.state, self._actions)
        self._actions = None
        self._stats.update(record, self.config)
        done = record.terminated | record.truncated
        observation = record.observation
        ended = np.flatnonzero(done)
        terminal = observation[ended].copy()
        episode: dict[str, NDArray[Any]] = {}
        if ended.size:
            episode = self._stats.summary(ended, record, time.perf_counter() - self._start)
            self._stats.reset_at(ended)
            fresh = self.task.initial(
                self.task.draw_scenarios(self._seed, self._env_ids[ended], self._episodes[ended])
            )
            self._episodes[ended] += 1
            self._state.replace_at(ended, fresh)
            observation = observation.copy()
            observation[ended] = self.task.observe(fresh)
        self.last_record = record
        infos = BatchInfos(record, self.task.reasons, done, terminal, episode)
        return observation, record.reward.astype(np.float32), done, infos  # type: ignore[return-value]

    def close(self) -> None:
        self._state = None

    # -- the VecEnv attribute protocol: the batch shares one configuration ---------------------

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        value = getattr(self, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        if len(list(self._get_indices(indices))) != self.num_envs:
            raise ValueError(
                f"set_attr({attr_name!r}) on a subset: the environments of a LeftTurnVecEnv "
                "share one configuration, so attributes can only be set for all of them"
            )
        setattr(self, attr_name, value)

    def env_method(
        self,
        method_name: str,
        *method_args: Any,
        indices: VecEnvIndices = None,
        **method_kwargs: Any,
    ) -> list[Any]:
        method = getattr(self, method_name)
        return [method(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
    ) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        from safeswitch.leftturn.render import render_scene

        return [
            render_scene(self.task, self.state, i, self.last_record) for i in range(self.num_envs)
        ]


def _fresh_seed() -> int:
    """A seed from the operating system's entropy."""
    return int(np.random.SeedSequence().generate_state(2, np.uint64).view(np.uint64)[0])


def make_vec_env(num_envs: int, **kwargs: Any) -> LeftTurnVecEnv:
    """A natively batched SB3 ``VecEnv`` of ``num_envs`` left-turn environments; keyword
    arguments as for ``gymnasium.make("safeswitch/LeftTurn-v0", ...)`` plus ``seed``."""
    return LeftTurnVecEnv(num_envs, **kwargs)
