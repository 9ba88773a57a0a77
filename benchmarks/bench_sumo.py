"""SUMO as a second simulator: speed, the certified logic's safety, and the shipped policies on
both simulators.

1. **Speed.** Steps per second of ``safeswitch/LeftTurnSumo-v0`` (one process, SUMO driving
   the north car) and of ``safeswitch/LeftTurn-v0`` (the embedded simulator, a batch of one),
   measured alternately in the same run, constant action, resets included; their ratio.
2. **Safety.** Every adversary drives whole episodes of random scenarios on SUMO under the
   certified logic (``--episodes`` scenarios × 8 adversaries): collisions by our footprint
   check and by SUMO's, and the episodes in which SUMO's north car broke the logic's
   assumptions (counted, not hidden); the paper logic's collisions in the same episodes.
3. **Cross-simulator.** The shipped policies and the rule-based controller on the same random
   scenarios, embedded vs SUMO: collisions, safety activations, time to clear, comfort.

Run: ``python benchmarks/bench_sumo.py [--json] [--episodes N] [--compare N]``; writes
``benchmarks/results/sumo.json``. Needs ``pip install 'safeswitch[sumo]'``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

import _common
from safeswitch.app.evaluate import evaluate
from safeswitch.evaluation.adversaries import catalogue
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn import LeftTurnEnv
from safeswitch.sumo.task import LeftTurnSumoEnv, sumo_task

RESULTS = Path(__file__).parent / "results" / "sumo.json"
ADVERSARIES = ("uniform", "bang_bang", "full_throttle", "zero_throttle", "enter_then_stop",
               "creep", "nan_inf", "noisy_cruise")  # fmt: skip
COMPARED = (("learned", "shipped"), ("learned", "certified"), ("learned", "paper-scratch"),
            ("rule", None))  # fmt: skip
KEYS = ("collisions", "safety_activation_episodes", "cleared_episodes", "mean_time_to_clear_s",
        "comfort_violation_fraction", "mean_efficiency")  # fmt: skip


def steps_per_s(env: Any, steps: int) -> float:
    env.reset(seed=0)
    action = np.array([0.3], dtype=np.float32)
    began = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - began)


def speed(rounds: int = 3, steps: int = 3000) -> dict[str, float]:
    sumo, ours = LeftTurnSumoEnv(), LeftTurnEnv()
    rates: dict[str, list[float]] = {"sumo": [], "embedded": []}
    for _ in range(rounds):
        rates["sumo"].append(steps_per_s(sumo, steps))
        rates["embedded"].append(steps_per_s(ours, steps))
    sumo.close()
    out = {name: float(np.median(values)) for name, values in rates.items()}
    out["sumo_to_embedded"] = out["sumo"] / out["embedded"]
    print(
        f"single env: SUMO {out['sumo']:,.0f} steps/s, embedded {out['embedded']:,.0f} steps/s "
        f"(ratio {out['sumo_to_embedded']:.2f})",
        file=sys.stderr,
    )
    return out


def safety(episodes: int) -> list[dict[str, object]]:
    rows = []
    for switching in ("certified", "paper"):
        task = sumo_task({"episode": {"learned_scope": "episode"}}, switching=switching)
        try:
            for name in ADVERSARIES:
                row = {"switching": switching, "adversary": name, "episodes": episodes,
                       "collisions": 0, "sumo_collision_episodes": 0,
                       "assumption_break_episodes": 0}  # fmt: skip
                for k in range(episodes):
                    scenario = task.draw_scenarios(2024, np.array([k]), np.zeros(1, int))
                    result = rollout(task, scenario, catalogue(task, 1, k)[name]())
                    row["collisions"] += int(result.collision[0])  # type: ignore[operator]
                    row["sumo_collision_episodes"] += int(task.sumo_collisions > 0)  # type: ignore[operator]
                    row["assumption_break_episodes"] += int(task.assumption_breaks)  # type: ignore[operator]
                rows.append(row)
                print(f"  {switching:9} {name:16} {row}", file=sys.stderr)
        finally:
            task.close()
    return rows


def cross(episodes: int) -> list[dict[str, object]]:
    rows = []
    for controller, model in COMPARED:
        for sim in ("embedded", "sumo"):
            summary = evaluate(controller, model, "random", episodes, 7, None, None, sim=sim)
            row = {"controller": controller, "model": model, "sim": sim,
                   **{k: summary[k] for k in KEYS}}  # fmt: skip
            if sim == "sumo":
                row["sumo_collision_episodes"] = summary["sumo_collision_episodes"]
                row["assumption_break_episodes"] = summary["assumption_break_episodes"]
            rows.append(row)
            print(f"  {row}", file=sys.stderr)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--episodes", type=int, default=250, help="per adversary and logic")
    parser.add_argument("--compare", type=int, default=200, help="episodes per simulator")
    args = parser.parse_args()
    result: dict[str, object] = {"machine": _common.machine(), "speed": speed()}
    rows = safety(args.episodes)
    result["safety"] = rows
    result["safety_totals"] = {
        s: {k: sum(int(r[k]) for r in rows if r["switching"] == s)  # type: ignore[call-overload]
            for k in ("episodes", "collisions", "sumo_collision_episodes",
                      "assumption_break_episodes")}
        for s in ("certified", "paper")
    }  # fmt: skip
    print(json.dumps(result["safety_totals"]), file=sys.stderr)
    result["cross_simulator"] = cross(args.compare)
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    _common.emit(result, args.json)


if __name__ == "__main__":
    main()
