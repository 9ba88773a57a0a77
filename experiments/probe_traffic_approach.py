"""Would a braked approach to the junction let a controller beat the gap planner in traffic?
(issue #39; docs/learning_experiments.md, "A braked approach in traffic").

The gap planner waits by rolling towards a stop 4 m before the first crossing movement's zone,
never faster than a closed throttle (about 0.6 m/s² of it counted on) can still stop from: it is
a throttle-only driver. The shipped `traffic-certified` policy has a learned brake. A driver
that can brake may approach faster and stop closer, and be nearer the zone, and faster, when a
gap opens. This one-off probe (exact simulated go checks, no learning) drives the gap planner in
the recipe's scene (its zones, limiters and learned brake; each action held 0.3 s, as the
policy's) on the 1,000 `test` scenes of seed 1000003, its wait replaced by one that tracks
``sqrt(2 b room)`` — ``b`` the approach's deceleration, ``room`` the distance to where it stops
— with the brake wherever it is faster than that, and holds the brake at the stop
(`gap_planner.approach: brake`, safeswitch.evaluation.planner_config.GapPlannerConfig).

Then the best approach with a go check that sees only what a car could (`foresight: observed`),
and with each action held 0.1 s and every tick. ``--waits``: how the gap
planner, its braked approach and the shipped policy wait (speeds before the zone, where they
stand). ``--predictors MODEL.npz ...``: each go predictor (fitted on the recipe's observation
without one, e.g. by ``experiments/go_predictor.py --config
experimental/traffic_certified_go_scene``) as the planner's go check, coasting and braked, at
several thresholds (``--config NAME`` first: predictors on that configuration's observation).
Run: ``python experiments/probe_traffic_approach.py [--waits | --predictors [--config NAME]
MODEL ...]`` (one core: about 10, 2 and 1 minutes per model).
"""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from go_predictor import PredictedGo
from probe_go_rule import score_rules, test_scenes

from safeswitch.app.evaluate import controller_setup, fit_observations
from safeswitch.evaluation.evaluate import run_controller
from safeswitch.evaluation.planner_config import GapPlannerConfig
from safeswitch.evaluation.traffic_planner import GapPlanner
from safeswitch.leftturn.config import traffic_config
from safeswitch.leftturn.make import build_task
from safeswitch.training.config import load_config

#: The recipe whose scene the probe drives in.
RECIPE = "traffic_certified"

#: The approaches tried: (deceleration [m/s²], where it stops before the first zone [m]).
SWEEP = ((1.0, 4.0), (1.5, 3.0), (1.5, 4.0), (2.0, 4.0), (2.0, 5.0), (2.0, 6.0), (2.5, 2.0),
         (2.5, 4.0), (3.5, 2.0), (3.5, 1.0))  # fmt: skip

#: The go predictors' thresholds tried (``--predictors``).
THRESHOLDS = (0.05, 0.1, 0.2, 0.3, 0.5)

#: The sweep's best, then driven with each action held 5 ticks and every tick.
BEST = GapPlannerConfig(approach="brake", coast_decel=2.0, stop_extra_m=4.0)


def waits(episodes: int = 300) -> None:
    """How the gap planner, its braked approach and the shipped policy wait, on ``episodes``
    `test` scenes: their mean speed where the ego passes 20 and 10 m before the first crossing
    zone, and where the episodes in which the ego stands (below 0.3 m/s) before it stand
    nearest the zone (median, m before it)."""
    task, scenes = test_scenes(RECIPE, episodes)
    planner = GapPlanner(task)
    entry = planner.first_entry
    policy_config, policy = controller_setup("learned", "traffic-certified", None)
    policy_task = build_task(None, policy_config, traffic=task.traffic)
    drivers = (("gap planner", task, planner), ("braked approach", task, GapPlanner(task, BEST)),
               ("traffic-certified", policy_task,
                fit_observations(policy, "traffic-certified", policy_task)))  # fmt: skip
    for name, driven, driver in drivers:
        progress, speed = [], []

        def record(state, step, tick, progress=progress, speed=speed):
            progress.append(state.world.progress[:, 0].copy())
            speed.append(state.world.vehicles.speed[:, 0].copy())

        run_controller(driven, driver, scenes, on_tick=record, trace=False)
        room, v = entry - np.array(progress), np.array(speed) * 3.6
        at = {d: [v[np.argmax(room[:, b] <= d), b] for b in range(episodes)
                  if (room[:, b] <= d).any()] for d in (20, 10)}  # fmt: skip
        standing = (v < 0.3 * 3.6) & (room > 0)
        nearest = [room[standing[:, b], b].min() for b in range(episodes) if standing[:, b].any()]
        print(f"{name}: {np.mean(at[20]):.1f} km/h 20 m before the zone, {np.mean(at[10]):.1f} "
              f"km/h 10 m before; stands in {len(nearest)} of {episodes} scenes, nearest the "
              f"zone {np.median(nearest):.1f} m before it (median)", flush=True)  # fmt: skip


def predictors(paths: list[str], observation: str = RECIPE) -> None:
    """Each go predictor of ``paths`` (``.npz``, fitted on the observation of the configuration
    ``observation`` without a predictor) as the gap planner's go check in the recipe's scene,
    coasting and braked, on the 1,000 `test` scenes."""
    observed = traffic_config(load_config(observation).traffic)
    for path in paths:
        seen = replace(observed, go_model=str(Path(path).resolve()))
        task, scenes = test_scenes(RECIPE, seen=seen)
        rules = [(f"{path} > {threshold}, {label}", PredictedGo(task, threshold, config=tuning))
                 for threshold in THRESHOLDS
                 for label, tuning in (("coast", None), ("braked approach", BEST))]  # fmt: skip
        score_rules(task, rules, scenes)


def main() -> None:
    if sys.argv[1:] == ["--waits"]:
        waits()
        return
    if sys.argv[1:2] == ["--predictors"]:
        if sys.argv[2:3] == ["--config"]:  # the predictors' observation: another recipe's
            predictors(sys.argv[4:], sys.argv[3])
        else:
            predictors(sys.argv[2:])
        return
    task, scenes = test_scenes(RECIPE)
    rules = [("gap planner (a closed throttle's approach, 0.6 m/s², 4 m before)", GapPlanner(task))]
    for decel, extra in SWEEP:
        name = f"braked approach at {decel} m/s², {extra} m before the zone"
        tuning = GapPlannerConfig(approach="brake", coast_decel=decel, stop_extra_m=extra)
        rules.append((name, GapPlanner(task, tuning)))
    seen = replace(BEST, foresight="observed")  # only the vehicles in the scene, none yielding
    rules.append(("braked approach at 2.0 m/s², 4.0 m, its check seeing only what a car could",
                  GapPlanner(task, seen)))  # fmt: skip
    score_rules(task, rules, scenes)
    for ticks in (5, 1):
        held, scenes = test_scenes(RECIPE, decision_interval=ticks)
        name = f"braked approach at 2.0 m/s², 4.0 m before, each action held {ticks} ticks"
        score_rules(held, [(name, GapPlanner(held, BEST))], scenes)


if __name__ == "__main__":
    main()
