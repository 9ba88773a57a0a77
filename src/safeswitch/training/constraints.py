"""Constrained PPO: Lagrange multipliers that move the learning-only costs to their budgets
(ours; the ``constraints`` section of a training configuration).

The targets a left-turn policy is held to are constraints, not one objective: no more than a
share of ticks over the comfort limits, no more than a share with the safety action, clear the
crossing within so many seconds on average — and, within those, the paper's reward. Fixed
penalty weights trade them against each other differently on every seed: in
``docs/learning_experiments.md`` each fixed charge that cured one seed's miss opened another
on the next. So each constraint ``c`` gets a multiplier ``λ_c`` (reward per unit of its cost)
that the run adjusts itself, after every rollout, from what the rollout measured against the
budget — the Lagrangian relaxation of constrained RL (Altman, *Constrained Markov Decision
Processes*, 1999; PPO-Lagrangian of Ray, Achiam & Amodei, *Benchmarking Safe Exploration in
Deep Reinforcement Learning*, 2019), with the proportional-integral multiplier update of Stooke,
Achiam & Abbeel (*Responsive Safety in Reinforcement Learning by PID Lagrangian Methods*,
ICML 2020), which damps the oscillation of the plain integral (gradient-ascent) update.

PPO learns from ``r − Σ_c λ_c · cost_c`` (added between the environment and
``VecNormalize``, like the other learning-only terms of :mod:`safeswitch.training.shaping`);
the environment's own reward, its returns, validation and evaluation stay the paper's.

The costs, counted per tick of each step (the learned controller holds its action for
``episode.decision_interval`` ticks), and what each constraint measures over the episodes that
ended since the last update (pooled until there are enough of them; see
:class:`ConstraintCosts`):

* ``comfort`` — the tick exceeded a comfort limit (the evaluation's comfort violation);
  measured as a share of the episodes' ticks.
* ``comfort_episodes`` — the episode's first tick over a comfort limit; measured as the share
  of episodes with one (the evaluation's ``comfort_violation_episodes``). A share of ticks
  hides a policy that breaks a limit for a few ticks in many episodes.
* ``speeding`` — the ego was faster than the tolerated speed on the tick (the highest speed at
  which ``R_v`` is at its best, 30 km/h by default: the evaluation's ``speeding_steps``); a
  share of ticks. ``R_v`` alone still pays +0.5 at 32.5 km/h, and a time constraint can buy
  its seconds there.
* ``safety`` — the episode's first tick on which the safety action was executed (with
  ``reasons``: one of those reasons' safety actions; under ``guarded`` the paper logic's own,
  which is what fires when the policy is deployed under ``paper``); measured as the share of
  episodes with a safety action, the unit of the target it stands for (``R_ADAS`` already
  charges every tick of one).
* ``overrule`` — under ``guarded``, the certified filter overruled the paper logic's own
  safety action on the tick (that braking was itself unsafe; deployed under ``paper`` alone,
  such episodes are the ones that collide: ``benchmarks/overrule_trace.py``); a share of ticks.
* ``clear_time`` — the tick ended with the ego not yet clear of its conflict zone; a collision
  (an episode that terminates) costs the rest of the horizon, so ending an episode never saves
  it. Measured as the mean over episodes [s]: the time to clear less one tick, or the whole
  horizon for an episode that never clears (as the evaluation's efficiency counts it).
* ``uncleared`` — the episode ended with the ego not clear of its conflict zone (charged on
  its last step); measured as the share of episodes.

After each rollout, for each constraint whose ``start`` has passed, with
``e = clip(measured / budget − 1, −1, 4)`` (the relative excess; episodes at more than five
times the budget count as five times, so one unlucky batch cannot throw the multiplier to its
maximum)::

    integral ← clip(integral + integral_gain · e, 0, max_multiplier)
    λ        ← clip(proportional_gain · e + integral, 0, max_multiplier)

A ``start`` later than 0 keeps a multiplier at its initial value while the exploration noise of
the first rollouts breaks the limits regardless of the policy's mean. The multipliers are part
of a run's checkpoints (``--resume`` continues with them) and of its ``metrics.json``; TensorBoard
logs ``constraints/<cost>`` (what was measured) and ``constraints/<cost>_multiplier``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from safeswitch.io import append_row
from safeswitch.training.config import ConstraintConfig, ConstraintsConfig
from safeswitch.training.shaping import left_turn_beneath

#: The relative excess of one rollout is clipped to ``[-1, MAX_EXCESS]``.
MAX_EXCESS = 4.0

#: The left turn's costs charged once per episode, on its first tick that has them: their
#: constraints count episodes.
EPISODE_COSTS = ("safety", "comfort_episodes")


@dataclass
class Multiplier:
    """One constraint's Lagrange multiplier with its proportional-integral update.

    Attributes:
        budget: What the constraint allows (in its measurement's unit), > 0.
        integral_gain: Added to the integral per rollout per unit of relative excess.
        proportional_gain: Multiplier per unit of the current rollout's relative excess.
        maximum: The multiplier's (and the integral's) upper bound.
        value: The multiplier ``λ`` now [reward per unit of the cost: a tick, or an episode
            for ``safety``, ``comfort_episodes`` and ``uncleared``].
        integral: The integral term now.
    """

    budget: float
    integral_gain: float
    proportional_gain: float
    maximum: float
    value: float = 0.0
    integral: float = 0.0

    @classmethod
    def from_config(cls, config: ConstraintConfig) -> Multiplier:
        return cls(
            budget=config.budget,
            integral_gain=config.integral_gain,
            proportional_gain=config.proportional_gain,
            maximum=config.max_multiplier,
            value=config.initial_multiplier,
            integral=config.initial_multiplier,
        )

    def excess(self, measured: float) -> float:
        """The relative excess over the budget, clipped to ``[-1, MAX_EXCESS]``."""
        return float(np.clip(measured / self.budget - 1.0, -1.0, MAX_EXCESS))

    def update(self, measured: float) -> float:
        """Move the multiplier after a rollout that measured ``measured``; returns it."""
        e = self.excess(measured)
        self.integral = float(np.clip(self.integral + self.integral_gain * e, 0, self.maximum))
        self.value = float(np.clip(self.proportional_gain * e + self.integral, 0, self.maximum))
        return self.value


class CostPool:
    """What every constrained environment shares: a multiplier per constraint, each cost
    summed over each environment's running episode, pooled over the episodes that end, and
    the multipliers moved from the pool after each rollout (:meth:`end_rollout`); a subclass
    computes the costs and says what the pool measured (:meth:`measured`)."""

    multipliers: dict[str, Multiplier]
    starts: dict[str, int]
    min_episodes: int

    def start_pool(
        self, constraints: Mapping[str, ConstraintConfig], num_envs: int, min_episodes: int | None
    ) -> None:
        """Multipliers at their initial values and an empty pool (``min_episodes``: ended
        episodes needed before the multipliers move; default half the environments)."""
        self.multipliers = {n: Multiplier.from_config(c) for n, c in constraints.items()}
        self.starts = {n: c.start for n, c in constraints.items()}
        self.min_episodes = max(1, num_envs // 2) if min_episodes is None else min_episodes
        #: Per environment, the running episode's cost sums and its length (in the costs'
        #: unit of time: ticks, or steps).
        self._episode = {name: np.zeros(num_envs) for name in self.multipliers}
        self._length = np.zeros(num_envs, dtype=np.int64)
        self._empty_pool()

    def _empty_pool(self) -> None:
        self._pooled = dict.fromkeys(self.multipliers, 0.0)
        self._pooled_length = 0
        self._pooled_episodes = 0

    def clear_episodes(self) -> None:
        """Forget the running episodes (at a reset)."""
        for sums in self._episode.values():
            sums[:] = 0.0
        self._length[:] = 0

    def charge(
        self,
        costs: Mapping[str, NDArray[np.float64]],
        length: NDArray[np.int64] | int,
        done: NDArray[np.bool_],
        counted: NDArray[np.bool_] | None = None,
    ) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
        """Add one step's ``costs`` and ``length`` to the running episodes and pool the ones
        ``done`` ends (those ``counted``, if given); returns the step's penalty
        ``Σ λ_c · cost_c`` ``[B]`` and the indices of the ended episodes."""
        penalty = np.zeros(len(done))
        for name, cost in costs.items():
            penalty += self.multipliers[name].value * cost
            self._episode[name] += cost
        self._length += length
        ended = np.flatnonzero(done)
        pooled = ended if counted is None else ended[counted[ended]]
        for name, sums in self._episode.items():
            self._pooled[name] += float(sums[pooled].sum())
            sums[ended] = 0.0
        self._pooled_length += int(self._length[pooled].sum())
        self._pooled_episodes += len(pooled)
        self._length[ended] = 0
        return penalty, ended

    def pooled_means(self) -> dict[str, float] | None:
        """Each pooled cost per unit of pooled length; ``None`` while fewer than
        ``min_episodes`` episodes have ended."""
        if self._pooled_episodes < self.min_episodes:
            return None
        length = max(self._pooled_length, 1)
        return {name: total / length for name, total in self._pooled.items()}

    def measured(self) -> dict[str, float] | None:
        """What the pool measured per constraint, in its budget's unit."""
        raise NotImplementedError

    def end_rollout(self, timesteps: int) -> dict[str, float] | None:
        """The pooled episodes' measurements, if there are enough of them (then a new pool
        starts); the multipliers whose ``start`` is past at ``timesteps`` move."""
        measured = self.measured()
        if measured is None:
            return None
        for name, value in measured.items():
            if timesteps >= self.starts[name]:
                self.multipliers[name].update(value)
        self._empty_pool()
        return measured

    def state(self) -> dict[str, dict[str, float]]:
        """The multipliers' state, for a checkpoint."""
        return {n: {"value": m.value, "integral": m.integral} for n, m in self.multipliers.items()}

    def restore(self, state: dict[str, dict[str, float]]) -> None:
        """The multipliers as a checkpoint left them."""
        for name, saved in state.items():
            self.multipliers[name].value = float(saved["value"])
            self.multipliers[name].integral = float(saved["integral"])


