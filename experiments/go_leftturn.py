"""The single-car scene's learned go predictor (issue #39; docs/learning_experiments.md, "A
go predictor for the left turn"; ``episode.go_model``), as ``experiments/go_predictor.py`` is
the traffic recipe's.

Random drivers (each episode a random pedal around a random bias, redrawn with probability
0.3 at each decision) drive the recipe's scene (scene seeds 7001 and 7101, which no run trains
on); every decision still before the ego's certified conflict zone is a sample, labelled with
whether the planners' fast drive from that state clears the zone with no collision and without
the certified filter acting — the gap planner's go check
(:func:`~safeswitch.evaluation.planner.drive_passes`), here in the paper's scene: the north car
alone, no vehicles still to come. The predictor is fitted as ``experiments/go_predictor.py``
fits it (a 2 x 64 tanh MLP on the standardised observation, binary cross-entropy). No
controller's action is a label.

Run: ``python experiments/go_leftturn.py --out experiments/go_model_leftturn_plain.npz`` (one
torch thread, about 25 s); ``--config`` names the recipe whose scene and observation it reads
(default ``certified``; its own ``episode.go_model`` is left out); ``--drivers RUN`` adds as
many batches of the states a run trained with a predictor drives through (scene seeds 7401 and
7501), for a DAgger-like second round.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from io import BytesIO
from pathlib import Path

import numpy as np

from safeswitch.evaluation.planner import FastDrive, drive_passes, throttle_scene
from safeswitch.evaluation.rollout import rollout
from safeswitch.evaluation.traffic_planner import GapPlannerConfig
from safeswitch.io import write_bytes_atomic
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.training.config import load_config

sys.path.insert(0, str(Path(__file__).parent))
from go_predictor import RandomDrivers, fit  # the traffic predictor's drivers and fit


def samples(
    config: str, seed: int, episodes: int, drivers: Path | None = None
) -> tuple[np.ndarray, ...]:
    """Observations, labels and episode ids of random drivers' decisions before the zone, or
    (``drivers``: a run trained with a predictor) of that policy's, its action plus a pedal
    noise drawn per episode (none in half of them): a DAgger-like round for the predictor,
    still no action labels."""
    cfg = load_config(config)
    # the observation the predictor reads is the one before its own probability
    env = dataclasses.replace(cfg.env, episode=dataclasses.replace(cfg.env.episode, go_model=None))
    task = build_task(None, env)
    policy = None
    if drivers is not None:
        from safeswitch.training.policies import load_policy

        trained = load_policy(drivers)
        policy = trained.as_policy()
        task = build_task(None, trained.config.env)  # its observation ends with its predictor
    c = GapPlannerConfig()
    drive = FastDrive(task, c.top_speed_kmh, c.accel_lat, c.curve_decel, c.preview_s,
                      c.speed_gain)  # fmt: skip
    check = LeftTurnTask(dataclasses.replace(throttle_scene(task.config), switching="certified"))
    entry, exit_at = task.north_conflict.ego_cert_zone
    horizon = task.config.episode.horizon_ticks
    rng = np.random.default_rng(seed)
    ids = np.arange(episodes)
    scenes = task.draw_scenarios(seed, ids, np.zeros_like(ids))
    random_drivers = RandomDrivers(rng, episodes)
    if policy is not None:  # (drawn only then: the random drivers' draws stay as they were)
        noise = rng.uniform(0.0, 0.4, episodes) * (rng.random(episodes) < 0.5)
    width = build_task(None, env).observation_bounds[0].shape[0]
    live = np.ones(episodes, dtype=bool)
    rows_x: list[np.ndarray] = []
    rows_y: list[np.ndarray] = []
    rows_g: list[np.ndarray] = []
    interval = task.config.episode.decision_interval

    action = random_drivers.action

    def act(obs, state, tick):  # type: ignore[no-untyped-def]
        nonlocal action
        if tick % interval == 0:
            rows = np.flatnonzero(live & (state.world.progress[:, 0] <= entry))
            if rows.size:
                part = state.take(rows)
                ok = drive_passes(check, part, np.arange(rows.size), exit_at, horizon,
                                  lambda now, t: drive.action(now, t))  # fmt: skip
                rows_x.append(obs[rows, :width].copy())
                rows_y.append(ok)
                rows_g.append(rows)
            if policy is not None:
                pedal = policy(obs, state, tick) + noise * rng.standard_normal(episodes)
                action = np.clip(pedal, -1.0, 1.0)
            else:
                action = random_drivers.next()
        return action.astype(np.float64)

    def on_tick(state, record, tick):  # type: ignore[no-untyped-def]
        live[:] &= ~(record.terminated | record.truncated)

    rollout(task, scenes, act, on_tick)
    return np.concatenate(rows_x), np.concatenate(rows_y), np.concatenate(rows_g)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="certified")
    parser.add_argument("--seed", type=int, default=7001)
    parser.add_argument("--episodes", type=int, default=1024)
    parser.add_argument("--batches", type=int, default=2)
    parser.add_argument("--epochs", type=int, default=30)
    parser.add_argument("--hidden", type=int, default=64)
    parser.add_argument(
        "--drivers",
        type=Path,
        default=None,
        metavar="RUN",
        help="also sample as many batches (scene seeds from seed + 400) of this run's policy, "
        "its action plus a pedal noise",
    )
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    start = time.time()
    seeds = [args.seed + 100 * b for b in range(args.batches)]
    parts = [samples(args.config, s, args.episodes) for s in seeds]
    if args.drivers is not None:
        driven = [args.seed + 400 + 100 * b for b in range(args.batches)]
        parts += [samples(args.config, s, args.episodes, args.drivers) for s in driven]
        seeds += driven
    x = np.concatenate([p[0] for p in parts])
    y = np.concatenate([p[1] for p in parts])
    g = np.concatenate([p[2] + b * args.episodes for b, p in enumerate(parts)])
    sampled = time.time() - start
    model = fit(x, y, g, args.epochs, args.seed, args.hidden)
    buffer = BytesIO()
    np.savez(buffer, **model["weights"])
    write_bytes_atomic(args.out, buffer.getvalue())
    drivers = "random" + (f", then {args.drivers}" if args.drivers else "")
    report = {"config": args.config, "scene_seeds": seeds, "drivers": drivers,
              "episodes": int(g.max()) + 1, "hidden": args.hidden, "epochs": args.epochs,
              "sampling_s": round(sampled, 1), "scores": model["scores"]}  # fmt: skip
    text = json.dumps(report, indent=2) + "\n"
    print(text, end="")
    write_bytes_atomic(args.out.with_suffix(".json"), text.encode())


if __name__ == "__main__":
    main()
