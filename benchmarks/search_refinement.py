"""Search-guided refinement of a trained left-turn policy under `certified` (a probe, issue #39).

A probe for docs/learning_experiments.md ("A careful driver's ceiling, and search-guided
refinement"), not a stage of the training pipeline. The scene is
deterministic given its start (the north car holds its speed), so a policy's actions replayed
open loop drive exactly its episode, and a trajectory search can start from them. Each
iteration (ours; the idea is expert iteration / guided policy search with a sampling
optimiser):

1. the policy drives ``--scenes`` fresh training scenarios (the run's training seed, ids no
   training environment uses) under `certified`;
2. where it fails — never clears, or breaks a comfort limit, passes the speed limit or needs the
   filter on some tick — the cross-entropy search of ``benchmarks/certified_ceiling.py
   --careful`` starts from its actions (population 128, ``--rounds``); where the search clears
   with at most ``--allow-dirty`` such ticks, its actions become the labels;
3. on ``--speed-scenes`` of the scenes it drives cleanly, a cheaper search (population 32, 6
   rounds) looks for a clean clear at least 0.1 s sooner; found, its actions become the labels
   (with ``--margin m``, an improved sequence of steps 2 and 3 is kept only if it stays as
   clean with ``m`` more throttle on every decision: a label the fitted policy may overshoot
   a little);
4. the actor's mean is fitted (mean squared error, Adam, ``--epochs`` passes, step ``--lr``) to
   the labels at the observations they drive through — the policy's own actions everywhere
   else, so it keeps what it does well — the improved scenes repeated ``--weight`` times;
5. the policy is evaluated on the 1,000 unseen scenarios (seed 1000003) under `certified`.

Every iteration's evaluation is printed (none is selected on it). Run::

    python benchmarks/search_refinement.py --model certified [--seed 1] [--iters 4] \\
        [--out benchmarks/results/search_refinement_seed1.json]

One torch thread.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

import _common  # pins the numeric libraries to one thread first
import certified_ceiling as ceiling

EVAL_SEED = 1_000_003
REFINE_ENV_OFFSET = 5_000_000  # scenario ids of the refinement's scenes (training seed)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="certified", help="a shipped name or a run dir")
    parser.add_argument("--config", default="certified", help="the recipe whose env it drives")
    parser.add_argument("--scenes", type=int, default=2000)
    parser.add_argument("--iters", type=int, default=4)
    parser.add_argument("--rounds", type=int, default=12)
    parser.add_argument("--speed-scenes", type=int, default=600)
    parser.add_argument("--allow-dirty", type=int, default=0)
    parser.add_argument("--weight", type=int, default=5)
    parser.add_argument(
        "--margin", type=float, default=0.0,
        help="keep an improved sequence only if it also stays within --allow-dirty (a sped-up "
        "one: clean) with this much more throttle on every decision",
    )  # fmt: skip
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--lr", type=float, default=1e-4)
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
    from safeswitch.evaluation.rollout import rollout
    from safeswitch.leftturn.task import LeftTurnTask
    from safeswitch.training.config import load_config
    from safeswitch.training.policies import load_policy
    from safeswitch.training.warm_start import fit_actor

    torch.set_num_threads(1)
    started = time.perf_counter()
    env = load_config(args.config).env
    env = replace(env, episode=replace(env.episode, learned_scope="episode"))
    if env.switching != "certified":
        raise SystemExit(f"--config {args.config} trains under {env.switching!r}, not certified")
    task = LeftTurnTask(env)
    interval = env.episode.decision_interval
    decisions = env.episode.horizon_ticks // interval
    policy = load_policy(args.model)
    test, _ = scenario_set(task, "random", 1000, EVAL_SEED)
    keys = ("collisions", "safety_activation_episodes", "cleared_episodes", "mean_efficiency",
            "comfort_violation_fraction", "speeding_episodes", "max_speed_kmh")  # fmt: skip

    def evaluate() -> dict[str, Any]:
        result, plan = run_controller(task, policy.as_policy(), test, trace=False)
        summary = summary_against_oracle(result, plan, env.episode.horizon_s)
        return {k: summary[k] for k in keys}

    def observed(scenarios: Any, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The observation at each decision of ``labels`` driven open loop, and which
        decisions fall before the episode's end."""
        size = int(np.prod(task.observation_bounds[0].shape))
        obs = np.zeros((len(labels), decisions, size), np.float32)

        def drive(o: Any, state: Any, tick: int) -> np.ndarray:
            obs[:, tick // interval] = o
            return labels[:, tick // interval]

        result = rollout(task, scenarios, drive)
        assert not result.collision.any(), "a collision under certified: the filter is broken"
        alive = np.arange(decisions)[None, :] * interval < result.ticks[:, None]
        return obs, alive

    def robust(scenarios: Any, seqs: np.ndarray, allowed: int) -> np.ndarray:
        """Which sequences stay within ``allowed`` dirty ticks with ``--margin`` more
        throttle (all, without a margin)."""
        if args.margin <= 0:
            return np.ones(len(seqs), dtype=bool)
        pushed = np.clip(seqs + args.margin, -1.0, 1.0)
        _, _, dirty = ceiling.drive_open_loop(task, scenarios, pushed)
        return np.asarray(dirty <= allowed)

    rows: list[dict[str, Any]] = [{"iteration": 0, "evaluation": evaluate()}]
    print(f"before: {rows[0]['evaluation']}", flush=True)
    seeds = np.repeat(ceiling.family_of_drivers(24), decisions // 24, axis=1)
    for it in range(1, args.iters + 1):
        ids = REFINE_ENV_OFFSET * it + np.arange(args.scenes)
        scenes = task.draw_scenarios(args.seed, ids, np.zeros(args.scenes, dtype=np.int64))
        actions = ceiling.policy_actions(task, scenes, policy.as_policy())
        clear, _, dirty = ceiling.drive_open_loop(task, scenes, actions)
        failing = np.flatnonzero(np.isnan(clear) | (dirty > 0))
        search = SimpleNamespace(seed=args.seed + it, population=128, rounds=args.rounds)
        f_clear, f_dirty, f_seqs = ceiling.search_sequences(
            task, scenes.take(failing), actions[failing], search, seeds=seeds
        )
        fixed = ~np.isnan(f_clear) & (f_dirty <= args.allow_dirty)
        fixed &= robust(scenes.take(failing), f_seqs, args.allow_dirty)
        labels, weight = actions.copy(), np.ones(args.scenes, dtype=int)
        labels[failing[fixed]] = f_seqs[fixed]
        weight[failing[fixed]] = args.weight
        clean = np.setdiff1d(np.arange(args.scenes), failing)[: args.speed_scenes]
        quick = SimpleNamespace(seed=args.seed + it, population=32, rounds=6)
        s_clear, s_dirty, s_seqs = ceiling.search_sequences(
            task, scenes.take(clean), actions[clean], quick, seeds=seeds
        )
        faster = ~np.isnan(s_clear) & (s_dirty == 0) & (s_clear < clear[clean] - 0.1)
        faster &= robust(scenes.take(clean), s_seqs, 0)
        labels[clean[faster]] = s_seqs[faster]
        weight[clean[faster]] = args.weight
        obs, alive = observed(scenes, labels)
        take = np.repeat(np.arange(args.scenes), weight)
        x = policy.normalise(obs[take][alive[take]]).astype(np.float32)
        y = labels[take][alive[take]].astype(np.float32)
        mse = fit_actor(policy.model, x, y, args.epochs, args.lr)
        row = {
            "iteration": it,
            "failing": int(failing.size),
            "fixed": int(fixed.sum()),
            "sped_up": int(faster.sum()),
            "sped_up_by_s": round(float(np.mean(clear[clean][faster] - s_clear[faster])), 3)
            if faster.any()
            else 0.0,
            "samples": len(x),
            "mse": round(mse, 5),
            "evaluation": evaluate(),
            "wall_time_s": round(time.perf_counter() - started, 1),
        }
        rows.append(row)
        print(row, flush=True)
    result = {
        "model": args.model,
        "config": args.config,
        "args": {k: v for k, v in vars(args).items() if k != "out"},
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
