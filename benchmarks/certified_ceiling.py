"""How many left turns *any* learned controller could clear under the `certified` filter: an
oracle under the filter's rules (issue #39, the `certified` row's "clears ≥ 99 %").

The oracle of the efficiency figures plans with hindsight and no filter; under `certified` a
policy may only do what the filter lets through, and the filter — which must stay safe for any
north car within its assumptions (it may speed up at 2.5 m/s²) — holds the ego back in some
scenes where the hindsight oracle cuts in front. This script asks, scene by scene, whether
*some* open-loop sequence of learned actions clears the conflict zone within the episode under
the filter, with the scene known in advance (a bound no policy that sees only the present can
beat):

1. simple drivers: full throttle; the planner; a family "drive at a, coast from t1 to t2 (a = −1:
   the throttle closed), then full throttle" (a ∈ {1, 0.5, 0}, t1 ∈ 0…6 s, t2 − t1 ∈ 0.5…6 s);
2. for every scene none of them clears, the cross-entropy method over 24 actions (one per
   0.5 s), started from the best of step 1 (population 128, 16 elites, 12 rounds).

A scene still uncleared is one no searched sequence clears: evidence, not proof, that no
policy can (the search is finite). Run::

    python benchmarks/certified_ceiling.py [--config certified] [--default-zones] \
        [--episodes 1000] [--out benchmarks/results/certified_ceiling.json]

``--careful`` asks the same of a careful driver: the cross-entropy method on *every* scene,
each tick on which a sequence breaks a comfort limit, passes the speed limit or needs the
filter costing it 10 s — more than any difference in time to clear, so the ranking is: clear,
then the fewest such ticks, then soonest. It reports how many scenes a sequence clears
cleanly (no such tick), how many only by breaking a rule or leaning on the filter, and the
careful driver's efficiency against the oracle (a scene not cleared cleanly counts as never
cleared) — the ceiling of a policy that keeps the rules the shipped policies keep. Both
efficiencies (with ``--from``, the policy's own too) are also given per band of the north car's
arrival offset (``by_arrival_offset``), to show where a policy falls short of the search.

On a recipe whose learned action works both pedals (``env.controllers.learned_brake``) the
structured drivers keep their throttles (the action ``(a + 1) / 2``) and the search ranges over
both pedals.

``--default-zones`` puts the filter's default conflict zones (the ego within 0.6 m of its route,
1.2 m of margin) in place of the recipe's (``configs/certified.yaml``: 0.45 m and 0.9 m).
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path
from typing import Any

import numpy as np

import _common  # pins the numeric libraries to one thread first
from safeswitch.evaluation.search import (
    SEGMENT_S,
    drive_open_loop,
    family_of_drivers,
    policy_actions,
    rank_score,
    search_sequences,
)

EVAL_SEED = 1_000_003

#: Bands of the north car's arrival offset [s] in which ``--careful --from`` compares the
#: policy with the search (as experiments/probe_certified_bands.py splits the evaluation).
OFFSET_EDGES = (-10.0, -1.0, 1.0, 2.0, 2.5, 3.0, 3.5, 10.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="certified", help="a left-turn recipe (its env)")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=EVAL_SEED)
    parser.add_argument("--rounds", type=int, default=12)
    parser.add_argument("--population", type=int, default=128)
    parser.add_argument(
        "--default-zones", action="store_true",
        help="the filter's default zones instead of the recipe's",
    )  # fmt: skip
    parser.add_argument(
        "--careful", action="store_true",
        help="search every scene for a clear that breaks no rule and needs no filter",
    )  # fmt: skip
    parser.add_argument(
        "--from", dest="model", metavar="MODEL",
        help="with --careful: start each scene's search at this policy's own actions (one "
        "per decision; a shipped name or a run directory)",
    )  # fmt: skip
    parser.add_argument("--out", type=Path)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()

    from dataclasses import replace

    from safeswitch.evaluation.evaluate import run_controller, scenario_set
    from safeswitch.evaluation.planner import Planner
    from safeswitch.leftturn.config import CertifiedConfig
    from safeswitch.leftturn.spaces import throttle_driver
    from safeswitch.leftturn.task import LeftTurnTask
    from safeswitch.training.config import load_config

    started = time.perf_counter()
    env = load_config(args.config).env
    env = replace(env, episode=replace(env.episode, learned_scope="episode"))
    if args.default_zones:
        default = CertifiedConfig()
        zones = {"ego_max_lateral_m": default.ego_max_lateral_m,
                 "zone_margin_m": default.zone_margin_m}  # fmt: skip
        env = replace(env, certified=replace(env.certified, **zones))
    if env.switching != "certified":
        raise SystemExit(f"--config {args.config} trains under {env.switching!r}, not certified")
    task = LeftTurnTask(env)
    horizon = env.episode.horizon_s
    segments = round(horizon / SEGMENT_S)
    scenarios, _ = scenario_set(task, "random", args.episodes, args.seed)
    n = args.episodes
    planner, plan = run_controller(task, Planner(task), scenarios, trace=False)
    oracle_clear = np.asarray(plan.time_to_clear, dtype=float)

    if args.careful:
        _careful(task, scenarios, oracle_clear, segments, args, env, started)
        return

    drivers: dict[str, np.ndarray] = {}
    best_seq = np.ones((n, segments))
    clear, progress, _ = drive_open_loop(task, scenarios, np.ones((n, segments)))  # full throttle
    drivers["full throttle"] = clear
    best_score = rank_score(clear, progress, horizon)
    drivers["planner"] = np.asarray(planner.time_to_clear, dtype=float)
    to_scene = throttle_driver(task.config.controllers, "the coast-then-go drivers")

    family = to_scene(family_of_drivers(segments))
    left = np.flatnonzero(np.isnan(drivers["full throttle"]) & np.isnan(drivers["planner"]))
    family_clear = np.full(n, np.nan)
    if left.size:
        rows = np.repeat(left, len(family))
        seqs = np.tile(family, (left.size, 1))
        clear, progress, _ = drive_open_loop(task, scenarios.take(rows), seqs)
        score = rank_score(clear, progress, horizon).reshape(left.size, len(family))
        pick = score.argmin(axis=1)
        family_clear[left] = clear.reshape(left.size, len(family))[np.arange(left.size), pick]
        better = score[np.arange(left.size), pick] < best_score[left]
        best_score[left[better]] = score[np.arange(left.size), pick][better]
        best_seq[left[better]] = family[pick[better]]
    drivers["coast-then-go family"] = family_clear

    left = np.flatnonzero(
        np.isnan(drivers["full throttle"]) & np.isnan(drivers["planner"]) & np.isnan(family_clear)
    )
    search_clear = np.full(n, np.nan)
    if left.size:
        search_clear[left], _, _ = search_sequences(
            task, scenarios.take(left), best_seq[left], population=args.population,
            rounds=args.rounds, seed=args.seed, start_std=0.8, dirty_cost=0.0,
        )  # fmt: skip
    drivers["cross-entropy search"] = search_clear

    cleared_by_any = np.zeros(n, dtype=bool)
    for clear in drivers.values():
        cleared_by_any |= ~np.isnan(clear)
    never = np.flatnonzero(~cleared_by_any)
    result: dict[str, Any] = {
        "config": args.config,
        "episodes": n,
        "seed": args.seed,
        "switching": env.switching,
        "other_max_accel": env.certified.other_max_accel,
        "zone_margin_m": env.certified.zone_margin_m,
        "ego_max_lateral_m": env.certified.ego_max_lateral_m,
        "cleared": {name: int(np.sum(~np.isnan(c))) for name, c in drivers.items()},
        "searched": {
            "family": len(family),
            "rounds": args.rounds,
            "population": args.population,
        },
        "cleared_by_any": int(cleared_by_any.sum()),
        "oracle_cleared": int(np.sum(~np.isnan(oracle_clear))),
        "never_cleared": [
            {
                "scenario": int(i),
                "arrival_offset_s": round(float(scenarios.arrival_offset[i]), 3),
                "north_speed_kmh": round(3.6 * float(scenarios.north_speed[i]), 2),
                "ego_speed_kmh": round(3.6 * float(scenarios.ego_speed[i]), 2),
                "ego_start_distance_m": round(float(scenarios.ego_start_distance[i]), 2),
                "oracle_time_to_clear_s": round(float(oracle_clear[i]), 2),
            }
            for i in never
        ],
        "wall_time_s": round(time.perf_counter() - started, 1),
        "machine": _common.machine(),
    }
    if _common.publish(result, args.out, args.json):
        return
    print(f"{args.config}: under {env.switching} ({n} scenes, seed {args.seed})")
    for name, count in result["cleared"].items():
        print(f"  cleared by {name:24s} {count:5d}")
    share = result["cleared_by_any"] / n
    print(f"  cleared by any of them         {result['cleared_by_any']:5d}  ({share:.1%})")
    print(f"  never cleared                  {len(never):5d}  (the ceiling's complement)")
    for row in result["never_cleared"]:
        print(f"    #{row['scenario']:4d}: north {row['arrival_offset_s']:+.2f} s behind at "
              f"{row['north_speed_kmh']:.1f} km/h; ego {row['ego_speed_kmh']:.1f} km/h, "
              f"{row['ego_start_distance_m']:.1f} m out; oracle clears at "
              f"{row['oracle_time_to_clear_s']:.2f} s")  # fmt: skip
    print(f"  {result['wall_time_s']} s")


def _careful(
    task: Any, scenarios: Any, oracle_clear: np.ndarray, segments: int,
    args: argparse.Namespace, env: Any, started: float,
) -> None:  # fmt: skip
    """``--careful``: the search on every scene, and its table."""
    from safeswitch.evaluation.oracle import efficiency
    from safeswitch.leftturn.spaces import throttle_driver

    horizon = env.episode.horizon_s
    to_scene = throttle_driver(task.config.controllers, "the coast-then-go drivers")
    seeds, start, own, own_clear = to_scene(family_of_drivers(segments)), None, None, None
    if args.model:
        from safeswitch.training.policies import load_policy

        start, own_clear, own_dirty, _ = policy_actions(
            task, scenarios, load_policy(args.model).as_policy()
        )
        seeds = np.repeat(seeds, start.shape[1] // segments, axis=1)
        own = {
            "cleared": int(np.sum(~np.isnan(own_clear))),
            "cleared_cleanly": int(np.sum(~np.isnan(own_clear) & (own_dirty == 0))),
            "efficiency": round(float(np.nanmean(efficiency(oracle_clear, own_clear, horizon))), 4),
        }
    clear, dirty, _ = search_sequences(
        task, scenarios, start, population=args.population, rounds=args.rounds,
        seed=args.seed, seeds=seeds,
    )  # fmt: skip
    n = len(clear)
    cleared, clean = ~np.isnan(clear), ~np.isnan(clear) & (dirty == 0)
    careful_eff = efficiency(oracle_clear, np.where(clean, clear, np.inf), horizon)
    any_eff = efficiency(oracle_clear, np.where(cleared, clear, np.inf), horizon)
    result: dict[str, Any] = {
        "config": args.config,
        "mode": "careful",
        "episodes": n,
        "seed": args.seed,
        "switching": env.switching,
        "zone_margin_m": env.certified.zone_margin_m,
        "ego_max_lateral_m": env.certified.ego_max_lateral_m,
        "searched": {
            "rounds": args.rounds,
            "population": args.population,
            "segment_s": horizon / seeds.shape[1],
            "from": args.model,
        },
        "the_policy_itself": own,
        "cleared_cleanly": int(clean.sum()),
        "cleared_only_breaking_a_rule_or_with_the_filter": int((cleared & ~clean).sum()),
        "never_cleared": int((~cleared).sum()),
        "careful_efficiency": round(float(np.nanmean(careful_eff)), 4),
        "efficiency_of_the_best_found": round(float(np.nanmean(any_eff)), 4),
        "by_arrival_offset": _bands(
            scenarios.arrival_offset,
            oracle_clear,
            own_clear,
            np.where(clean, clear, np.inf),
            horizon,
        ),
        "dirty_scenes": [
            {
                "scenario": int(i),
                "arrival_offset_s": round(float(scenarios.arrival_offset[i]), 3),
                "north_speed_kmh": round(3.6 * float(scenarios.north_speed[i]), 2),
                "ego_speed_kmh": round(3.6 * float(scenarios.ego_speed[i]), 2),
                "time_to_clear_s": None if np.isnan(clear[i]) else round(float(clear[i]), 2),
                "dirty_ticks": int(dirty[i]),
            }
            for i in np.flatnonzero(~clean)
        ],
        "wall_time_s": round(time.perf_counter() - started, 1),
        "machine": _common.machine(),
    }
    if _common.publish(result, args.out, args.json):
        return
    print(f"{args.config}, a careful driver under {env.switching} ({n} scenes, seed {args.seed})")
    if own is not None:
        print(f"  {args.model} itself: cleared {own['cleared']}, cleanly {own['cleared_cleanly']}, "
              f"efficiency {own['efficiency']:.3f}; the search from its actions:")  # fmt: skip
    print(f"  cleared with no rule broken and no filter   {result['cleared_cleanly']:5d}")
    print(f"  cleared only breaking a rule or with it     "
          f"{result['cleared_only_breaking_a_rule_or_with_the_filter']:5d}")  # fmt: skip
    print(f"  never cleared                               {result['never_cleared']:5d}")
    print(f"  efficiency, careful (others: never cleared) {result['careful_efficiency']:.3f}")
    print(f"  efficiency, the best found                  "
          f"{result['efficiency_of_the_best_found']:.3f}")  # fmt: skip
    for band in result["by_arrival_offset"]:
        low, high = band["arrival_offset_s"]
        mine = "" if own is None else f"{args.model} {band['policy_efficiency']:.3f}, "
        print(f"  north car {low:+5.1f} to {high:+5.1f} s behind ({band['scenarios']:3d} scenes): "
              f"{mine}careful {band['careful_efficiency']:.3f}")  # fmt: skip
    print(f"  {result['wall_time_s']} s")


def _bands(
    offset: np.ndarray, oracle_clear: np.ndarray, own_clear: np.ndarray | None,
    careful_clear: np.ndarray, horizon: float,
) -> list[dict[str, Any]]:  # fmt: skip
    """Per band of :data:`OFFSET_EDGES`: the scenes, and the mean efficiency of the policy
    (with ``--from``) and of the careful driver (a scene it does not clear cleanly: never)."""
    from safeswitch.evaluation.oracle import efficiency

    careful = efficiency(oracle_clear, careful_clear, horizon)
    own = None if own_clear is None else efficiency(oracle_clear, own_clear, horizon)
    rows = []
    for low, high in itertools.pairwise(OFFSET_EDGES):
        band = (offset >= low) & (offset < high)
        row: dict[str, Any] = {
            "arrival_offset_s": [low, high],
            "scenarios": int(band.sum()),
            "careful_efficiency": round(float(np.nanmean(careful[band])), 4),
        }
        if own is not None:
            row["policy_efficiency"] = round(float(np.nanmean(own[band])), 4)
        rows.append(row)
    return rows


if __name__ == "__main__":
    main()