class ConstraintCosts(CostPool, VecEnvWrapper):
    """Charges each configured constraint's cost at its multiplier in the reward PPO learns
    from, and measures each over the episodes that end (see the module docstring).

    Each constraint is measured over whole episodes — the left turn's episodes all last the
    horizon, and a rollout shorter than an episode holds only part of each, so a per-rollout
    share of ticks would swing with the part it holds. The episodes that ended since the last
    update are pooled until there are at least ``min_episodes`` of them. An environment's first
    episode is left out when the environment staggers its starts (that episode is cut short
    on purpose).

    Args:
        venv: The batched left-turn environment (or a wrapper of it).
        config: The configuration's ``constraints`` section.
        min_episodes: Ended episodes needed before the multipliers move (default: half the
            environments, at least 1).

    Raises:
        ValueError: ``safety.reasons`` names a reason the switching logic does not have (the
            message lists its reasons).
    """

    def __init__(
        self, venv: VecEnv, config: ConstraintsConfig, min_episodes: int | None = None
    ) -> None:
        base = left_turn_beneath(venv, "constraints")
        super().__init__(venv)
        self.base, self.config = base, config
        self.start_pool(config.active(), self.num_envs, min_episodes)
        known = base.task.reasons
        #: Per reason-counted cost, the reason codes it counts (``safety`` without reasons
        #: counts every safety action instead).
        self._reasons: dict[str, NDArray[np.intp]] = {}
        for name in ("safety", "overrule"):
            given = getattr(config, name)
            if given is None:
                continue
            reasons = given.reasons
            if name == "overrule" and not reasons:
                reasons = tuple(r for r in known if r.endswith(":overrules_primary"))
                if not reasons:
                    raise ValueError(
                        f"constraints.overrule: the switching logic {base.config.switching!r} "
                        "has no ':overrules_primary' reasons (use switching: guarded)"
                    )
            unknown = sorted(set(reasons) - set(known))
            if unknown:
                raise ValueError(
                    f"constraints.{name}.reasons: {unknown} not reasons of the switching logic "
                    f"{base.config.switching!r} (its reasons: {', '.join(known)})"
                )
            if reasons:
                self._reasons[name] = np.array([known.index(r) for r in reasons])
                base.count_reasons = True
        base.count_costs = True
        episode = base.config.episode
        self.dt = episode.dt
        self.horizon_ticks = round(episode.horizon_s / episode.dt)
        n = self.num_envs
        self._cleared = np.zeros(n, dtype=bool)
        #: Per cost counted in episodes, whether the running episode has already paid it.
        self._seen = {
            name: np.zeros(n, dtype=bool) for name in EPISODE_COSTS if name in self.multipliers
        }
        self._counted = np.ones(n, dtype=bool)

    def reset(self) -> VecEnvObs:
        observation = self.venv.reset()
        self.clear_episodes()
        self._cleared[:] = False
        for seen in self._seen.values():
            seen[:] = False
        self._counted[:] = not self.base.stagger
        return observation

    def step_wait(self) -> VecEnvStepReturn:
        observation, reward, done, infos = self.venv.step_wait()
        costs = self.costs_of_step(done)
        penalty, ended = self.charge(costs, self.base.costs_in_step.ticks, done, self._counted)
        self._cleared[ended] = False
        for seen in self._seen.values():
            seen[ended] = False
        self._counted[ended] = True
        return observation, (reward - penalty).astype(np.float32), done, infos

    def costs_of_step(self, done: NDArray[np.bool_]) -> dict[str, NDArray[np.float64]]:
        """Per constraint, its cost in the last step per environment ``[B]`` (ticks; for
        :data:`EPISODE_COSTS` and ``uncleared`` episodes); ``done``: the episodes that step
        ended."""
        counts = self.base.costs_in_step
        record = self.base.last_record
        assert record is not None
        out: dict[str, NDArray[np.float64]] = {}
        if "uncleared" in self.multipliers:
            out["uncleared"] = (done & ~record.ego_cleared).astype(np.float64)
        if "comfort" in self.multipliers:
            out["comfort"] = counts.comfort.astype(np.float64)
        if "comfort_episodes" in self.multipliers:
            out["comfort_episodes"] = counts.comfort.astype(np.float64)
        if "speeding" in self.multipliers:
            out["speeding"] = counts.speeding.astype(np.float64)
        if "safety" in self.multipliers and "safety" not in self._reasons:
            out["safety"] = counts.safety.astype(np.float64)
        for name, codes in self._reasons.items():
            out[name] = self.base.reason_ticks_in_step[:, codes].sum(axis=1).astype(np.float64)
        for name, seen in self._seen.items():  # an episode's first such tick is its cost
            acted = out[name] > 0
            out[name] = (acted & ~seen).astype(np.float64)
            seen |= acted
        if "clear_time" in self.multipliers:
            self._cleared |= record.ego_cleared
            rest = np.maximum(self.horizon_ticks - self._length - counts.ticks, 0)
            charged = counts.uncleared + np.where(record.terminated & ~self._cleared, rest, 0)
            out["clear_time"] = charged.astype(np.float64)
        return out

    def measured(self) -> dict[str, float] | None:
        """What the pooled episodes measured per constraint, in its budget's unit (a share of
        ticks; for :data:`EPISODE_COSTS` and ``uncleared`` a share of episodes; for
        ``clear_time`` the mean time to clear [s]); ``None`` while fewer than ``min_episodes``
        have ended."""
        out = self.pooled_means()  # per tick
        if out is None:
            return None
        episodes = self._pooled_episodes
        for name in (*EPISODE_COSTS, "uncleared"):
            if name in out:
                out[name] = self._pooled[name] / episodes
        if "clear_time" in out:
            out["clear_time"] = self._pooled["clear_time"] * self.dt / episodes
        return out


