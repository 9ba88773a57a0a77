"""A natively batched Stable-Baselines3 ``VecEnv`` of the left turn.

All environments advance in one call of :meth:`LeftTurnTask.step`; ended episodes are reset in
place with one call of :meth:`LeftTurnTask.initial` for just those. SB3 conventions hold
(``DummyVecEnv`` is the reference): the returned observation of an ended environment is the
first of its next episode, and its info carries ``terminal_observation``,
``TimeLimit.truncated`` and an ``episode`` summary (the keys of SB3's ``Monitor`` — ``r``,
``l``, ``t`` — plus the safety and comfort statistics below); ``reset_infos[i]`` holds the
scenario of environment ``i``'s current episode; ``get_attr`` and ``env_method`` act per
environment, on an :class:`EnvironmentView`; reset options are refused (the scenario
distribution is part of the configuration).

The ``infos`` of a step are a :class:`~safeswitch.leftturn.info.BatchInfos`: a sequence of
per-environment dicts built lazily on access (``infos[i]["reason"]``, ``for info in infos``,
``list(infos)`` all work as with a list), so that 4,096 dicts are not built every tick.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import fields, replace
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

from safeswitch.core.arrays import put_rows
from safeswitch.leftturn.config import FROM_CONFIG, LeftTurnConfig
from safeswitch.leftturn.info import BatchInfos, scenario_info
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.spaces import action_space, observation_space
from safeswitch.leftturn.statistics import EpisodeStatistics, TickCosts
from safeswitch.leftturn.task import StepRecord, TaskState, learned_actions


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
        learned_scope: As for :class:`~safeswitch.leftturn.env.LeftTurnEnv`.
        traffic: As for :class:`~safeswitch.leftturn.env.LeftTurnEnv` (``None``: the paper's
            scene, bit for bit).
        perception: As for :class:`~safeswitch.leftturn.env.LeftTurnEnv`.
        stagger: Truncate each environment's first episode after a random number of ticks
            (uniform over the horizon, drawn from ``seed``), as a time limit (SB3 bootstraps
            it). Every episode of the left turn lasts the whole horizon, so without this all
            environments start, and end, their episodes together for the whole run: each
            rollout of fewer ticks than an episode then holds only the approach, or only what
            follows the turn, of every episode, and the next update sees only the other part
            (Rudin et al., *Learning to Walk in Minutes Using Massively Parallel Deep RL*,
            CoRL 2021, randomise the first episode's length for the same reason). Off by
            default (the paper's setting, and every run before it).
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
        learned_scope: str = FROM_CONFIG,
        traffic: Any = None,
        perception: Any = FROM_CONFIG,
        stagger: bool = False,
    ) -> None:
        if not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        self.task = build_task(
            render_mode, config, learned_scope, traffic, switching=switching,
            adas_penalty=adas_penalty, scenario=scenario,
            perception=perception,
        )  # fmt: skip
        self.config = self.task.config
        self._traffic = traffic
        self.render_mode = render_mode
        super().__init__(int(num_envs), observation_space(self.task), action_space())
        self._seed = _fresh_seed() if seed is None else int(seed)
        self._env_ids = np.arange(self.num_envs, dtype=np.int64)
        self._episodes = np.zeros(self.num_envs, dtype=np.int64)
        self._state: TaskState | None = None
        self._actions: NDArray[np.float64] | None = None
        self._stats = EpisodeStatistics(self.num_envs)
        self._start = time.perf_counter()
        self.stagger = bool(stagger)
        #: Per environment, the tick its first episode is cut at (0: no cut; see ``stagger``).
        self._first_cut = np.zeros(self.num_envs, dtype=np.int64)
        self.last_record: StepRecord | None = None
        #: The ego's progress along its route after the last step [m], taken before the
        #: episodes that ended are reset (reward shaping reads it; training.shaping).
        self.ego_progress_after_step = np.zeros(self.num_envs)
        #: Set ``count_reasons`` to have :attr:`reason_ticks_in_step` filled: per environment
        #: and reason of :attr:`LeftTurnTask.reasons`, the ticks of the last step on which
        #: that reason's safety action ran (training.shaping.ReasonPenalty reads it).
        self.count_reasons = False
        self.reason_ticks_in_step = np.zeros((self.num_envs, len(self.task.reasons)), np.int32)
        #: While ``count_costs`` holds (the default), :attr:`costs_in_step` is filled (a
        #: :class:`TickCosts` of the last step; training.constraints reads it) and every info
        #: has ``costs``, the plant's named costs of the step; off, neither.
        self.count_costs = True
        self.costs_in_step = TickCosts(self.num_envs)
        #: ``(task, count)``: the last ``count`` environments draw their scenarios from
        #: ``task`` (see :meth:`rehearse`).
        self._rehearsal: tuple[Any, int] | None = None

    def rehearse(self, config: LeftTurnConfig | dict[str, Any], count: int) -> None:
        """From the next episode on, the last ``count`` environments draw their scenarios from
        ``config``'s distribution instead of this batch's (a *rehearsal* of another
        distribution of the same plant, as ``safeswitch adapt`` replays the one a policy was
        trained on; 0: none). Only the scenarios come from ``config``: every environment drives
        this batch's plant, logic and rewards.

        Raises:
            ValueError: ``count`` outside ``0 … num_envs``.
        """
        if not 0 <= count <= self.num_envs:
            raise ValueError(f"count must be in 0…{self.num_envs}, got {count}")
        task = build_task(None, config, traffic=self._traffic) if count else None
        self._rehearsal = (task, int(count)) if count else None

    @property
    def rehearsing(self) -> NDArray[np.bool_]:
        """Per environment, whether it draws from the rehearsed distribution ``[N]``."""
        count = 0 if self._rehearsal is None else self._rehearsal[1]
        return self._env_ids >= self.num_envs - count

    def _draw(self, env_ids: NDArray[np.int64], episodes: NDArray[np.int64]) -> Any:
        """The scenarios of episodes ``episodes`` of environments ``env_ids``."""
        drawn = self.task.draw_scenarios(self._seed, env_ids, episodes)
        if self._rehearsal is None:
            return drawn
        task, count = self._rehearsal
        rows = np.flatnonzero(env_ids >= self.num_envs - count)
        if len(rows):
            put_rows(drawn, rows, task.draw_scenarios(self._seed, env_ids[rows], episodes[rows]))
        return drawn

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
        scenarios = self._draw(self._env_ids, self._episodes)
        self._episodes += 1
        self._state = self.task.initial(scenarios)
        self._stats = EpisodeStatistics(self.num_envs)
        self._first_cut = self._stagger_cuts() if self.stagger else np.zeros_like(self._first_cut)
        self.reset_infos = [{"scenario": scenario_info(scenarios, i)} for i in range(self.num_envs)]
        self._reset_options()
        return self.task.observe(self._state)

    def set_options(self, options: list[dict[str, Any]] | dict[str, Any] | None = None) -> None:
        """Reset options are refused: the left turn takes none (choose scenarios with
        ``scenario=`` or the configuration's ``scenarios`` section)."""
        given = options if isinstance(options, list) else [options]
        if any(given):
            raise ValueError(
                f"LeftTurnVecEnv takes no reset options, got {options!r}; set the scenario "
                "with scenario=... or the configuration's 'scenarios' section"
            )

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = learned_actions(actions, self.num_envs)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        counting, counts = self.count_reasons, self.reason_ticks_in_step
        costs = self.costs_in_step if self.count_costs else None
        if counting:
            counts[:] = 0
        if costs is not None:
            costs.clear()

        def on_tick(tick: StepRecord, live: NDArray[np.bool_]) -> None:
            self._stats.update(tick, self.config, live)
            if counting:
                acted = np.flatnonzero(tick.safety_active & live)
                counts[acted, tick.reason[acted]] += 1
            if costs is not None:
                costs.add(tick, self._stats, live)

        self._state, record = self.task.hold(self.state, self._actions, on_tick)
        self._actions = None
        if self._first_cut.any():
            record = self._cut_first_episodes(record)
        self.ego_progress_after_step = self._state.world.progress[:, 0].copy()
        done = record.terminated | record.truncated
        observation = record.observed
        ended = np.flatnonzero(done)
        terminal = observation[ended].copy()
        episode: dict[str, NDArray[Any]] = {}
        if ended.size:
            # Some of the record's arrays are the state's own (the ego's acceleration, its
            # lateral deviation, ...): copied before the reset writes the fresh episodes in.
            record = _detached(record)
            episode = self._stats.summary(ended, record, time.perf_counter() - self._start)
            self._stats.reset_at(ended)
            fresh = self.task.initial(self._draw(self._env_ids[ended], self._episodes[ended]))
            self._episodes[ended] += 1
            self._state.replace_at(ended, fresh)
            for j, i in enumerate(ended):
                self.reset_infos[i] = {"scenario": scenario_info(fresh.scenarios, j)}
            observation = observation.copy()
            observation[ended] = self.task.observe(fresh)
        self.last_record = record
        published = costs.arrays() if costs is not None else None
        infos = BatchInfos(record, self.task.reasons, done, terminal, episode, published)
        return observation, record.reward.astype(np.float32), done, infos  # type: ignore[return-value]

    def _stagger_cuts(self) -> NDArray[np.int64]:
        """The tick each environment's first episode is cut at: uniform over the horizon,
        from the base seed (so a run is reproducible)."""
        episode = self.config.episode
        horizon = round(episode.horizon_s / episode.dt)
        rng = np.random.default_rng([self._seed, 0x5A66])
        return rng.integers(episode.decision_interval, horizon + 1, self.num_envs)

    def _cut_first_episodes(self, record: StepRecord) -> StepRecord:
        """Truncate the first episodes that reached their cut (``stagger``)."""
        ended = record.terminated | record.truncated
        cut = (self._first_cut > 0) & (self._stats.length >= self._first_cut) & ~ended
        self._first_cut[ended | cut] = 0
        if not cut.any():
            return record
        return replace(record, truncated=record.truncated | cut)

    def close(self) -> None:
        self._state = None

    # -- the VecEnv attribute protocol, per environment -----------------------------------

    def environment(self, index: int) -> EnvironmentView:
        """Environment ``index`` of the batch (what ``get_attr`` and ``env_method`` act on)."""
        if not -self.num_envs <= index < self.num_envs:
            raise IndexError(f"environment {index} out of range for {self.num_envs}")
        return EnvironmentView(self, index % self.num_envs)

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.environment(i), attr_name) for i in self._get_indices(indices)]

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
        views = [self.environment(i) for i in self._get_indices(indices)]
        return [getattr(view, method_name)(*method_args, **method_kwargs) for view in views]

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
    ) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [self.environment(i).render() for i in range(self.num_envs)]


