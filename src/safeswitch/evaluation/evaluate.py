"""Evaluation building blocks: scenario sets, the rule-based baselines and the oracle, one
episode per scenario, summaries against the oracle and the per-episode CSV.

``safeswitch evaluate`` (:mod:`safeswitch.app.evaluate`) puts them together with trained
policies.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Callable
from dataclasses import fields, replace
from typing import Any

import numpy as np

from safeswitch.evaluation.metrics import summarize
from safeswitch.evaluation.oracle import Oracle, OraclePlan, efficiency
from safeswitch.evaluation.planner import Planner
from safeswitch.evaluation.rollout import Policy, RolloutResult, rollout
from safeswitch.leftturn.config import SCENARIO_NAMES, LearnedScope, LeftTurnConfig
from safeswitch.leftturn.scenarios import Scenarios, named_scenarios
from safeswitch.leftturn.task import OUTCOMES, LeftTurnTask, StepRecord, TaskState
from safeswitch.sim.geometry import FloatArray

#: The rule-based controllers and the oracle (``safeswitch evaluate --controller``).
BASELINES: tuple[str, ...] = ("rule", "planner", "oracle")


def _rule_policy(obs: Any, state: Any, tick: int) -> Any:
    return np.zeros(obs.shape[0])  # ignored: learned_scope="never" lets PID_th drive


def scenario_set(
    task: LeftTurnTask, which: str, episodes: int, seed: int
) -> tuple[Scenarios, list[str]]:
    """The paper's three scenarios, or ``episodes`` random ones drawn with ``seed``."""
    if which == "paper":
        parts = [named_scenarios(name, 1) for name in SCENARIO_NAMES]
        merged = Scenarios(
            *(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Scenarios))
        )
        return merged, list(SCENARIO_NAMES)
    if which != "random":
        raise ValueError(f"--scenarios must be 'paper' or 'random', got {which!r}")
    if episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {episodes}")
    scenarios = task.draw_scenarios(seed, np.arange(episodes), np.zeros(episodes, dtype=int))
    return scenarios, [f"random-{i}" for i in range(episodes)]


def baseline_setup(
    controller: str, switching: str | None = None
) -> tuple[LeftTurnConfig, Policy | None]:
    """The task configuration and policy of a rule-based controller: ``rule`` (``PID_th``
    proposes throughout), ``planner`` (drives with the learned controller's throttle
    throughout) or ``oracle`` (plans instead of acting: the policy is ``None``), under the
    ``paper`` logic unless ``switching`` names another."""
    if controller not in BASELINES:
        raise ValueError(f"controller {controller!r} is not one of {', '.join(BASELINES)}")
    scope: LearnedScope = "episode" if controller == "planner" else "never"
    env_config = replace(LeftTurnConfig(), switching=switching or "paper")
    env_config = replace(env_config, episode=replace(env_config.episode, learned_scope=scope))
    policy: Policy | None = None
    if controller == "planner":
        policy = Planner(LeftTurnTask(env_config))
    elif controller == "rule":
        policy = _rule_policy
    return replace(env_config, scenario=None), policy


def run_controller(
    task: LeftTurnTask,
    policy: Policy | None,
    batch: Scenarios,
    on_tick: Callable[[TaskState, StepRecord, int], None] | None = None,
    plan: OraclePlan | None = None,
) -> tuple[RolloutResult, OraclePlan]:
    """One episode per scenario (the oracle's plan when ``policy`` is None), and the oracle's
    plan of the same scenarios (``plan``, if already made for this road and these scenarios)."""
    if plan is None or policy is None:
        oracle = Oracle(task)
        plan = plan or oracle.plan(batch)
        if policy is None:
            return oracle.as_rollout(plan), plan
    return rollout(task, batch, policy, on_tick), plan


def summary_against_oracle(
    result: RolloutResult, plan: OraclePlan, horizon_s: float
) -> dict[str, Any]:
    """:func:`~safeswitch.evaluation.metrics.summarize` plus the oracle's mean time to clear
    and ``mean_efficiency``: the mean over scenarios of the oracle's time to clear divided by
    the controller's (see :func:`~safeswitch.evaluation.oracle.efficiency`)."""
    ratio = efficiency(plan.time_to_clear, result.time_to_clear, horizon_s)
    return {
        **summarize(result),
        "mean_oracle_time_to_clear_s": float(np.nanmean(plan.time_to_clear)),
        "mean_efficiency": float(np.nanmean(ratio)),
    }


def episodes_csv(
    names: list[str], scenarios: Scenarios, result: RolloutResult, oracle_time: FloatArray
) -> str:
    """One row per episode: the scenario, what happened, and the oracle's time to clear."""
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(
        [
            "episode",
            "ego_start_distance_m",
            "ego_speed_kmh",
            "north_speed_kmh",
            "arrival_offset_s",
            "collision",
            "safety_steps",
            "min_speed_kmh",
            "time_to_clear_s",
            "outcome",
            "comfort_violation_steps",
            "max_accel_lon",
            "max_accel_lat",
            "max_lateral_m",
            "return",
            "oracle_time_to_clear_s",
        ]
    )
    for i, name in enumerate(names):
        writer.writerow(
            [
                name,
                f"{scenarios.ego_start_distance[i]:.3f}",
                f"{scenarios.ego_speed[i] * 3.6:.3f}",
                f"{scenarios.north_speed[i] * 3.6:.3f}",
                f"{scenarios.arrival_offset[i]:.3f}",
                int(result.collision[i]),
                int(result.safety_steps[i]),
                f"{result.min_speed[i] * 3.6:.3f}",
                f"{result.time_to_clear[i]:.3f}",
                OUTCOMES[int(result.outcome[i])],
                int(result.comfort_violation_steps[i]),
                f"{result.max_accel_lon[i]:.3f}",
                f"{result.max_accel_lat[i]:.3f}",
                f"{result.max_lateral[i]:.3f}",
                f"{result.episode_return[i]:.3f}",
                f"{oracle_time[i]:.3f}",
            ]
        )
    return buffer.getvalue()
