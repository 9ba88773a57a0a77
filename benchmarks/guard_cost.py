"""What training under ``guarded`` costs a policy deployed under ``paper``: its yields.

On the README's 1,000 unseen scenarios (seed 1000003): the planner (which plans around the
paper logic alone) under ``paper``, and under ``guarded`` — the paper logic with the certified
filter beneath it, the logic the shipped ``paper`` recipe trains under — with the certified
zones at their defaults (for an ego within 0.6 m of its route) and narrowed to what an ego
behind the 29.9 km/h speed limiter needs (within 0.45 m: ``ego_max_lateral_m`` 0.45,
``zone_margin_m`` 0.9); then each ``--model`` under ``paper`` (where it is deployed) and under
the ``guarded`` it was trained under. For each: efficiency (oracle time / time; an episode that
never clears counts with the 12 s horizon), the mean over the episodes it yields in and over
those it cuts in, mean time to clear, episodes never cleared, episodes with a safety action,
collisions, and the post-encroachment time (PET: how long after the north car left the
conflict area the ego entered it; the mean of each episode's minimum, and episodes below 1 s).

The filter keeps the ego able to stop before its certified zone until the north car has left
its own; the wider the zones, the further behind a north car it yields to the ego must stay —
a distance a policy trained under ``guarded`` keeps under ``paper`` too.

Run: ``python benchmarks/guard_cost.py [--model shipped ...] [--json]`` (about a minute);
writes ``benchmarks/results/guard_cost.json``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

import _common
from safeswitch.app.evaluate import controller_setup
from safeswitch.app.reproduce import EVAL_SEED
from safeswitch.evaluation.evaluate import run_controller, scenario_set
from safeswitch.evaluation.oracle import efficiency
from safeswitch.evaluation.planner import Planner
from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.task import OUTCOMES, LeftTurnTask
from safeswitch.training.policies import load_policy

EPISODES = 1000
RESULTS = Path(__file__).parent / "results" / "guard_cost.json"
#: The narrower certified zones of an ego behind the speed limiter.
NARROW = {"ego_max_lateral_m": 0.45, "zone_margin_m": 0.9}


def measure(name: str, config: LeftTurnConfig, policy: Any = None) -> dict[str, Any]:
    task = LeftTurnTask(replace(config, scenario=None))
    batch, _ = scenario_set(task, "random", EPISODES, EVAL_SEED)
    result, plan = run_controller(task, policy or Planner(task), batch, trace=False)
    ratio = efficiency(plan.time_to_clear, result.time_to_clear, config.episode.horizon_s)
    pet = result.min_pet
    row: dict[str, Any] = {
        "controller": name,
        "switching": config.switching,
        "ego_max_lateral_m": config.certified.ego_max_lateral_m,
        "zone_margin_m": config.certified.zone_margin_m,
        "mean_efficiency": float(np.nanmean(ratio)),
        "mean_time_to_clear_s": float(np.nanmean(result.time_to_clear)),
        "never_cleared": int(np.isnan(result.time_to_clear).sum()),
        "safety_activation_episodes": int((result.safety_steps > 0).sum()),
        "collisions": int(result.collision.sum()),
        "mean_min_pet_s": float(np.nanmean(pet)),
        "pet_below_1s_episodes": int((pet < 1.0).sum()),
    }
    for outcome in ("yield", "cut"):
        mask = result.outcome == OUTCOMES.index(outcome)
        row[f"{outcome}_episodes"] = int(mask.sum())
        row[f"{outcome}_efficiency"] = float(np.nanmean(ratio[mask])) if mask.any() else None
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", nargs="+", default=["shipped"])
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    scope = LeftTurnConfig()
    scope = replace(scope, episode=replace(scope.episode, learned_scope="episode"))
    narrow = replace(
        scope,
        certified=replace(scope.certified, **NARROW),
        controllers=replace(scope.controllers, learned_speed_limiter_kmh=29.9),
    )
    rows = [
        measure("planner", replace(scope, switching="paper")),
        measure("planner", replace(scope, switching="guarded")),
        measure("planner", replace(narrow, switching="guarded")),
    ]
    for model in args.model:
        deployed, policy = controller_setup("learned", model, None)
        trained = load_policy(model).config.env
        rows.append(measure(model, deployed, policy))
        rows.append(measure(model, replace(trained, scenario=None), policy))
    report = {
        "benchmark": "guard_cost",
        "seed": EVAL_SEED,
        "episodes": EPISODES,
        "machine": _common.machine(),
        "rows": rows,
    }
    if _common.publish(report, RESULTS, args.json):
        return 0
    print(f"{EPISODES} random scenarios, seed {EVAL_SEED}; PET: post-encroachment time")
    print(
        "controller  logic    zone margin  efficiency (yields, cuts)  time to clear  "
        "never cleared  safety eps  collisions  mean PET  PET < 1 s"
    )
    for r in rows:
        margin = f"{r['zone_margin_m']:.2f} m" if r["switching"] != "paper" else "–"
        print(
            f"{r['controller']:10s}  {r['switching']:7s}  {margin:>11s}  "
            f"{r['mean_efficiency']:.3f} ({r['yield_efficiency']:.3f}, {r['cut_efficiency']:.3f})  "
            f"{r['mean_time_to_clear_s']:11.2f} s  {r['never_cleared']:13d}  "
            f"{r['safety_activation_episodes']:10d}  {r['collisions']:10d}  "
            f"{r['mean_min_pet_s']:6.2f} s  {r['pet_below_1s_episodes']:9d}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
