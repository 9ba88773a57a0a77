"""Potential-based reward shaping on the ego's progress along its route (ours, opt-in).

``shaping.progress_shaping: k`` adds ``F = γ·Φ(s') − Φ(s)`` with ``Φ(s) = k · (the ego's path
distance along its route) [per metre]`` to the reward PPO learns from, with PPO's own ``γ``
per environment step (one decision). Shaping of this form leaves the optimal policies of the
discounted task unchanged (Ng, Harada & Russell, *Policy invariance under reward
transformations*, ICML 1999): it changes how soon a speed-up is paid for, not which behaviour
the paper's reward prefers. Its motive is measured in ``docs/learning_experiments.md``: PPO
from scratch drives below the speed limit where nothing stops it, because "a little more
throttle" pays off in ``R_v`` only through a transient that ``R_a_lon`` charges for.

The environment's own reward, its episode returns, ``progress.csv`` and every evaluation stay
the paper's: the shaping term is added here, between the environment and ``VecNormalize``.

``shaping.progress_shaping_final`` anneals ``k`` linearly over the run to that value, one value per
rollout (:class:`ShapingSchedule`): strong shaping while PPO explores, the paper's reward alone
(or nearly) while it refines. Each step uses one ``k`` for ``Φ(s)`` and ``Φ(s')``; an episode
that spans a change of ``k`` telescopes piecewise.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from safeswitch.leftturn.task import LeftTurnTask, TaskState, learned_actions
from safeswitch.leftturn.vec_env import LeftTurnVecEnv


def left_turn_beneath(venv: VecEnv, what: str) -> LeftTurnVecEnv:
    """The batched left-turn environment ``venv`` wraps (or is); ``what`` needs it."""
    base = getattr(venv, "unwrapped", venv)
    if not isinstance(base, LeftTurnVecEnv):
        raise TypeError(f"{what} needs a LeftTurnVecEnv, got {type(base).__name__}")
    return base


class ProgressShaping(VecEnvWrapper):
    """``F = gamma·Φ(s') − Φ(s)``, ``Φ = per_metre · ego progress [m]``, added to each reward.

    At the step that ends an episode ``s'`` is the episode's last state (not the next
    episode's first), so the telescoping sum is that of the episode that ended. Where the
    episode *terminated* (a collision: an absorbing state, nothing is bootstrapped after it)
    ``Φ(s') = 0``, as Ng et al. require for the optimal policies to stay unchanged; otherwise a
    collision would pay ``k`` per metre the ego had come, against the episodes that go on. At a
    time limit or the end of the route (truncation: PPO bootstraps the value of ``s'``) it is
    the last state's potential; a horizon that terminates (``episode.horizon_terminates``) is
    a termination like any other.

    Args:
        venv: The batched left-turn environment.
        per_metre: ``k`` [reward per metre of progress], > 0.
        gamma: The discount PPO applies per step of ``venv``.
    """

    def __init__(self, venv: VecEnv, per_metre: float, gamma: float) -> None:
        base = left_turn_beneath(venv, "progress shaping")
        if not (np.isfinite(per_metre) and per_metre > 0 and 0 < gamma <= 1):
            raise ValueError(f"progress shaping: per_metre={per_metre!r}, gamma={gamma!r}")
        super().__init__(venv)
        self.base = base
        self.per_metre, self.gamma = float(per_metre), float(gamma)
        self._before: np.ndarray | None = None

    def reset(self) -> VecEnvObs:
        observation = self.venv.reset()
        self._before = self._progress()
        return observation

    def step_async(self, actions: np.ndarray) -> None:
        if self._before is None:
            self._before = self._progress()
        self.venv.step_async(actions)

    def step_wait(self) -> VecEnvStepReturn:
        observation, reward, done, infos = self.venv.step_wait()
        assert self._before is not None
        record = self.base.last_record
        assert record is not None
        after = np.where(record.terminated, 0.0, self.base.ego_progress_after_step)
        shaped = self.per_metre * (self.gamma * after - self._before)
        self._before = self._progress()  # where each episode is now (a fresh one if ended)
        return observation, (reward + shaped).astype(np.float32), done, infos

    def _progress(self) -> np.ndarray:
        return self.base.state.world.progress[:, 0].copy()


class RolloutSchedule(BaseCallback):
    """Sets ``target.<attribute>`` before each rollout: linear from ``start`` at the beginning
    of the run to ``final`` at its end (a function of the run's progress, so a resumed run
    picks up where it was), logged as ``tag``."""

    def __init__(
        self, target: object, attribute: str, start: float, final: float, tag: str
    ) -> None:
        if not all(np.isfinite(v) and v >= 0 for v in (start, final)):
            raise ValueError(f"{tag} schedule: start={start!r}, final={final!r}")
        super().__init__()
        self.target, self.attribute, self.tag = target, attribute, tag
        self.start, self.final = float(start), float(final)

    def _on_rollout_start(self) -> None:
        done = 1.0 - float(self.model._current_progress_remaining)
        value = self.start + (self.final - self.start) * done
        setattr(self.target, self.attribute, value)
        self.logger.record(self.tag, value)

    def _on_step(self) -> bool:
        return True


class ReasonPenalty(VecEnvWrapper):
    """A learning-only penalty per tick on which a named reason's safety action ran, added to
    the reward PPO learns from (ours; ``shaping.reason_penalties``).

    Unlike the progress shaping this changes what PPO optimises, on purpose: under the
    ``guarded`` logic the certified filter overrules the paper logic's own braking
    (``guard:…:overrules_primary``) where that braking was itself unsafe — in every episode
    in which a guarded-trained policy we traced collided under the paper logic alone
    (``benchmarks/overrule_trace.py``). Charged about what the collision there would forfeit,
    the overrule teaches the policy to stay out of those states although training never
    collides — the "punish the shield's corrections" variant of shielded RL (Alshiekh et al.,
    *Safe Reinforcement Learning via Shielding*, AAAI 2018). The environment's own reward,
    returns, validation and evaluation stay the paper's.

    Args:
        venv: The batched left-turn environment (or a wrapper of it).
        penalties: Reason name (of ``venv``'s task's ``reasons``) → reward per tick, <= 0.

    Raises:
        ValueError: An unknown reason (the message lists the logic's reasons), or a penalty
            that is positive or not finite.
    """

    def __init__(self, venv: VecEnv, penalties: dict[str, float]) -> None:
        base = left_turn_beneath(venv, "reason penalties")
        reasons = base.task.reasons
        unknown = sorted(set(penalties) - set(reasons))
        if unknown:
            raise ValueError(
                f"reason penalties: {unknown} not reasons of the switching logic "
                f"{base.config.switching!r} (its reasons: {', '.join(reasons)})"
            )
        bad = {k: v for k, v in penalties.items() if not (np.isfinite(v) and v <= 0)}
        if bad:
            raise ValueError(f"reason penalties must be finite and <= 0, got {bad}")
        super().__init__(venv)
        self.base = base
        self.per_tick = np.zeros(len(reasons))
        #: Multiplies every penalty (:class:`PenaltySchedule` ramps it; 1: as configured).
        self.scale = 1.0
        for name, value in penalties.items():
            self.per_tick[reasons.index(name)] = value
        base.count_reasons = True

    def reset(self) -> VecEnvObs:
        return self.venv.reset()

    def step_wait(self) -> VecEnvStepReturn:
        observation, reward, done, infos = self.venv.step_wait()
        penalty = self.scale * (self.base.reason_ticks_in_step @ self.per_tick)
        return observation, (reward + penalty).astype(np.float32), done, infos


class ShapingSchedule(RolloutSchedule):
    """``shaping.progress_shaping_final``: the shaping's ``k`` from ``start`` to ``final``."""

    def __init__(self, shaping: ProgressShaping, start: float, final: float) -> None:
        super().__init__(shaping, "per_metre", start, final, "train/progress_shaping")


class PenaltySchedule(RolloutSchedule):
    """``shaping.reason_penalties_initial_scale``: the reason penalties scaled from ``start`` of
    their configured values at the beginning of the run to all of them at its end."""

    def __init__(self, penalty: ReasonPenalty, start: float) -> None:
        super().__init__(penalty, "scale", start, 1.0, "train/reason_penalty_scale")


class ClearTimePenalty(VecEnvWrapper):
    """A learning-only cost per second until the ego has left its conflict zone, added to the
    reward PPO learns from (ours; ``shaping.clear_time_penalty``).

    The paper's reward is all but indifferent to *when* the ego clears the crossing: a yield
    that crawls up to the zone and one that arrives just behind the north car at speed score
    about the same (``benchmarks/reward_landscape.py``), so PPO has no reason to prefer the
    second, and efficiency (oracle time over time to clear) does. This term charges
    ``per_second`` for every step begun with the ego not yet clear: a minimum-time cost on top
    of the paper's reward. A collision (an episode that terminates) is charged the rest of the
    horizon, so ending an episode never saves the cost. The environment's own reward,
    returns, validation and evaluation stay the paper's.

    Args:
        venv: The batched left-turn environment (or a wrapper of it).
        per_second: The cost [reward per second], > 0.
    """

    def __init__(self, venv: VecEnv, per_second: float) -> None:
        base = left_turn_beneath(venv, "a clear-time penalty")
        if not (np.isfinite(per_second) and per_second > 0):
            raise ValueError(f"clear-time penalty: per_second={per_second!r}")
        super().__init__(venv)
        self.base, self.per_second = base, float(per_second)
        episode = base.config.episode
        self.step_s = episode.decision_interval * episode.dt
        self.horizon_s = episode.horizon_s
        self.elapsed = np.zeros(self.num_envs)
        self.cleared = np.zeros(self.num_envs, dtype=bool)

    def reset(self) -> VecEnvObs:
        self.elapsed[:] = 0.0
        self.cleared[:] = False
        return self.venv.reset()

    def step_wait(self) -> VecEnvStepReturn:
        observation, reward, done, infos = self.venv.step_wait()
        record = self.base.last_record
        assert record is not None
        charge = np.where(self.cleared, 0.0, self.per_second * self.step_s)
        self.elapsed += self.step_s
        self.cleared |= record.ego_cleared
        rest = np.maximum(self.horizon_s - self.elapsed, 0.0)
        charge += np.where(record.terminated & ~self.cleared, self.per_second * rest, 0.0)
        self.elapsed[done] = 0.0
        self.cleared[done] = False
        return observation, (reward - charge).astype(np.float32), done, infos


class CounterfactualPenalty(VecEnvWrapper):
    """A learning-only charge for the collisions the deployed logic *alone* would have let
    happen (ours; ``shaping.counterfactual_penalty``).

    Under ``guarded`` the certified filter beneath the paper logic keeps training
    collision-free, so the policy never meets the collisions the paper logic alone lets
    through (it brakes an ego that has started across, to a stop inside the north car's
    path). Charging every tick on which the filter intervened (``shaping.reason_penalties``) is a
    broad proxy: a constant throttle of 0.6 meets such an overrule in 1,077 of 2,000 random
    scenarios and collides under the paper logic alone in 1 (``benchmarks/overrule_trace.py
    --throttle``).
    This charges only the ones that matter: on every step on which the guard starts
    intervening (any ``guard:…`` reason, after a step of the same episode without one), a copy
    of the episode as it was at the start of that step is rolled forward under the deployed
    logic alone (``switching``), the step's learned action held, for at most ``horizon_s`` or
    until either car has left its conflict zone; if that copy collides, ``penalty`` is added
    to the reward of the step. The real episode goes on under the guard, so training stays
    collision-free. The counterfactual is exact for the north car (its behaviour does not
    depend on the ego) and a model for the policy (its action held): an episode's first one
    *is* that episode under the deployed logic alone if the policy's action has been
    constant. The environment's own reward, returns, validation and evaluation stay the
    paper's.

    Args:
        venv: The batched left-turn environment (or a wrapper of it), under a guarded logic.
        penalty: Reward added to a step whose counterfactual collided, < 0.
        horizon_s: How far a counterfactual is rolled at most [s], > 0.
        switching: The logic the counterfactual runs under (the deployed one, e.g. ``paper``).

    Attributes:
        rollouts: Counterfactuals rolled so far; ``collisions``: how many of them collided.
        rolled: Per environment, a counterfactual was rolled on the last step;
            ``collided``: and it collided.

    Raises:
        ValueError: A penalty or horizon out of range, or a logic without ``guard:`` reasons.
        TypeError: Not the single-car left turn (traffic has no counterfactual here).
    """

    def __init__(self, venv: VecEnv, penalty: float, horizon_s: float, switching: str) -> None:
        base = left_turn_beneath(venv, "a counterfactual penalty")
        if type(base.task) is not LeftTurnTask:
            raise TypeError("a counterfactual penalty needs the single-car left turn (no traffic)")
        if not (np.isfinite(penalty) and penalty < 0 and np.isfinite(horizon_s) and horizon_s > 0):
            raise ValueError(
                f"counterfactual penalty: penalty={penalty!r} (< 0), horizon_s={horizon_s!r} (> 0)"
            )
        reasons = base.task.reasons
        self.guard_reasons = np.array([r.startswith("guard:") for r in reasons])
        if not self.guard_reasons.any():
            raise ValueError(
                f"counterfactual penalty: the switching logic {base.config.switching!r} has no "
                "'guard:' reasons to roll a counterfactual from (use switching: guarded)"
            )
        super().__init__(venv)
        self.base, self.penalty = base, float(penalty)
        episode = dataclasses.replace(base.config.episode, end_on_reasons=())
        self.shadow = LeftTurnTask(
            dataclasses.replace(base.config, switching=switching, episode=episode)
        )
        self.ticks = max(1, round(horizon_s / episode.dt))
        self.rollouts = self.collisions = 0
        self.rolled = np.zeros(self.num_envs, dtype=bool)
        self.collided = np.zeros(self.num_envs, dtype=bool)
        #: Per environment: the guard intervened on its last step (of the same episode).
        self._guarding = np.zeros(self.num_envs, dtype=bool)
        self._before: TaskState | None = None
        self._actions = np.zeros(self.num_envs)
        base.count_reasons = True

    def reset(self) -> VecEnvObs:
        self._guarding[:] = False
        return self.venv.reset()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = learned_actions(actions, self.num_envs).copy()
        self._before = self.base.state.take(np.arange(self.num_envs))
        self.venv.step_async(actions)

    def step_wait(self) -> VecEnvStepReturn:
        observation, reward, done, infos = self.venv.step_wait()
        assert self._before is not None
        guarded = self.base.reason_ticks_in_step[:, self.guard_reasons].any(axis=1)
        self.rolled = guarded & ~self._guarding
        self.collided = np.zeros(self.num_envs, dtype=bool)
        fresh = np.flatnonzero(self.rolled)
        if fresh.size:
            self.collided[fresh] = self.collides(self._before.take(fresh), self._actions[fresh])
            self.rollouts += fresh.size
            self.collisions += int(self.collided.sum())
        self._guarding = guarded & ~done
        charge = np.where(self.collided, self.penalty, 0.0)
        return observation, (reward + charge).astype(np.float32), done, infos

    def collides(self, state: TaskState, action: np.ndarray) -> np.ndarray:
        """Per episode of ``state``: rolled forward under :attr:`shadow` with ``action`` held,
        does it collide within the horizon (before either car has left its conflict zone)?"""
        collided = np.zeros(state.batch_size, dtype=bool)
        live = np.ones(state.batch_size, dtype=bool)
        north_clear = self.shadow.conflict.zone_b[1]
        for _ in range(self.ticks):
            state, record = self.shadow.step(state, action, observe=False)
            collided |= record.collision & live
            passed = state.world.progress[:, 1] > north_clear  # the north car has left its zone
            live &= ~(record.terminated | record.truncated | record.ego_cleared | passed)
            if not live.any():
                break
        return collided


class CounterfactualLog(BaseCallback):
    """Logs the counterfactuals rolled and collided so far (``train/counterfactual_*``)."""

    def __init__(self, penalty: CounterfactualPenalty) -> None:
        super().__init__()
        self.penalty = penalty

    def _on_rollout_end(self) -> None:
        self.logger.record("train/counterfactual_rollouts", self.penalty.rollouts)
        self.logger.record("train/counterfactual_collisions", self.penalty.collisions)

    def _on_step(self) -> bool:
        return True