#: The costs every switched plant has, from the switch itself (see
#: :class:`NamedCostConstraints`).
SWITCH_COSTS = ("intervention", "safety")


class NamedCostConstraints(CostPool, VecEnvWrapper):
    """Constrained PPO on any plant (the generic pipeline's ``constraints``): each constraint
    is a cost the plant publishes by name in ``info["costs"]`` (a mapping such as
    ``{"speeding": 1.0, "comfort": 0.0}`` per step), measured as its mean per step over the
    episodes that end. Two are the switch's own: ``intervention``, its per-step
    ``info["cost"]`` (1 on a step the safety action ran), a share of steps; and ``safety``, an
    episode with a safety action (``info["safety_active"]``), a share of episodes, as the left
    turn's. PPO learns
    from ``r − Σ_c λ_c · cost_c``; the multipliers move as :class:`Multiplier` says, after every
    rollout with at least ``min_episodes`` ended episodes pooled.

    Raises:
        ValueError: On the first step, a configured cost the plant does not publish (naming
            the costs it does).
    """

    def __init__(
        self,
        venv: VecEnv,
        constraints: Mapping[str, ConstraintConfig],
        min_episodes: int | None = None,
    ) -> None:
        super().__init__(venv)
        self.start_pool(constraints, self.num_envs, min_episodes)
        self._safety_seen = np.zeros(self.num_envs, dtype=bool)
        self._checked = False

    def reset(self) -> VecEnvObs:
        observation = self.venv.reset()
        self.clear_episodes()
        self._safety_seen[:] = False
        return observation

    def step_async(self, actions: NDArray[Any]) -> None:
        self.venv.step_async(actions)

    def step_wait(self) -> VecEnvStepReturn:
        observation, reward, done, infos = self.venv.step_wait()
        penalty, ended = self.charge(self._costs(infos), 1, done)
        self._safety_seen[ended] = False
        return observation, (reward - penalty).astype(np.float32), done, infos

    def _costs(self, infos: Sequence[Mapping[str, Any]]) -> dict[str, NDArray[np.float64]]:
        out = {name: np.zeros(self.num_envs) for name in self.multipliers}
        for i, info in enumerate(infos):
            published = info.get("costs", {})
            if not self._checked:
                missing = sorted(set(self.multipliers) - set(SWITCH_COSTS) - set(published))
                if missing:
                    raise ValueError(
                        f"constraints: the plant publishes no cost {missing[0]!r} in "
                        f"info['costs'] (it publishes: {', '.join(sorted(published)) or 'none'})"
                    )
                self._checked = True
            for name in out:
                if name == "intervention":
                    out[name][i] = float(info.get("cost", 0.0))
                elif name != "safety":
                    out[name][i] = float(published[name])
        if "safety" in out:  # an episode's first safety action is its cost: it counts episodes
            acted = np.array([bool(info.get("safety_active", False)) for info in infos])
            out["safety"] = (acted & ~self._safety_seen).astype(np.float64)
            self._safety_seen |= acted
        return out

    def measured(self) -> dict[str, float] | None:
        """What the pooled episodes measured: a mean per step; ``safety`` a share of
        episodes."""
        measured = self.pooled_means()
        if measured is not None and "safety" in measured:
            measured["safety"] = self._pooled["safety"] / self._pooled_episodes
        return measured


