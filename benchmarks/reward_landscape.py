"""What the paper's reward pays for: return against efficiency, scenario by scenario.

1. **The planner family.** The planner (``evaluation.planner``: throttle only, plans around
   the paper logic, never needs the Safety controller) with its tuning varied — the lateral
   acceleration it plans the turn for, its top speed on the straight, how late it yields —
   on the same random scenarios: mean return under a training configuration's reward and
   mean efficiency (the oracle's time to clear over the controller's). If the reward paid for
   a fast crossing, the more efficient settings would earn more.
2. **Policies by arrival offset.** For each ``--model`` (a run directory or a shipped name)
   on the README's 1,000 unseen scenarios (seed 1000003), by the north car's arrival offset:
   how often it crosses first, its efficiency beside the logic-aware limit (closed throttle,
   the learned controller's means), and its return with each term of Eq. 5 summed, in the
   yield scenarios (offset below 0 s) and the easy cuts (3 s and more).

Run: ``python benchmarks/reward_landscape.py [--config NAME] [--model DIR ...] [--json]``
(about two minutes); the reward is ``--config``'s (default ``experimental/scratch_wide``).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
from typing import Any

import numpy as np

import _common
from safeswitch.evaluation.evaluate import run_controller
from safeswitch.evaluation.logic_limit import PaperLogicLimit
from safeswitch.evaluation.oracle import efficiency
from safeswitch.evaluation.planner import Planner, PlannerConfig
from safeswitch.leftturn.task import build_task
from safeswitch.training.config import load_config
from safeswitch.training.policies import load_policy

SEED, EPISODES = 1_000_003, 1000
#: Planner settings compared (the default first).
PLANNERS: tuple[dict[str, float], ...] = (
    {},
    {"accel_lat": 2.5},
    {"accel_lat": 2.0},
    {"top_speed_kmh": 25.0},
    {"top_speed_kmh": 25.0, "accel_lat": 2.0},
    {"yield_margin_s": 1.0},
    {"yield_speed": 2.5},
)
OFFSETS = np.arange(-3.0, 5.01, 1.0)


def planner_family(task: Any, scenarios: Any, plan: Any) -> list[dict[str, Any]]:
    horizon = task.config.episode.horizon_s
    rows = []
    for tuning in PLANNERS:
        planner = Planner(task, dataclasses.replace(PlannerConfig(), **tuning))
        result, _ = run_controller(task, planner, scenarios, plan=plan, trace=False)
        rows.append({
            "planner": tuning or "default",
            "mean_return": float(result.episode_return.mean()),
            "mean_efficiency": float(np.nanmean(efficiency(plan.time_to_clear,
                                                           result.time_to_clear, horizon))),
            "safety_activation_episodes": int((result.safety_steps > 0).sum()),
            "cut_episodes": int((result.outcome == 1).sum()),
        })  # fmt: skip
    return rows


def by_offset(model: str, task: Any, scenarios: Any, plan: Any, limit: Any) -> dict[str, Any]:
    policy = load_policy(model)
    result, _ = run_controller(task, policy.as_policy(), scenarios, plan=plan, trace=False)
    horizon = task.config.episode.horizon_s
    eff = efficiency(plan.time_to_clear, result.time_to_clear, horizon)
    bound = efficiency(plan.time_to_clear, limit, horizon)
    offset = scenarios.arrival_offset
    bins = []
    for low, high in itertools.pairwise(OFFSETS):
        m = (offset >= low) & (offset < high)
        bins.append({
            "offset_s": [float(low), float(high)],
            "episodes": int(m.sum()),
            "cut_share": float(np.mean(result.outcome[m] == 1)),
            "efficiency": float(np.nanmean(eff[m])),
            "limit_efficiency": float(np.nanmean(bound[m])),
            "mean_return": float(result.episode_return[m].mean()),
        })  # fmt: skip
    terms = {}
    for name, m in (("yield", offset < 0.0), ("easy_cut", offset >= 3.0)):
        terms[name] = {
            "mean_return": float(result.episode_return[m].mean()),
            **{t: float(v[m].mean()) for t, v in result.terms.items()},
        }
    return {
        "model": model,
        "mean_efficiency": float(np.nanmean(eff)),
        "mean_return": float(result.episode_return.mean()),
        "by_offset": bins,
        "terms": terms,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="experimental/scratch_wide", help="whose reward")
    parser.add_argument("--model", nargs="*", default=["shipped"], help="policies to compare")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    env = load_config(args.config).env
    task = build_task(None, env)
    scenarios = task.scenario_set(SEED, EPISODES)
    _, plan = run_controller(task, None, scenarios)
    limit = PaperLogicLimit(task, braking="throttle").times(scenarios)
    result = {
        "benchmark": "reward_landscape",
        **_common.machine(),
        "config": args.config,
        "planners": planner_family(task, scenarios, plan),
        "models": [by_offset(m, task, scenarios, plan, limit) for m in args.model],
    }
    if args.json:
        _common.emit(result, True)
        return 0
    print(f"reward of {args.config}; {EPISODES} scenarios, seed {SEED}")
    for row in result["planners"]:
        print(f"  planner {row['planner']!s:45} return {row['mean_return']:7.1f}  "
              f"efficiency {row['mean_efficiency']:.3f}  cuts {row['cut_episodes']:3}  "
              f"safety {row['safety_activation_episodes']}")  # fmt: skip
    for entry in result["models"]:
        print(f"{entry['model']}: efficiency {entry['mean_efficiency']:.3f}, "
              f"return {entry['mean_return']:.1f}")  # fmt: skip
        print("  offset [s]   n  cut %  efficiency (limit)  return")
        for b in entry["by_offset"]:
            low, high = b["offset_s"]
            print(f"  {low:+.0f}..{high:+.0f} {b['episodes']:6} {100 * b['cut_share']:6.1f}"
                  f"  {b['efficiency']:.3f} ({b['limit_efficiency']:.3f})  "
                  f"{b['mean_return']:8.1f}")  # fmt: skip
        for name, t in entry["terms"].items():
            print(f"  {name:8} " + "  ".join(f"{k} {v:7.1f}" for k, v in t.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
