"""How broad a sign of a collision the guard's overrule is: constant cruises under both logics.

Training under ``guarded`` (the paper logic with the certified filter beneath it) can charge
the ticks on which the filter overrules the paper logic's own braking
(``…:overrules_primary``) as a stand-in for the collision the paper logic alone would have let
happen there. This measures how broad that stand-in is. For each constant throttle it drives
the same random scenarios twice, with the shipped ``paper`` recipe's environment
(``configs/paper.yaml``: the learned controller drives the whole episode, a decision every 5
ticks): under ``guarded``, counting the episodes in which the filter stepped in at all and
those with an overrule; under ``paper`` alone, counting the episodes that collide. A constant
throttle is the same policy under both, so the counts are of the same behaviour
(``docs/learning_experiments.md``, "Rare collisions under ``paper``").

Run: ``python benchmarks/overrule_breadth.py [--throttles 0.3 0.6 1.0] [--episodes 2000]
[--seed 8000009] [--out FILE] [--json]`` (about 5 s per throttle).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

import numpy as np

import _common
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.task import build_task
from safeswitch.training.config import load_config


def drive(switching: str, throttle: float, episodes: int, seed: int) -> dict[str, int]:
    """A constant ``throttle`` under ``switching`` on ``episodes`` random scenarios: episodes
    in which a guard stepped in, in which it overruled the primary logic, and collisions."""
    env = load_config("paper").env
    task = build_task(None, dataclasses.replace(env, switching=switching))
    scenarios = task.draw_scenarios(seed, np.arange(episodes), np.zeros(episodes, dtype=int))
    guard = np.array([r.startswith("guard:") for r in task.reasons])
    overrule = np.array([r.endswith(":overrules_primary") for r in task.reasons])
    guarded, overruled = np.zeros(episodes, dtype=bool), np.zeros(episodes, dtype=bool)
    live = np.ones(episodes, dtype=bool)
    action = np.full(episodes, 2.0 * throttle - 1.0)  # the learned action asking for it

    def on_tick(state: Any, record: Any, tick: int) -> None:
        acted = live & record.safety_active
        guarded[acted & guard[record.reason]] = True
        overruled[acted & overrule[record.reason]] = True
        live[record.terminated | record.truncated] = False

    result = rollout(task, scenarios, lambda observation, state, tick: action, on_tick)
    return {
        "guard_episodes": int(guarded.sum()),
        "overrule_episodes": int(overruled.sum()),
        "collisions": int(result.collision.sum()),
    }


def cruise(throttle: float, episodes: int, seed: int) -> dict[str, Any]:
    """Under ``guarded``: episodes with the filter, with an overrule, collisions; under
    ``paper``: collisions."""
    guarded = drive("guarded", throttle, episodes, seed)
    return {
        "throttle": throttle,
        "guard_episodes": guarded["guard_episodes"],
        "overrule_episodes": guarded["overrule_episodes"],
        "guarded_collisions": guarded["collisions"],
        "paper_collisions": drive("paper", throttle, episodes, seed)["collisions"],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--throttles", type=float, nargs="+", default=[0.3, 0.6, 1.0])
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=8_000_009)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--out", type=Path, help="also write the JSON to this file")
    args = parser.parse_args(argv)
    bad = [t for t in args.throttles if not (np.isfinite(t) and 0.0 <= t <= 1.0)]
    if bad:
        parser.error(f"--throttles must be in [0, 1], got {bad}")
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    rows = [cruise(t, args.episodes, args.seed) for t in args.throttles]
    result = {
        "benchmark": "overrule_breadth", **_common.machine(), "config": "paper",
        "episodes": args.episodes, "seed": args.seed, "cruises": rows,
    }  # fmt: skip
    if _common.publish(result, args.out, args.json):
        return 0
    print(f"constant throttle, {args.episodes:,} random scenarios (seed {args.seed}):")
    print("throttle | guarded: episodes with the filter / with an overrule / collisions "
          "| paper: collisions")  # fmt: skip
    for row in rows:
        print(f"{row['throttle']:8.2f} | {row['guard_episodes']:25,} / "
              f"{row['overrule_episodes']:16,} / {row['guarded_collisions']:10,} "
              f"| {row['paper_collisions']:17,}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