#: The run's log of the constraints' measurements and multipliers.
CONSTRAINTS_LOG = "constraints.csv"


class ConstraintUpdate(BaseCallback):
    """Moves the multipliers after every rollout (each from its ``start`` on) and logs
    ``constraints/<name>`` (what the pooled episodes measured) and
    ``constraints/<name>_multiplier`` to TensorBoard and, with ``log``, a row of both per
    update to that CSV file (``timesteps``, then ``<name>`` and ``<name>_multiplier`` per
    constraint: the run's ``constraints.csv``)."""

    def __init__(self, costs: ConstraintCosts | NamedCostConstraints, log: Path | None = None):
        super().__init__()
        self.costs = costs
        self.log = log
        names = sorted(costs.multipliers)
        self.fields = ("timesteps", *(f for n in names for f in (n, f"{n}_multiplier")))

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        measured = self.costs.end_rollout(self.num_timesteps)
        if measured is None:
            return
        row: dict[str, float] = {"timesteps": self.num_timesteps}
        for name, value in measured.items():
            multiplier = self.costs.multipliers[name].value
            self.logger.record(f"constraints/{name}", value)
            self.logger.record(f"constraints/{name}_multiplier", multiplier)
            row |= {name: value, f"{name}_multiplier": multiplier}
        if self.log is not None:
            append_row(self.log, self.fields, row)