class EnvironmentView:
    """One environment of a :class:`LeftTurnVecEnv`: what ``get_attr`` and ``env_method``
    reach, as they reach the environments of SB3's ``DummyVecEnv``.

    Attributes not defined here are the batch's (its ``config``, ``task``, spaces and
    ``render_mode`` are shared by every environment).

    Args:
        vec: The batch.
        index: Which environment.
    """

    def __init__(self, vec: LeftTurnVecEnv, index: int) -> None:
        self._vec = vec
        self.env_index = index

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        try:
            return getattr(self._vec, name)
        except AttributeError:
            raise AttributeError(
                f"environment {self.env_index} of the LeftTurnVecEnv has no attribute {name!r}"
            ) from None

    def scenario(self) -> dict[str, float]:
        """The scenario of this environment's current episode (see ``reset_infos``)."""
        return scenario_info(self._vec.state.scenarios, self.env_index)

    def episode_count(self) -> int:
        """Episodes this environment has started."""
        return int(self._vec.episode_counters[self.env_index])

    def render(self) -> np.ndarray | None:
        """This environment's current scene as an RGB image (``render_mode="rgb_array"``)."""
        if self._vec.render_mode != "rgb_array":
            return None
        from safeswitch.leftturn.render import render_scene

        return render_scene(self._vec.task, self._vec.state, self.env_index, self._vec.last_record)


def _detached(record: StepRecord) -> StepRecord:
    """``record`` with every array copied (none shared with the task state any more)."""
    arrays: dict[str, Any] = {
        f.name: value.copy()
        for f in fields(record)
        if isinstance(value := getattr(record, f.name), np.ndarray)
    }
    return replace(record, **arrays)


def _fresh_seed() -> int:
    """A seed from the operating system's entropy."""
    return int(np.random.SeedSequence().generate_state(2, np.uint64).view(np.uint64)[0])


def make_vec_env(num_envs: int, **kwargs: Any) -> LeftTurnVecEnv:
    """A natively batched SB3 ``VecEnv`` of ``num_envs`` left-turn environments; keyword
    arguments as for ``gymnasium.make("safeswitch/LeftTurn-v0", ...)`` plus ``seed``."""
    return LeftTurnVecEnv(num_envs, **kwargs)
