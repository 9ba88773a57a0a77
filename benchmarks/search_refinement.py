"""Search-guided refinement of a finished left-turn policy under `certified`, each iteration
evaluated on the 1,000 unseen scenarios (issue #39).

The pipeline's last stage (``refine:`` in a recipe; :mod:`safeswitch.training.refine`, whose
docstring has the steps) run on any trained policy, with every iteration's evaluation on the
test scenarios printed — a probe for docs/learning_experiments.md; none is selected on it.
Run::

    python benchmarks/search_refinement.py --model certified [--seed 1] [--iters 3] \\
        [--scenes 1000] [--rounds 8] [--speed-scenes 300] [--knot 5] \\
        [--out benchmarks/results/search_refinement_seed1.json] [--save DIR]

The first records of the learning log were made with ``--scenes 2000 --rounds 12
--speed-scenes 600 --knot 1`` (the defaults then); ``--margin`` (an improved sequence kept only
if it stays as clean with more throttle on every decision) was a flag of this script up to
commit 882680a. One torch thread.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import _common  # pins the numeric libraries to one thread first

EVAL_SEED = 1_000_003


def main() -> None:
    from safeswitch.training.config import RefineConfig

    defaults = RefineConfig()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="certified", help="a shipped name or a run dir")
    parser.add_argument("--config", default="certified", help="the recipe whose env it drives")
    parser.add_argument("--iters", type=int, default=3)
    parser.add_argument("--scenes", type=int, default=defaults.scenes)
    parser.add_argument("--rounds", type=int, default=defaults.rounds)
    parser.add_argument("--speed-scenes", type=int, default=defaults.speed_scenes)
    parser.add_argument("--knot", type=int, default=defaults.knot)
    parser.add_argument("--weight", type=int, default=defaults.weight)
    parser.add_argument("--epochs", type=int, default=defaults.epochs)
    parser.add_argument("--lr", type=float, default=defaults.learning_rate)
    parser.add_argument("--seed", type=int, default=1, help="the training seed's scenes")
    parser.add_argument("--out", type=Path)
    parser.add_argument(
        "--save", type=Path, metavar="DIR",
        help="write the refined policy as a run folder (model.zip, vecnormalize.pkl and the "
        "source run's config.yaml): `safeswitch evaluate --model DIR` loads it",
    )  # fmt: skip
    args = parser.parse_args()

    import torch

    from safeswitch.evaluation.evaluate import run_controller, scenario_set, summary_against_oracle
    from safeswitch.leftturn.task import LeftTurnTask
    from safeswitch.training.config import load_config
    from safeswitch.training.policies import load_policy
    from safeswitch.training.refine import refine_iteration

    torch.set_num_threads(1)
    started = time.perf_counter()
    refine = replace(
        defaults, iterations=args.iters, scenes=args.scenes, rounds=args.rounds,
        speed_scenes=args.speed_scenes, knot=args.knot, weight=args.weight, epochs=args.epochs,
        learning_rate=args.lr,
    )  # fmt: skip
    env = load_config(args.config).env
    env = replace(env, episode=replace(env.episode, learned_scope="episode"))
    if env.switching != "certified":
        raise SystemExit(f"--config {args.config} trains under {env.switching!r}, not certified")
    task = LeftTurnTask(env)
    policy = load_policy(args.model)
    test, _ = scenario_set(task, "random", 1000, EVAL_SEED)
    keys = ("collisions", "safety_activation_episodes", "cleared_episodes", "mean_efficiency",
            "comfort_violation_fraction", "speeding_episodes", "max_speed_kmh")  # fmt: skip

    def evaluate() -> dict[str, Any]:
        result, plan = run_controller(task, policy.as_policy(), test, trace=False)
        summary = summary_against_oracle(result, plan, env.episode.horizon_s)
        return {k: summary[k] for k in keys}

    rows: list[dict[str, Any]] = [{"iteration": 0, "evaluation": evaluate()}]
    print(f"before: {rows[0]['evaluation']}", flush=True)
    for it in range(1, args.iters + 1):
        row = {"iteration": it, **refine_iteration(task, policy, refine, args.seed, it)}
        row["evaluation"] = evaluate()
        row["wall_time_s"] = round(time.perf_counter() - started, 1)
        rows.append(row)
        print(row, flush=True)
    result = {
        "model": args.model,
        "config": args.config,
        "args": {k: v for k, v in vars(args).items() if k not in ("out", "save")},
        "iterations": rows,
        "machine": _common.machine(),
    }
    if args.save is not None:
        import shutil

        from safeswitch.io import write_policy_files
        from safeswitch.training.policies import run_config_path

        args.save.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(run_config_path(policy.path), args.save / "config.yaml")
        write_policy_files(args.save, policy.model, policy.normalizer)
    _common.publish(result, args.out, False)


if __name__ == "__main__":
    main()
