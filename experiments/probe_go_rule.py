"""How good a go decision the learned go predictor makes by itself (issue #39;
docs/learning_experiments.md, "A learned go predictor in the observation").

A one-off probe: the gap planner under `certified` (the from-scratch recipes' narrower zones) on
the 1,000 `test` scenes of seed 1000003, once with its own go check (a forward simulation that
knows every vehicle's future) and once with that check replaced by the learned predictor's
verdict on the observation (`traffic.go_model`, probability above a threshold), the planner's
wait and its drive otherwise the same. If the rule with the predictor comes near the planner,
the predictor holds the go decision and what a policy given it lacks is learning to use it.
Run: ``python experiments/probe_go_rule.py [experimental/traffic_certified_go_model]``.
"""

import sys
import time
from dataclasses import replace
from typing import Any

from go_predictor import PredictedGo

from safeswitch.evaluation.evaluate import run_controller, scenario_chunks, summary_against_oracle
from safeswitch.evaluation.traffic_planner import GapPlanner
from safeswitch.leftturn.config import observed_as, traffic_config
from safeswitch.leftturn.make import build_task
from safeswitch.training.config import load_config


def test_scenes(
    name: str, episodes: int = 1000, seen: Any = None, decision_interval: int | None = None
) -> tuple[Any, Any]:
    """The task and scenes the traffic probes drive: ``episodes`` `test` scenes of seed
    1000003 in the scene of the configuration ``name`` under `certified`, observed as its
    policy observes (``seen``: as a policy trained in that traffic does instead), each action
    held ``decision_interval`` ticks if given (also ``experiments/probe_decision_rate.py``'s
    and ``experiments/probe_traffic_approach.py``'s)."""
    config = load_config(name)
    env = replace(config.env, switching="certified")
    if decision_interval is not None:
        env = replace(env, episode=replace(env.episode, decision_interval=decision_interval))
    observed = traffic_config(config.traffic) if seen is None else seen
    task = build_task(None, env, traffic=observed_as(traffic_config("test"), observed))
    ((_, scenes),) = scenario_chunks(task, "random", episodes, 1_000_003)
    return task, scenes


def main() -> None:
    name = sys.argv[1] if len(sys.argv) > 1 else "experimental/traffic_certified_go_model"
    task, scenes = test_scenes(name)
    rules = [("gap planner (its simulated go check)", GapPlanner(task))]
    rules += [(f"learned predictor > {t}", PredictedGo(task, t)) for t in (0.3, 0.5, 0.7)]
    score_rules(task, rules, scenes)


def score_rules(task: Any, rules: list[tuple[str, Any]], scenes: Any) -> None:
    """Drive each named rule on ``scenes`` of ``task`` and print its summary against the
    oracle (also ``experiments/probe_certified_delays.py``'s)."""
    for name, rule in rules:
        start = time.time()
        result, plan = run_controller(task, rule, scenes, trace=False)
        s = summary_against_oracle(result, plan, task.config.episode.horizon_s)
        print(
            f"{name}: collisions {s['collisions']}, safety episodes "
            f"{s['safety_activation_episodes']}, cleared {s['cleared_episodes']}, efficiency "
            f"{s['mean_efficiency']:.4f}, comfort exceeded {s['comfort_violation_fraction']:.4%} "
            f"of ticks, max {s['max_speed_kmh']:.2f} km/h ({time.time() - start:.0f} s)",
            flush=True,
        )


if __name__ == "__main__":
    main()
