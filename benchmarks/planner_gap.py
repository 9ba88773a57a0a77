"""What the paper switching logic costs a controller that must never trigger it.

On the README's 1,000 random scenarios (seed 1000003) it replays the oracle's plans through the
paper logic's rule (Algorithm 1 with the task's constants; the north car's speed from its
simulated trajectory) and counts, for the oracle's cuts and yields, the plans on which the rule
fires; computes the logic-aware limit (:mod:`safeswitch.evaluation.logic_limit`: a lower bound
on the time to clear of any controller that never triggers the logic, with comfort braking and
with a closed throttle only); runs the planner and the rule-based system; and breaks all times
to clear down by the oracle's outcome, with the overall means and efficiencies.

Run: ``python benchmarks/planner_gap.py [--json] [--curve-decel A]`` (about three minutes;
numpy and numba). ``--curve-decel`` replaces the planner's ``curve_decel``: much above its
default, it enters the turn faster than the oracle's point-mass model allows and beats the
oracle (the ``faster than the oracle`` count).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import _common
from safeswitch.app.evaluate import controller_setup
from safeswitch.app.reproduce import EVAL_SEED
from safeswitch.evaluation.evaluate import run_controller, scenario_set
from safeswitch.evaluation.logic_limit import PaperLogicLimit
from safeswitch.evaluation.oracle import Oracle, efficiency
from safeswitch.evaluation.planner import Planner, PlannerConfig
from safeswitch.leftturn.task import OUTCOMES, LeftTurnTask
from safeswitch.leftturn.views import north_view


def rule_fires_on_plans(task: LeftTurnTask, oracle: Oracle, scenarios) -> np.ndarray:
    """``[B]``: the paper logic fires on some tick of the oracle's plan."""
    plan = oracle.plan(scenarios)
    dt = task.config.episode.dt
    s, v, s_n = plan.progress[:, 1:], plan.speed[:, 1:], plan.north_progress[:, 1:]
    v_n = np.diff(plan.north_progress, axis=1) / dt
    flat = [a.ravel() for a in (s, v, np.zeros(s.size), np.zeros(s.size), s_n, v_n)]
    state = north_view(task.north_conflict, *flat, v_n.ravel())
    decision = task.switching.decide(state, np.zeros((s.size, 1)), np.zeros((s.size, 1)))
    return decision.use_safety.reshape(s.shape).any(axis=1), plan


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--curve-decel", type=float, default=None, help="the planner's curve_decel")
    args = parser.parse_args(argv)
    config, planner = controller_setup("planner", None, None)
    task = LeftTurnTask(config)
    if args.curve_decel is not None:
        planner = Planner(task, PlannerConfig(curve_decel=args.curve_decel))
    scenarios, _ = scenario_set(task, "random", args.episodes, EVAL_SEED)
    oracle = Oracle(task)
    fires, plan = rule_fires_on_plans(task, oracle, scenarios)
    runs = {"planner": run_controller(task, planner, scenarios, plan=plan)[0]}
    rule_config, rule = controller_setup("rule", None, None)
    runs["rule"] = run_controller(LeftTurnTask(rule_config), rule, scenarios, plan=plan)[0]
    horizon = config.episode.horizon_s
    times = {"oracle": plan.time_to_clear}
    for braking in ("comfort", "throttle"):
        limit = PaperLogicLimit(task, braking=braking)  # type: ignore[arg-type]
        times[f"limit_{braking}"] = limit.times(scenarios)
    for name, result in runs.items():
        times[name] = result.time_to_clear
    times = {k: np.where(np.isfinite(t), t, horizon) for k, t in times.items()}
    overall = {
        name: {
            "mean_time_to_clear_s": float(t.mean()),
            "efficiency": float(np.mean(efficiency(plan.time_to_clear, t, horizon))),
            # controllers only: the limits are relaxations and may undercut the oracle by the
            # grid's rounding where the logic does not bind
            "faster_than_the_oracle": int(np.sum(t < plan.time_to_clear - 1e-9))
            if name in runs
            else None,
        }
        for name, t in times.items()
    }
    rows = []
    for code in (OUTCOMES.index("cut"), OUTCOMES.index("yield")):
        for fired in (False, True):
            mask = (plan.outcome == code) & (fires == fired)
            if not mask.any():
                continue
            row = {
                "oracle_outcome": OUTCOMES[code],
                "paper_logic_fires_on_oracle_plan": fired,
                "episodes": int(mask.sum()),
                "oracle_time_s": float(plan.time_to_clear[mask].mean()),
            }
            row["limit_throttle_time_s"] = float(times["limit_throttle"][mask].mean())
            for name, result in runs.items():
                row[f"{name}_time_s"] = float(times[name][mask].mean())
                row[f"{name}_cuts"] = int((result.outcome[mask] == OUTCOMES.index("cut")).sum())
            rows.append(row)
    if args.json:
        report = {"benchmark": "planner_gap", "episodes": args.episodes, "rows": rows}
        _common.emit({**report, "overall": overall}, True)
        return 0
    print(f"{args.episodes} random scenarios (seed {EVAL_SEED}); times to clear [s], never = 12 s")
    print("oracle   logic fires   episodes   oracle   limit   planner (cuts)   rule (cuts)")
    for r in rows:
        print(
            f"{r['oracle_outcome']:8s} {r['paper_logic_fires_on_oracle_plan']!s:11s} "
            f"{r['episodes']:10d} {r['oracle_time_s']:8.2f} {r['limit_throttle_time_s']:7.2f} "
            f"{r['planner_time_s']:9.2f} ({r['planner_cuts']:3d}) {r['rule_time_s']:9.2f} "
            f"({r['rule_cuts']:3d})"
        )
    print("(limit: the logic-aware limit with a closed throttle only)")
    print("\nall scenarios                     mean time   oracle time / time   faster than oracle")
    for name, o in overall.items():
        print(
            f"{name:32s} {o['mean_time_to_clear_s']:9.2f} {o['efficiency']:12.3f} "
            f"{'–' if o['faster_than_the_oracle'] is None else o['faster_than_the_oracle']:>20}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
