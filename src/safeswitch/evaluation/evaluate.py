"""``safeswitch evaluate``: any controller × any switching logic × a set of scenarios."""

from __future__ import annotations

import csv
import io
import json
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from safeswitch.evaluation.metrics import summarize
from safeswitch.evaluation.policies import load_policy
from safeswitch.evaluation.rollout import Policy, RolloutResult, rollout
from safeswitch.leftturn.config import SCENARIO_NAMES, LeftTurnConfig
from safeswitch.leftturn.scenarios import Scenarios, named_scenarios
from safeswitch.leftturn.task import OUTCOMES, LeftTurnTask
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
    the summary (see :mod:`safeswitch.evaluation.metrics` for its fields)."""
    policy: Policy
    if controller == "learned":
        if model is None:
            raise ValueError("--controller learned needs --model (a run directory or 'shipped')")
        trained = load_policy(model)
        env_config = load_config(trained.path / "config.yaml").env
        policy = trained.as_policy()
    elif controller == "rule":
        env_config = replace(LeftTurnConfig(), switching="paper")
        env_config = replace(env_config, episode=replace(env_config.episode, learned_scope="never"))
        policy = _rule_policy
    else:
        raise ValueError(f"--controller must be 'learned' or 'rule', got {controller!r}")
    if switching is not None:
        env_config = replace(env_config, switching=switching)  # type: ignore[arg-type]
    env_config = replace(env_config, scenario=None)
    task = LeftTurnTask(env_config)
    batch, names = scenario_set(task, scenarios, episodes, seed)
    result = rollout(task, batch, policy)
    summary = {
        "controller": controller,
        "model": str(model) if model else None,
        "switching": env_config.switching,
        "scenarios": scenarios,
        "seed": seed,
        **summarize(result),
    }
    if out is not None:
        folder = Path(out)
        folder.mkdir(parents=True, exist_ok=True)
        write_atomic(folder / "episodes.csv", episodes_csv(names, batch, result))
        write_atomic(folder / "summary.json", json.dumps(summary, indent=2))
    return summary


def episodes_csv(names: list[str], scenarios: Scenarios, result: RolloutResult) -> str:
    """One row per episode: the scenario and what happened."""
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
            "return",
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
                f"{result.episode_return[i]:.3f}",
            ]
        )
    return buffer.getvalue()
