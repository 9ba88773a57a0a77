"""Traffic from every leg: throughput with many vehicles, and the switching logics' safety.

1. **Throughput.** The batched VecEnv at 4,096 scenes of the ``heavy`` preset (8 to 9 other
   vehicles per scene on average; the mean is measured and printed), of the same with drivers
   deciding every tick instead of every 0.1 s (``traffic.action_step_s``) and of the ``dense``
   setting below (about 12) against the paper's scene in the same run, uniform random actions,
   one core, 250 ticks into the episodes; the single Env likewise.
2. **Safety.** Every adversary of ``safeswitch.evaluation.adversaries`` drives whole 30 s
   episodes under ``certified`` and under ``paper``, at every density (light, medium, heavy and
   the test split), on random scenes (3,125 per density and adversary under ``certified``:
   100,000 in all; the first 500 of them under ``paper``, whose collisions only need counting),
   then on a grid of the paper's scenario parameters (north arrival offset × north speed × ego
   speed) with traffic drawn around each cell; collisions of the ego and among the other
   vehicles are counted.

Run: ``python benchmarks/bench_traffic.py [--json] [--episodes N] [--skip-safety]``; writes
``benchmarks/results/traffic.json`` (``--skip-safety`` measures the throughput alone and keeps
the file's safety rows). The full run takes about half an hour on an idle machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import _common
from safeswitch.bench import time_per_call
from safeswitch.evaluation.adversaries import catalogue
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn import LeftTurnEnv, make_vec_env
from safeswitch.leftturn.scenarios import scenario_grid
from safeswitch.leftturn.task import build_task

RESULTS = Path(__file__).parent / "results" / "traffic.json"
PRESETS = ("light", "medium", "heavy", "test")
#: Denser than the heavy preset, for the throughput target (≥ 8 vehicles per scene).
DENSE = {"preset": "heavy", "main_flow_veh_h": (900.0, 1100.0),
         "minor_flow_veh_h": (450.0, 600.0), "max_vehicles": 16}  # fmt: skip


def vec_throughput(traffic: object, seconds: float) -> tuple[float, float]:
    """(env-steps/s, mean other vehicles per scene) of the VecEnv at 4,096 scenes."""
    n = 4096
    env = make_vec_env(n, traffic=traffic, switching="paper", seed=0)
    env.reset()
    actions = np.random.default_rng(0).uniform(-1, 1, (16, n, 1)).astype(np.float32)
    for k in range(250):  # into the episodes: the streams have filled the approaches
        env.step(actions[k % 16])
    counter = {"k": 0}
    counts: list[float] = []

    def step() -> None:
        env.step(actions[counter["k"] % 16])
        counter["k"] += 1
        traffic_state = getattr(env.state, "traffic", None)
        if traffic_state is not None and counter["k"] % 10 == 0:
            counts.append(float(traffic_state.active.sum(axis=1).mean()))

    rate = n / time_per_call(step, seconds)
    return rate, float(np.mean(counts)) if counts else 0.0


def env_throughput(traffic: object, seconds: float) -> float:
    env = LeftTurnEnv(switching="paper", traffic=traffic)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (1000, 1)).astype(np.float32)
    counter = {"k": 0}

    def hundred() -> None:
        for _ in range(100):
            *_, terminated, truncated, _ = env.step(actions[counter["k"] % 1000])
            counter["k"] += 1
            if terminated or truncated:
                env.reset()

    return 100 / time_per_call(hundred, seconds)


def throughput(seconds: float) -> dict[str, object]:
    plain, _ = vec_throughput(None, seconds)
    heavy, heavy_vehicles = vec_throughput("heavy", seconds)
    per_tick, _ = vec_throughput({"preset": "heavy", "action_step_s": 0.02}, seconds)
    dense, vehicles = vec_throughput(DENSE, seconds)
    single_plain = env_throughput(None, seconds)
    single_heavy = env_throughput("heavy", seconds)
    out = {
        "vec_env_4096_paper_scene_steps_per_s": plain,
        "vec_env_4096_heavy_traffic_steps_per_s": heavy,
        "heavy_mean_other_vehicles": heavy_vehicles,
        "vec_env_4096_heavy_traffic_drivers_every_tick_steps_per_s": per_tick,
        "action_step_speedup": heavy / per_tick,
        "vec_env_4096_dense_traffic_steps_per_s": dense,
        "dense_mean_other_vehicles": vehicles,
        "heavy_to_paper_scene_ratio": heavy / plain,
        "env_paper_scene_steps_per_s": single_plain,
        "env_heavy_traffic_steps_per_s": single_heavy,
    }
    print(
        f"VecEnv 4096: paper scene {plain:,.0f} steps/s; heavy traffic {heavy:,.0f} steps/s "
        f"({heavy_vehicles:.1f} other vehicles per scene on average; ratio {heavy / plain:.2f}; "
        f"drivers deciding every tick {per_tick:,.0f}, {heavy / per_tick:.2f}x slower); "
        f"dense {dense:,.0f} ({vehicles:.1f} vehicles); single Env {single_plain:,.0f} / "
        f"{single_heavy:,.0f} steps/s",
        file=sys.stderr,
    )
    return out


def grid_cells(task: object) -> object:
    base = scenario_grid(
        np.arange(-3.0, 5.001, 0.5), np.arange(20.0, 32.1, 4.0), np.linspace(18.0, 25.0, 3)
    )
    n = base.ego_speed.shape[0]
    ids = np.arange(n)
    return task.with_traffic(base, 77, ids, np.zeros_like(ids))  # type: ignore[attr-defined]


class _NPCs:
    """``on_tick`` keeping the collisions among the other vehicles."""

    def __init__(self) -> None:
        self.count = 0

    def __call__(self, state: object, record: object, tick: int) -> None:
        self.count = int(state.npc_collisions.sum())  # type: ignore[attr-defined]


def safety(episodes: int, paper_episodes: int) -> list[dict[str, object]]:
    rows = []
    for preset in PRESETS:
        for switching, count in (("certified", episodes), ("paper", paper_episodes)):
            task = build_task(
                None, {"episode": {"learned_scope": "episode"}}, traffic=preset,
                switching=switching,
            )  # fmt: skip
            random = task.scenario_set(2024, count)
            cells = grid_cells(task)
            for name in catalogue(task, 1, 0):
                row: dict[str, object] = {"preset": preset, "switching": switching,
                                          "adversary": name}  # fmt: skip
                for label, scenarios in (("random", random), ("grid", cells)):
                    batch = scenarios.ego_speed.shape[0]  # type: ignore[attr-defined]
                    npcs = _NPCs()
                    began = time.perf_counter()
                    result = rollout(task, scenarios, catalogue(task, batch, seed=7)[name](), npcs)  # type: ignore[arg-type]
                    row[f"{label}_episodes"] = batch
                    row[f"{label}_collisions"] = int(result.collision.sum())
                    row[f"{label}_lost_control"] = int(result.lost_control.sum())
                    row[f"{label}_npc_collisions"] = npcs.count
                    row[f"{label}_cleared"] = int(np.isfinite(result.time_to_clear).sum())
                    row[f"{label}_seconds"] = round(time.perf_counter() - began, 1)
                rows.append(row)
                print(
                    f"  {preset:6} {switching:9} {name:16} collisions "
                    f"{row['random_collisions']:4} / {count} random, "
                    f"{row['grid_collisions']:3} / {row['grid_episodes']} grid; among the others "
                    f"{row['random_npc_collisions']} / {row['grid_npc_collisions']}; lost control "
                    f"{row['random_lost_control']} / {row['grid_lost_control']}",
                    file=sys.stderr,
                )
    return rows


def totals(rows: list[dict[str, object]]) -> dict[str, dict[str, int]]:
    out: dict[str, dict[str, int]] = {}
    for switching in ("certified", "paper"):
        mine = [r for r in rows if r["switching"] == switching]
        out[switching] = {
            key: sum(int(r[key]) for r in mine)  # type: ignore[call-overload]
            for key in ("random_episodes", "random_collisions", "grid_episodes",
                        "grid_collisions", "random_npc_collisions", "grid_npc_collisions",
                        "random_lost_control", "grid_lost_control")
        }  # fmt: skip
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument(
        "--episodes", type=int, default=3125, help="random episodes per cell, certified"
    )
    parser.add_argument(
        "--paper-episodes", type=int, default=500, help="random episodes per cell, paper"
    )
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--skip-safety", action="store_true")
    args = parser.parse_args()
    result: dict[str, object] = {
        "machine": _common.machine(),
        "throughput": throughput(args.seconds),
    }
    if not args.skip_safety:
        rows = safety(args.episodes, args.paper_episodes)
        result["safety"] = rows
        result["safety_totals"] = totals(rows)
        print(json.dumps(result["safety_totals"], indent=1), file=sys.stderr)
    elif RESULTS.is_file():  # keep the last safety run's rows beside the new throughput
        previous = json.loads(RESULTS.read_text())
        for key in ("safety", "safety_totals"):
            if key in previous:
                result[key] = previous[key]
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    _common.emit(result, args.json)


if __name__ == "__main__":
    main()
