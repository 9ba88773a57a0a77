"""Safety of the switching logics against adversarial learned controllers, and their cost.

For every switching logic (certified, paper, none) and every adversary of
``safeswitch.evaluation.adversaries``, the adversary drives the whole episode
(``learned_scope="episode"``) over 10,000 random scenarios and over an exhaustive grid of north
arrival offset × north speed × ego initial speed. Reported: episodes with a collision,
episodes with an intervention, and intervention ticks per episode. Then: interventions for
sensible drivers, the assumption breaks, and the certified logic's cost per VecEnv step.

Run: ``python benchmarks/bench_safety.py [--json] [--random N]``; writes
``benchmarks/results/safety.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

import _common
from safeswitch.bench import time_per_call
from safeswitch.evaluation.adversaries import catalogue, noisy_cruise
from safeswitch.evaluation.policies import load_policy
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn import make_vec_env
from safeswitch.leftturn.config import resolve_config
from safeswitch.leftturn.scenarios import Scenarios, scenario_grid
from safeswitch.leftturn.task import LeftTurnTask

SWITCHINGS = ("certified", "paper", "none")
RESULTS = Path(__file__).parent / "results" / "safety.json"


def grid() -> Scenarios:
    return scenario_grid(
        np.arange(-3.0, 5.001, 0.25), np.arange(20.0, 32.1, 2.0), np.linspace(18.0, 25.0, 4)
    )


def adversarial_table(random_count: int) -> list[dict[str, object]]:
    rows = []
    cells = grid()
    for switching in SWITCHINGS:
        task = LeftTurnTask(
            resolve_config({"episode": {"learned_scope": "episode"}}, switching=switching)
        )
        random = task.draw_scenarios(2024, np.arange(random_count), np.zeros(random_count, int))
        for name in catalogue(task, 1, 0):
            row: dict[str, object] = {"switching": switching, "adversary": name}
            for label, scenarios in (("random", random), ("grid", cells)):
                batch = scenarios.ego_speed.shape[0]
                result = rollout(task, scenarios, catalogue(task, batch, seed=7)[name]())
                row[f"{label}_episodes"] = batch
                row[f"{label}_collisions"] = int(result.collision.sum())
                row[f"{label}_intervention_episodes"] = int((result.safety_steps > 0).sum())
                row[f"{label}_intervention_ticks_per_episode"] = float(result.safety_steps.mean())
            rows.append(row)
            print(
                f"  {switching:9} {name:16} collisions {row['random_collisions']:5} / "
                f"{random_count} random, {row['grid_collisions']:4} / {row['grid_episodes']} "
                f"grid cells",
                file=sys.stderr,
            )
    return rows


def sensible_drivers(count: int) -> list[dict[str, object]]:
    """Interventions when the driver is reasonable: PID_th alone, a cruise P-controller, and
    the shipped paper policy (each under both logics)."""
    rows = []
    drivers = (
        ("rule (PID_th cruise)", "never"),
        ("cruise P-controller", "episode"),
        ("shipped paper policy", "episode"),
    )
    for driver, scope in drivers:
        for switching in ("certified", "paper"):
            task = LeftTurnTask(
                resolve_config({"episode": {"learned_scope": scope}}, switching=switching)
            )
            scenarios = task.draw_scenarios(99, np.arange(count), np.zeros(count, int))
            if driver.startswith("shipped"):
                policy = load_policy("shipped").as_policy()
            else:
                policy = noisy_cruise(task, np.random.default_rng(0), sigma=0.0)
            result = rollout(task, scenarios, policy)
            rows.append(
                {
                    "driver": driver,
                    "switching": switching,
                    "episodes": count,
                    "collisions": int(result.collision.sum()),
                    "intervention_episodes": int((result.safety_steps > 0).sum()),
                    "intervention_ticks_per_episode": float(result.safety_steps.mean()),
                    "mean_time_to_clear_s": float(np.nanmean(result.time_to_clear)),
                }
            )
    return rows


def assumption_breaks(count: int) -> list[dict[str, object]]:
    """The north car breaks the certified logic's assumptions mid-episode."""
    cases = {
        "north brakes to a stop inside the intersection": (0.0, -3.0),
        "north brakes to a stop before the intersection": (0.0, 15.0),
        "north speeds up to 60 km/h (assumed at most 50)": (60.0, 25.0),
        "north speeds up to 90 km/h": (90.0, 25.0),
    }
    rows = []
    for switching in ("certified", "paper"):
        task = LeftTurnTask(
            resolve_config({"episode": {"learned_scope": "episode"}}, switching=switching)
        )
        scenarios = task.draw_scenarios(5, np.arange(count), np.zeros(count, int))
        north_entry = task.conflict.zone_b[0]
        for label, (speed_kmh, before) in cases.items():
            triggered = np.zeros(count, dtype=bool)

            def hook(
                state,
                record,
                tick,
                speed_kmh=speed_kmh,
                before=before,
                triggered=triggered,
                north_entry=north_entry,
            ):
                near = state.world.progress[:, 1] > north_entry - before
                state.scenarios.north_speed[near & ~triggered] = speed_kmh / 3.6
                triggered |= near

            policy = catalogue(task, count, 3)["uniform"]()
            result = rollout(task, scenarios, policy, hook)
            rows.append(
                {
                    "case": label,
                    "switching": switching,
                    "episodes": count,
                    "collisions": int(result.collision.sum()),
                }
            )
    return rows


