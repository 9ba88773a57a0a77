"""Model selection on a validation set: which policy of a run is the run's policy.

Every ``validation.every`` timesteps the deterministic policy (the Gaussian's mean, as it is
evaluated and deployed) drives the validation scenarios — random scenarios drawn with their own
seed, never trained on and never in the final evaluation, under the logic it is deployed under
(``deploy_switching``, by default the one it trains with) or ``validation.switching`` — and
its mean return there is its score (the paper's criterion for learned model validation;
``validation.criterion`` can put the fewest collisions, or the constraints, first). The
best policy so far is saved whole into ``best/`` of the run directory (model and observation
statistics, written into a temporary folder and renamed); each validation is a row of
``validation.csv`` with the evaluation's summary fields. At the end of the run the best policy
becomes the run's ``model.zip`` and the last one is kept in ``last/``.

With ``validation.families`` set (in traffic), a policy that would become the best is also
driven on as many scenes of each of those traffic families, and each limit of
``constraints_then_return`` (comfort, speeding, safety) counts at the worst of the validation
set and the families (``family_safety_episodes`` and ``worst_family`` in ``validation.csv``;
blank where it was not driven there). ``validation.scenes`` does the same in the paper's scene
with named scenario distributions.

With ``validation.stress`` set, a policy that would become the best is also driven on a
second, narrower set of scenarios where rare collisions concentrate, and its collisions there
count with the validation set's (``stress_collisions`` in ``validation.csv``; blank where it
was not driven there: its rank could only have fallen). It is driven in chunks and stopped as
soon as its collisions there rule it out, so a rejected policy's count is the collisions found
until then (at least that many).

With ``validation.average`` set, the callback also keeps a moving average of the policy's
weights over PPO's updates (one step at the end of every rollout, before the next update) and
drives it at every validation after the current policy; either can become the best (the row's
``averaged`` column says which was driven). The average is written into every checkpoint and
read back on ``--resume``.

The oracle's plan of the validation scenarios is made once (the other vehicles never react to
the ego's policy in the paper's scene; in traffic the oracle plans against the others' world
without the ego), so a validation costs one batched rollout.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback

from safeswitch.evaluation.evaluate import run_controller, summary_against_oracle
from safeswitch.evaluation.oracle import OraclePlan
from safeswitch.evaluation.rollout import rollout
from safeswitch.io import POLICY_FILES, append_row, copy_policy_files, write_snapshot
from safeswitch.leftturn.config import ScenarioConfig, observed_as, traffic_config
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.training.config import TrainConfig
from safeswitch.training.policies import TrainedPolicy

#: Scenarios of the stress set driven at once (a candidate that collides there is rejected
#: after the first chunk with enough collisions, not after the whole set).
STRESS_CHUNK = 5000

#: The file of a checkpoint holding the moving average of the policy's weights.
AVERAGE_FILE = "average.pt"

#: Columns of ``validation.csv``: when, the score, then the evaluation's summary fields.
VALIDATION_FIELDS = (
    "timesteps",
    "mean_return",
    "collisions",
    "safety_activation_episodes",
    "comfort_violation_fraction",
    "stops",
    "cut_episodes",
    "cleared_episodes",
    "mean_efficiency",
    "safety_activation_steps",
    "clear_time_s",
    "speeding_episodes",
    "stress_collisions",
    "family_safety_episodes",
    "worst_family",
    "best",
)


def best_so_far(run: Path) -> dict[str, Any]:
    """The score of the run's best validated policy so far and when it was reached
    (``best/state.json``; ``None`` values before the first validation)."""
    saved = run / "best" / "state.json"
    if not saved.is_file():
        return {"best_return": None, "best_timesteps": None}
    state: dict[str, Any] = json.loads(saved.read_text(encoding="utf-8"))
    return state


class BestPolicy(BaseCallback):
    """Validates the policy after the rollouts that reach each ``validation.every`` timesteps
    and keeps the best (see the module docstring): what every plant shares. A plant's
    validator says how a policy is validated (:meth:`validate`: a summary with at least
    ``mean_return``), how summaries rank (:meth:`key`, maximised) and which columns
    ``validation.csv`` has (:attr:`fields`).

    Args:
        config: The run's configuration (its ``validation`` section set).
        run: The run directory (a resumed run's ``best/`` is the best so far).
    """

    #: Columns of ``validation.csv``.
    fields: tuple[str, ...] = ("timesteps", "mean_return", "best")

    def __init__(self, config: Any, run: Path) -> None:
        super().__init__()
        self.config, self.run = config, run
        #: The best score and when it was reached (``None``: no validation yet).
        self.state: dict[str, Any] = best_so_far(run)
        self._next = 0
        #: The TensorBoard section :meth:`record` writes the validation's scalars into.
        self.scalars = "validation"
        #: The moving average of the policy's weights (``validation.average``), by name.
        self.average: dict[str, torch.Tensor] | None = None

    def validate(self) -> dict[str, Any]:
        """The current deterministic policy's summary on the validation set."""
        raise NotImplementedError

    def key(self, summary: dict[str, Any]) -> tuple[float, ...]:
        """What ``validation.criterion`` maximises, from a validation's summary."""
        raise NotImplementedError

    def refine(self, summary: dict[str, Any], best: list[float] | None) -> None:
        """More measures of a policy about to become the best (in place); none here."""

    def record(self, summary: dict[str, Any]) -> dict[str, Any]:
        """Further columns of the validation's row, and its TensorBoard scalars."""
        self.logger.record(f"{self.scalars}/return", float(summary["mean_return"]))
        return {}

    def _on_training_start(self) -> None:
        v = self.config.validation
        self._next = max((self.num_timesteps // v.every + 1) * v.every, v.start)

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        decay = self.config.validation.average
        if decay:
            self._update_average(decay)
        if self.num_timesteps < self._next:
            return
        every = self.config.validation.every
        self._next = (self.num_timesteps // every + 1) * every
        self._validate_candidate(averaged=False)
        if decay:
            with self.averaged_weights():
                self._validate_candidate(averaged=True)

    def _update_average(self, decay: float) -> None:
        """One step of the weights' moving average (:attr:`average`; its first value is the
        policy's weights at the first update it sees)."""
        weights = self.model.policy.state_dict()
        if self.average is None:
            self.average = copied(weights, floating_only=True)
            return
        with torch.no_grad():
            for name, value in self.average.items():
                value.mul_(decay).add_(weights[name], alpha=1.0 - decay)

    @contextlib.contextmanager
    def averaged_weights(self) -> Iterator[None]:
        """The model's policy holds the averaged weights inside the block (copied into its
        parameters, so the optimiser's references stay valid) and its own after it."""
        assert self.average is not None
        policy = self.model.policy
        own = copied(policy.state_dict())
        policy.load_state_dict(self.average, strict=False)
        try:
            yield
        finally:
            policy.load_state_dict(own)

    def save_average(self, folder: Path) -> None:
        """Write the weights' average into a checkpoint being written (``folder``; nothing
        before the first update or without ``validation.average``)."""
        if self.average is not None:
            torch.save(self.average, folder / AVERAGE_FILE)

    def resume(self, checkpoint: dict[str, Any]) -> None:
        """Continue the weights' average from the checkpoint resumed from (if it holds one)."""
        path = Path(checkpoint["path"]) / AVERAGE_FILE
        if self.config.validation.average and path.is_file():
            self.average = torch.load(path, weights_only=True)

    def _validate_candidate(self, averaged: bool) -> None:
        """Validate the policy the model holds now and keep it if it is the best so far
        (``averaged``: it is the weights' average; a column of ``validation.csv`` and the
        TensorBoard scalars' section ``validation_average`` when ``validation.average`` is
        on)."""
        self.scalars = "validation_average" if averaged else "validation"
        summary = self.validate()
        score = float(summary["mean_return"])
        key = self.key(summary)
        best = self.state.get("best_key")
        if best is None and self.state["best_return"] is not None:  # a run from before keys
            best = self._old_key(self.state)
        better = best is None or tuple(key) > tuple(best)
        if better:
            self.refine(summary, best)
            key = self.key(summary)
            better = best is None or tuple(key) > tuple(best)
        if better:
            self.state = {
                "best_return": score,
                "best_collisions": int(summary.get("collisions", summary.get("failures", 0))),
                "best_timesteps": int(self.num_timesteps),
                "best_key": list(key),
                **({"best_averaged": True} if averaged else {}),
                **(
                    {"best_stress_collisions": int(summary["stress_collisions"])}
                    if "stress_collisions" in summary
                    else {}
                ),
            }
            self._save_best()
        row = {"timesteps": self.num_timesteps, **summary, **self.record(summary),
               "best": int(better)}  # fmt: skip
        fields = tuple(self.fields)
        if self.config.validation.average:
            row["averaged"] = int(averaged)
            fields += ("averaged",)
        path = self.run / "validation.csv"
        if path.exists():  # a resumed run keeps its file's columns (an older version's too)
            with open(path, newline="", encoding="utf-8") as handle:
                fields = tuple(next(csv.reader(handle), fields))
        append_row(path, fields, row)

    def _old_key(self, state: dict[str, Any]) -> list[float] | None:
        """The key of the best policy a run resumed from before keys recorded (its return and
        collisions); ``None`` under ``constraints_then_return``, which that state cannot rank:
        the next validation then becomes the best."""
        criterion = self.config.validation.criterion
        if criterion == "return":
            return [float(state["best_return"])]
        if criterion == "collisions_then_return":
            return [-float(state.get("best_collisions", 0)), float(state["best_return"])]
        return None

    def _policy(self) -> TrainedPolicy:
        env = self.model.get_env()
        normalizer = env if self.config.ppo.normalize_observations else None
        return TrainedPolicy(self.model, normalizer, self.config, self.run)  # type: ignore[arg-type]

    def _save_best(self) -> None:
        write_snapshot(self.run / "best", self.model, self.model.get_env(), self.state)


def copied(
    weights: dict[str, torch.Tensor], floating_only: bool = False
) -> dict[str, torch.Tensor]:
    """A copy of a module's ``state_dict`` that later updates leave alone (with
    ``floating_only``, its floating-point tensors alone: what an average can hold)."""
    return {name: value.detach().clone() for name, value in weights.items()
            if value.is_floating_point() or not floating_only}  # fmt: skip


class Validator(BestPolicy):
    """The left turn's validator: random scenarios under the deployment logic, the oracle's
    efficiency, and optionally the stress set (see the module docstring)."""

    fields = VALIDATION_FIELDS

    def __init__(self, config: TrainConfig, run: Path) -> None:
        super().__init__(config, run)
        v = config.validation
        self.validation_set = ValidationSet(config)
        #: Where a candidate must keep its limits too, by name: the traffic families
        #: (``validation.families``) or the paper scene's distributions (``validation.scenes``).
        self.families = {name: ValidationSet(config, family=name) for name in v.families}
        self.families |= {
            name: ValidationSet(config, scenarios=scene) for name, scene in v.scenes.items()
        }
        env = self.task.config
        self.stress_task, self.stress_scenarios = None, None
        if v.stress is not None:
            stress = v.stress
            self.stress_task = build_task(
                None, dataclasses.replace(env, scenarios=stress.scenarios)
            )
            self.stress_scenarios = self.stress_task.scenario_set(stress.seed, stress.episodes)

    @property
    def task(self) -> LeftTurnTask:
        """The validation's task (its logic and horizon)."""
        return self.validation_set.task

    @property
    def scenarios(self) -> Scenarios:
        """The validation scenarios."""
        return self.validation_set.scenarios

    def refine(self, summary: dict[str, Any], best: list[float] | None) -> None:
        if self.families:
            policy = self._policy()
            summary["families"] = {n: f.summary(policy) for n, f in self.families.items()}
            worst = max(summary["families"].items(),
                        key=lambda item: item[1]["safety_activation_episodes"])  # fmt: skip
            summary["worst_family"] = worst[0]
            summary["family_safety_episodes"] = worst[1]["safety_activation_episodes"]
            if best is not None and tuple(self.key(summary)) <= tuple(best):
                return  # ruled out in a family: the stress set cannot raise it again
        if self.stress_task is None:
            return

        def still_better(collisions: int) -> bool:
            key = self.key({**summary, "stress_collisions": collisions})
            return best is None or tuple(key) > tuple(best)

        summary["stress_collisions"] = self.stress_collisions(still_better)

    def record(self, summary: dict[str, Any]) -> dict[str, Any]:
        super().record(summary)
        self.logger.record(f"{self.scalars}/efficiency", summary.get("mean_efficiency", np.nan))
        self.logger.record(f"{self.scalars}/safety_activation_episodes",
                           summary["safety_activation_episodes"])  # fmt: skip
        if "stress_collisions" in summary:
            self.logger.record(f"{self.scalars}/stress_collisions", summary["stress_collisions"])
        if "family_safety_episodes" in summary:
            self.logger.record(f"{self.scalars}/family_safety_episodes",
                               summary["family_safety_episodes"])  # fmt: skip
        horizon = self.task.config.episode.horizon_s
        return {"clear_time_s": constraint_measures(summary, horizon)["clear_time"]}

    def key(self, summary: dict[str, Any]) -> tuple[float, ...]:
        """What ``validation.criterion`` maximises, from a validation's summary (its
        collisions include the stress set's, where it was driven there)."""
        criterion = self.config.validation.criterion
        mean_return = float(summary["mean_return"])
        collisions = float(summary["collisions"]) + float(summary.get("stress_collisions", 0))
        if criterion == "collisions_then_return":
            return (-collisions, mean_return)
        if criterion == "constraints_then_return":
            horizon = self.task.config.episode.horizon_s
            return (-collisions, *constraint_key(self.config, summary, horizon))
        return (mean_return,)

    def stress_collisions(self, still_better: Callable[[int], bool] | None = None) -> int:
        """The current deterministic policy's collisions on the stress set, driven in chunks
        of :data:`STRESS_CHUNK` scenarios; once ``still_better(collisions so far)`` is false
        the rest is not driven (the policy cannot become the best any more) and the count is
        the collisions found until then."""
        assert self.stress_task is not None and self.stress_scenarios is not None
        policy = self._policy().as_policy()
        total, episodes = 0, len(self.stress_scenarios.arrival_offset)
        for start in range(0, episodes, STRESS_CHUNK):
            chunk = self.stress_scenarios.take(
                np.arange(start, min(start + STRESS_CHUNK, episodes))
            )
            total += int(np.count_nonzero(rollout(self.stress_task, chunk, policy).collision))
            if still_better is not None and not still_better(total):
                break
        return total

    def validate(self) -> dict[str, Any]:
        """The current deterministic policy's summary on the validation scenarios."""
        return self.validation_set.summary(self._policy())


class ValidationSet:
    """A run's validation scenarios (``validation.episodes`` drawn with ``validation.seed``)
    under the deployment logic (or ``validation.switching``), and the oracle's plan of them
    (made at the first summary, kept for the next).

    Args:
        config: The run's configuration.
        family: A traffic preset to draw the scenes from instead of the run's traffic (what
            the policy observes stays the run's, as ``safeswitch evaluate --traffic``).
        scenarios: The paper scene's distribution to draw the scenarios from instead of the
            deployment's (``validation.scenes``).
    """

    def __init__(
        self,
        config: TrainConfig,
        family: str | None = None,
        scenarios: ScenarioConfig | None = None,
    ) -> None:
        v = config.validation
        env = config.deployed_env
        if v.switching is not None:
            env = dataclasses.replace(env, switching=v.switching)
        if scenarios is not None:
            env = dataclasses.replace(env, scenarios=scenarios)
        traffic = config.traffic_settings
        if family is not None:
            assert traffic is not None  # TrainConfig refuses families without traffic
            scene = traffic_config(family)
            assert scene is not None
            traffic = observed_as(scene, traffic)
        self.task: LeftTurnTask = build_task(None, env, traffic=traffic)
        self.scenarios = self.task.scenario_set(v.seed, v.episodes)
        self._plan: OraclePlan | None = None

    def summary(self, policy: TrainedPolicy) -> dict[str, Any]:
        """``policy``'s deterministic summary on the validation scenarios."""
        result, self._plan = run_controller(
            self.task, policy.as_policy(), self.scenarios, plan=self._plan, trace=False
        )
        return summary_against_oracle(result, self._plan, self.task.config.episode.horizon_s)


def constraint_measures(summary: dict[str, Any], horizon_s: float) -> dict[str, float]:
    """What each constraint of :mod:`safeswitch.training.constraints` measures, from an
    evaluation's summary (the deterministic policy's): the share of ticks over a comfort limit,
    the share of episodes with such a tick, the share of ticks faster than the tolerated speed,
    the share of episodes with a safety action (any reason: validation runs under one logic),
    the mean time to clear [s] with an episode that never clears counted at the horizon, and
    the share of episodes that never clear."""
    ticks = max(float(summary["ticks"]), 1.0)
    episodes = max(float(summary["episodes"]), 1.0)
    cleared = float(summary["cleared_episodes"])
    cleared_time = float(summary["mean_time_to_clear_s"]) if cleared else 0.0
    return {
        "comfort": float(summary["comfort_violation_steps"]) / ticks,
        "comfort_episodes": float(summary["comfort_violation_episodes"]) / episodes,
        "speeding": float(summary["speeding_steps"]) / ticks,
        "safety": float(summary["safety_activation_episodes"]) / episodes,
        "clear_time": (cleared * cleared_time + (episodes - cleared) * horizon_s) / episodes,
        "uncleared": (episodes - cleared) / episodes,
    }


def constraint_key(
    config: TrainConfig, summary: dict[str, Any], horizon_s: float
) -> tuple[float, float, float]:
    """``constraints_then_return``'s order, to maximise: the safety constraints first (minus
    the summed excess ``max(0, measured / budget − 1)`` of ``comfort``, ``comfort_episodes``,
    ``speeding`` and ``safety``, each against its ``validation_budget``, by default its
    training budget, and each at the worst of the summary and its ``families``), then the
    task's (the summed excess of ``clear_time`` and ``uncleared``), then the mean return — the
    constrained problem's priorities: a policy that keeps its limits before a faster one, a
    faster one (until it is fast enough) before a better-rewarded one."""
    excess = constraint_excess(config, summary, horizon_s)
    safe = sum(excess.get(name, 0.0) for name in SAFETY_CONSTRAINTS)
    task = excess.get("clear_time", 0.0) + excess.get("uncleared", 0.0)
    return (-safe, -task, float(summary["mean_return"]))


#: The constraints a policy keeps before it is fast (``constraints_then_return``'s first term).
SAFETY_CONSTRAINTS = ("comfort", "comfort_episodes", "speeding", "safety")


def constraint_excess(
    config: TrainConfig, summary: dict[str, Any], horizon_s: float
) -> dict[str, float]:
    """Each active constraint's excess over its selection budget, ``max(0, measured / budget
    − 1)``, by name (those :func:`constraint_measures` measures)."""
    measured = constraint_measures(summary, horizon_s)
    for family in summary.get("families", {}).values():  # a limit counts where it is worst
        theirs = constraint_measures(family, horizon_s)
        for name in SAFETY_CONSTRAINTS:
            measured[name] = max(measured[name], theirs[name])
    return {  # ``overrule`` has no measure outside ``guarded``: collisions come first anyway
        name: max(0.0, measured[name] / c.selection_budget - 1.0)
        for name, c in config.constraints.active().items()
        if name in measured
    }


def select_best(run: Path) -> None:
    """Make the validated best policy of ``run`` the run's policy: the last one moves to
    ``last/``, ``best/``'s model and statistics take its place (each file renamed whole)."""
    last = run / "last"
    last.mkdir(exist_ok=True)
    for name in POLICY_FILES:
        os.replace(run / name, last / name)
    copy_policy_files(run / "best", run)
