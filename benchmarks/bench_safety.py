"""Safety of the switching logics against adversarial learned controllers, and their cost.

For every switching logic (certified, paper, none) and every adversary of
``safeswitch.evaluation.adversaries``, the adversary drives the whole episode
(``learned_scope="episode"``) over 10,000 random scenarios and over an exhaustive grid of north
arrival offset × north speed × ego initial speed. Reported: episodes with a collision,
episodes that lost control (the tyres slid the ego off its lane), episodes with an
intervention, and intervention ticks per episode. Then: interventions for sensible drivers, the
assumption breaks, and the certified logic's cost per VecEnv step.

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
from safeswitch.core.config import to_dict
from safeswitch.evaluation.adversaries import catalogue, noisy_cruise, with_invalid
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.config import resolve_config
from safeswitch.leftturn.scenarios import Scenarios, scenario_grid
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.training.policies import load_policy

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
        random = task.scenario_set(2024, random_count)
        trained = load_policy("shipped").act
        for name in catalogue(task, 1, 0, trained):
            row: dict[str, object] = {"switching": switching, "adversary": name}
            for label, scenarios in (("random", random), ("grid", cells)):
                batch = scenarios.ego_speed.shape[0]
                result = rollout(
                    task, scenarios, catalogue(task, batch, seed=7, trained=trained)[name]()
                )
                row[f"{label}_episodes"] = batch
                row[f"{label}_collisions"] = int(result.collision.sum())
                row[f"{label}_lost_control"] = int(result.lost_control.sum())
                row[f"{label}_intervention_episodes"] = int((result.safety_steps > 0).sum())
                row[f"{label}_intervention_ticks_per_episode"] = float(result.safety_steps.mean())
            rows.append(row)
            print(
                f"  {switching:9} {name:16} collisions {row['random_collisions']:5} / "
                f"{random_count} random, {row['grid_collisions']:4} / {row['grid_episodes']} "
                f"grid cells; lost control {row['random_lost_control']:5} random, "
                f"{row['grid_lost_control']:4} grid",
                file=sys.stderr,
            )
    return rows


def invalid_actions(count: int) -> list[dict[str, object]]:
    """Each adversary with and without NaN on 30 % of its ticks (the rest of its behaviour
    unchanged), in both learned-controller scopes, under each logic: the invalid ticks must
    add no collisions (the pedals are held in their place; braking there instead stopped the
    car in the north car's path)."""
    rows = []
    for scope in ("window", "episode"):
        for switching in SWITCHINGS:
            task = LeftTurnTask(
                resolve_config({"episode": {"learned_scope": scope}}, switching=switching)
            )
            scenarios = task.scenario_set(99, count)
            for name in ("uniform", "bang_bang", "creep", "noisy_cruise", "zero_throttle"):
                alone = rollout(task, scenarios, catalogue(task, count, 5)[name]())
                broken = with_invalid(catalogue(task, count, 5)[name](), np.random.default_rng(3))
                invalid = rollout(task, scenarios, broken)
                rows.append(
                    {
                        "scope": scope,
                        "switching": switching,
                        "adversary": name,
                        "episodes": count,
                        "collisions": int(alone.collision.sum()),
                        "collisions_with_30pct_nan": int(invalid.collision.sum()),
                        "lost_control": int(alone.lost_control.sum()),
                        "lost_control_with_30pct_nan": int(invalid.lost_control.sum()),
                    }
                )
    return rows


def sensible_drivers(count: int) -> list[dict[str, object]]:
    """Interventions when the driver is reasonable: PID_th alone, a cruise P-controller, and
    the shipped paper policy (each under both logics; the policy with its own controllers, so
    one trained behind a speed limiter drives behind it)."""
    rows = []
    drivers = (
        ("rule (PID_th cruise)", "never"),
        ("cruise P-controller", "episode"),
        ("shipped paper policy", "episode"),
    )
    shipped = load_policy("shipped").config.deployed_env.controllers
    for driver, scope in drivers:
        for switching in ("certified", "paper"):
            override: dict[str, object] = {"episode": {"learned_scope": scope}}
            if driver.startswith("shipped"):
                override["controllers"] = to_dict(shipped)
            task = LeftTurnTask(resolve_config(override, switching=switching))
            scenarios = task.scenario_set(99, count)
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
        scenarios = task.scenario_set(5, count)
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


def cost(rounds: int = 9) -> dict[str, float]:
    """Time of one ``LeftTurnTask.step`` of 4,096 episodes for each logic, in one run.

    Two regimes, each from the same start states with the same uniform random actions and
    without resets (a VecEnv comparison would also count how often each logic lets episodes
    end): ``episode`` — whole 12 s episodes from their start; ``near`` — 30 ticks starting
    after 3 s of cruising, when most cars are at the intersection and the certified filter
    works hardest. The logics are timed in interleaved rounds and the median per logic is
    reported, so drifting load on a shared machine hits all of them alike; the overhead is the
    median over rounds of certified/none timed back to back in the same round.
    """
    n = 4096
    rng = np.random.default_rng(0)
    tasks = {
        name: LeftTurnTask(
            resolve_config({"episode": {"learned_scope": "episode"}}, switching=name)
        )
        for name in SWITCHINGS
    }
    base = tasks["none"]
    start = base.initial(base.scenario_set(0, n))
    near = start
    cruise = noisy_cruise(base, np.random.default_rng(0), sigma=0.0)
    for tick in range(150):
        near, _ = base.step(near, cruise(base.observe(near), near, tick))
    regimes = {"episode": (start, base.config.episode.horizon_ticks), "near": (near, 30)}
    out: dict[str, float] = {}
    for regime, (state0, ticks) in regimes.items():
        actions = rng.uniform(-1, 1, (ticks, n))
        samples: dict[str, list[float]] = {name: [] for name in tasks}
        for _ in range(rounds if regime == "episode" else 4 * rounds):
            for name, task in tasks.items():
                state = state0
                t0 = time.perf_counter()
                for k in range(ticks):
                    state, _ = task.step(state, actions[k])
                samples[name].append((time.perf_counter() - t0) / ticks)
        for name, values in samples.items():
            out[f"{regime}_{name}_step_ms"] = 1e3 * float(np.median(values))
        # Paired within each round (the logics ran back to back), then the median over rounds.
        paired = np.array(samples["certified"]) / np.array(samples["none"])
        out[f"{regime}_certified_over_none"] = float(np.median(paired)) - 1.0
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
        "invalid_actions": invalid_actions(2500),
        "sensible_drivers": sensible_drivers(2000),
        "assumption_breaks": assumption_breaks(2000),
        "cost_at_4096_envs": cost(),
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
        "| adversary | switching | collisions (random) | collisions (grid) | lost control "
        "(random / grid) | interventions (random episodes) | intervention ticks/episode |"
    )
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: |")
    for r in result["adversarial"]:
        print(
            f"| {r['adversary']} | {r['switching']} | {r['random_collisions']:,} / "
            f"{r['random_episodes']:,} | {r['grid_collisions']} / {r['grid_episodes']} | "
            f"{r['random_lost_control']:,} / {r['grid_lost_control']} | "
            f"{100 * r['random_intervention_episodes'] / r['random_episodes']:.1f} % | "
            f"{r['random_intervention_ticks_per_episode']:.1f} |"
        )
    print()
    print(
        "| scope | switching | adversary | collisions | with 30 % NaN ticks | lost control "
        "| with 30 % NaN ticks |"
    )
    print("| --- | --- | --- | ---: | ---: | ---: | ---: |")
    for r in result["invalid_actions"]:
        print(
            f"| {r['scope']} | {r['switching']} | {r['adversary']} | {r['collisions']} / "
            f"{r['episodes']} | {r['collisions_with_30pct_nan']} | {r['lost_control']} | "
            f"{r['lost_control_with_30pct_nan']} |"
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
    for regime in ("episode", "near"):
        print(
            f"Task step of 4,096 episodes ({regime}): none {c[f'{regime}_none_step_ms']:.2f} ms,"
            f" paper {c[f'{regime}_paper_step_ms']:.2f} ms, certified "
            f"{c[f'{regime}_certified_step_ms']:.2f} ms "
            f"(+{100 * c[f'{regime}_certified_over_none']:.0f} % over none)"
        )
    print(f"wall time {result['wall_time_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