def cost(seconds: float) -> dict[str, float]:
    """VecEnv step time at 4,096 environments for each logic, measured in one run."""
    out = {}
    actions = np.random.default_rng(0).uniform(-1, 1, (16, 4096, 1))
    for switching in ("none", "paper", "certified"):
        env = make_vec_env(4096, switching=switching, seed=0)
        env.reset()
        counter = {"k": 0}

        def step(env=env, counter=counter) -> None:
            env.step(actions[counter["k"] % 16])
            counter["k"] += 1

        out[f"{switching}_step_ms"] = 1e3 * time_per_call(step, seconds)
    out["certified_over_none"] = out["certified_step_ms"] / out["none_step_ms"] - 1.0
    out["certified_over_paper"] = out["certified_step_ms"] / out["paper_step_ms"] - 1.0
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--random", type=int, default=10_000, help="random scenarios")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    result = {
        "benchmark": "safety",
        **_common.machine(),
        "adversarial": adversarial_table(args.random),
        "sensible_drivers": sensible_drivers(2000),
        "assumption_breaks": assumption_breaks(2000),
        "cost_at_4096_envs": cost(2.0),
    }
    result["wall_time_s"] = time.perf_counter() - start
    RESULTS.parent.mkdir(exist_ok=True)
    tmp = RESULTS.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result, indent=2))
    os.replace(tmp, RESULTS)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(
        "| adversary | switching | collisions (random) | collisions (grid) | "
        "interventions (random episodes) | intervention ticks/episode |"
    )
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    for r in result["adversarial"]:
        print(
            f"| {r['adversary']} | {r['switching']} | {r['random_collisions']:,} / "
            f"{r['random_episodes']:,} | {r['grid_collisions']} / {r['grid_episodes']} | "
            f"{100 * r['random_intervention_episodes'] / r['random_episodes']:.1f} % | "
            f"{r['random_intervention_ticks_per_episode']:.1f} |"
        )
    print()
    for r in result["sensible_drivers"]:
        print(
            f"{r['driver']:22} {r['switching']:9} interventions in "
            f"{100 * r['intervention_episodes'] / r['episodes']:.1f} % of episodes, "
            f"{r['intervention_ticks_per_episode']:.1f} ticks/episode, collisions "
            f"{r['collisions']}, mean time to clear {r['mean_time_to_clear_s']:.2f} s"
        )
    print()
    for r in result["assumption_breaks"]:
        print(f"{r['case']:50} {r['switching']:9} collisions {r['collisions']} / {r['episodes']}")
    c = result["cost_at_4096_envs"]
    print(
        f"\nVecEnv step at 4,096 envs: none {c['none_step_ms']:.2f} ms, paper "
        f"{c['paper_step_ms']:.2f} ms, certified {c['certified_step_ms']:.2f} ms "
        f"(+{100 * c['certified_over_none']:.0f} % over none)"
    )
    print(f"wall time {result['wall_time_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
