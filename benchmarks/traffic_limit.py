"""What the paper switching logic costs in traffic from every leg: the logic-aware limit against
every conflict at once.

For each density of the traffic study (light, medium, heavy and the test split) on random scenes
(seed 1000003, the README's): the multi-conflict oracle's time to clear; the reachable-set bound
without the logic (a relaxation of the same problem: how far the oracle's brake-then-drive plan
is from the best plan of the point-mass model); the logic-aware limit with comfort braking and
with a closed throttle only (:mod:`safeswitch.evaluation.logic_limit`, every conflicting
vehicle's Algorithm 1 as a constraint); and, beside them, the rule-based system and the shipped
``paper`` policy under the paper logic. All bounds plan against the others' world without the
ego, as the oracle does. An episode that never clears counts as the horizon (30 s); efficiency
(per-scene oracle time / time, averaged) is over the scenes the oracle clears.

Run: ``python benchmarks/traffic_limit.py [--json] [--episodes N]`` (about ten minutes at the
default 200 scenes per density on two cores; numba uses both); writes
``benchmarks/results/traffic_limit.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import _common
from safeswitch.app.evaluate import controller_setup, fit_observations
from safeswitch.app.reproduce import EVAL_SEED
from safeswitch.evaluation.evaluate import run_controller, scenario_set
from safeswitch.evaluation.logic_limit import PaperLogicLimit
from safeswitch.evaluation.oracle import efficiency
from safeswitch.leftturn.make import build_task
from safeswitch.training.policies import SHIPPED_DIR

RESULTS = Path(__file__).parent / "results" / "traffic_limit.json"
PRESETS = ("light", "medium", "heavy", "test")
CHUNK = 50


def bounds(task, scenarios, episodes: int) -> dict[str, np.ndarray]:
    """The three bounds of every scene, the conflict timeline built once per chunk."""
    limits = {
        "free": PaperLogicLimit(task, logic=False),
        "limit_comfort": PaperLogicLimit(task, braking="comfort"),
        "limit_throttle": PaperLogicLimit(task, braking="throttle"),
    }
    out = {name: np.empty(episodes) for name in limits}
    for start in range(0, episodes, CHUNK):
        rows = np.arange(start, min(start + CHUNK, episodes))
        timeline = task.conflict_timeline(scenarios.take(rows))
        for name, limit in limits.items():
            out[name][rows] = limit.bound(timeline)
    return out


def density(preset: str, episodes: int) -> dict[str, object]:
    started = time.perf_counter()
    config, rule = controller_setup("rule", None, None)
    task = build_task(None, config, traffic=preset)
    scenarios, _ = scenario_set(task, "random", episodes, EVAL_SEED)
    horizon = task.config.episode.horizon_s
    rule_result, plan = run_controller(task, rule, scenarios, trace=False)
    model = str(SHIPPED_DIR / "paper")
    learned_config, learned = controller_setup("learned", model, "paper")
    learned_task = build_task(None, learned_config, traffic=preset)
    learned = fit_observations(learned, model, learned_task)
    learned_result, _ = run_controller(learned_task, learned, scenarios, plan=plan, trace=False)
    times = {"oracle": plan.time_to_clear, **bounds(task, scenarios, episodes)}
    times["rule"] = rule_result.time_to_clear
    times["ppo-paper"] = learned_result.time_to_clear
    oracle = plan.time_to_clear
    rows = {}
    for name, t in times.items():
        never = ~np.isfinite(t)
        capped = np.where(never, horizon, t)
        rows[name] = {
            "mean_time_to_clear_s": float(capped.mean()),
            # over the scenes the oracle clears (the others have no efficiency)
            "efficiency": float(np.nanmean(efficiency(oracle, capped, horizon))),
            "never_clears": int(never.sum()),
        }
    for name, result in (("rule", rule_result), ("ppo-paper", learned_result)):
        rows[name]["collisions"] = int((result.collision > 0).sum())
        rows[name]["safety_episodes"] = int((result.safety_steps > 0).sum())
    both = np.isfinite(oracle) & np.isfinite(times["free"])
    gap = oracle[both] - times["free"][both]
    return {
        "preset": preset,
        "episodes": episodes,
        "rows": rows,
        "oracle_minus_free_s": {
            "median": float(np.median(gap)),
            "share_within_0.1s": float(np.mean(gap <= 0.1)),
            "max": float(gap.max()),
        },
        "seconds": time.perf_counter() - started,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--episodes", type=int, default=200, help="scenes per density")
    args = parser.parse_args(argv)
    results = []
    for preset in PRESETS:
        results.append(density(preset, args.episodes))
        if not args.json:
            r = results[-1]
            print(f"{preset}: {args.episodes} scenes, {r['seconds']:.0f} s")
            for name, row in r["rows"].items():
                extra = ""
                if "collisions" in row:
                    extra = f"  collisions {row['collisions']}  safety {row['safety_episodes']}"
                print(
                    f"  {name:15s} {row['mean_time_to_clear_s']:6.2f} s  "
                    f"eff {row['efficiency']:.3f}  never {row['never_clears']:3d}{extra}"
                )
            g = r["oracle_minus_free_s"]
            print(
                f"  oracle - bound without the logic: median {g['median']:.2f} s, "
                f"{100 * g['share_within_0.1s']:.1f} % within 0.1 s, max {g['max']:.2f} s"
            )
    report = {
        "benchmark": "traffic_limit",
        "seed": EVAL_SEED,
        "machine": _common.machine(),
        "densities": results,
    }
    _common.publish(report, RESULTS, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
