"""``safeswitch evaluate``: any controller × any switching logic × a set of scenarios."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from safeswitch.evaluation.metrics import summarize
from safeswitch.evaluation.oracle import Oracle, OraclePlan, efficiency
from safeswitch.evaluation.planner import Planner
from safeswitch.evaluation.policies import load_policy
from safeswitch.evaluation.rollout import Policy, RolloutResult, rollout
from safeswitch.leftturn.config import SCENARIO_NAMES, LearnedScope, LeftTurnConfig
from safeswitch.leftturn.scenarios import Scenarios, named_scenarios
from safeswitch.leftturn.task import OUTCOMES, LeftTurnTask, StepRecord, TaskState
from safeswitch.sim.geometry import FloatArray
from safeswitch.training.config import load_config
from safeswitch.training.run import write_atomic


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


def controller_setup(
    controller: str, model: str | None, switching: str | None
) -> tuple[LeftTurnConfig, Policy | None]:
    """The task configuration and policy of a controller (``None`` for the oracle, which
    plans instead of acting)."""
    policy: Policy | None
    if controller == "learned":
        if model is None:
            raise ValueError("--controller learned needs --model (a run directory or 'shipped')")
        trained = load_policy(model)
        env_config = load_config(trained.path / "config.yaml").env
        policy = trained.as_policy()
    elif controller in ("rule", "oracle", "planner"):
        # The rule's PID_th proposes throughout; the planner drives with the learned
        # controller's throttle throughout.
        scope: LearnedScope = "episode" if controller == "planner" else "never"
        env_config = replace(LeftTurnConfig(), switching="paper")
        env_config = replace(env_config, episode=replace(env_config.episode, learned_scope=scope))
        if controller == "planner":
            policy = Planner(LeftTurnTask(env_config))
        else:
            policy = _rule_policy if controller == "rule" else None
    else:
        raise ValueError(
            f"--controller must be 'learned', 'rule', 'planner' or 'oracle', got {controller!r}"
        )
    if switching is not None:
        env_config = replace(env_config, switching=switching)  # type: ignore[arg-type]
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


def evaluate(
    controller: str,
    model: str | None,
    scenarios: str,
    episodes: int,
    seed: int,
    switching: str | None,
    out: str | Path | None,
) -> dict[str, Any]:
    """Run the evaluation, write ``episodes.csv`` and ``summary.json`` into ``out``, and return
    the summary (see :mod:`safeswitch.evaluation.metrics` for its fields; ``mean_efficiency``
    is the mean over scenarios of the oracle's time to clear divided by the controller's)."""
    env_config, policy = controller_setup(controller, model, switching)
    task = LeftTurnTask(env_config)
    batch, names = scenario_set(task, scenarios, episodes, seed)
    result, plan = run_controller(task, policy, batch)
    summary = {
        "controller": controller,
        "model": str(model) if model else None,
        "switching": env_config.switching if policy is not None else None,
        "scenarios": scenarios,
        "seed": seed,
        **summary_against_oracle(result, plan, env_config.episode.horizon_s),
    }
    if out is not None:
        folder = Path(out)
        folder.mkdir(parents=True, exist_ok=True)
        write_atomic(
            folder / "episodes.csv", episodes_csv(names, batch, result, plan.time_to_clear)
        )
        write_atomic(folder / "summary.json", json.dumps(summary, indent=2))
    return summary


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
