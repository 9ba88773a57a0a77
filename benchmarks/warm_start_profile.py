"""Where the warm start's time goes: the teacher's labels, the rollouts around them, and the
fits of the actor (issue #18 asks for the profile of the warm start of the `paper_warm` recipe,
1,077 s of its 1,289).

Runs the warm start of a training configuration (default ``paper_warm``) with
``--episodes`` scenarios per round instead of the configured number, and extrapolates to the
configured size by the ratio: the fits and the rollouts are linear in the samples; the teacher's
calls are batched over the scenarios, so their extrapolated time is an upper bound. It times
each phase by wrapping it: the teacher's calls (the planner, or the gap planner in traffic:
labelling), the rest of the rollouts (the simulator, the
switching logic and, in the DAgger rounds, the clone's forward passes), and the fits (the
actor's epochs of Adam over all labels so far). One torch thread.

Run: ``python benchmarks/warm_start_profile.py [--config paper_warm] [--episodes 100] [--json]``;
writes ``benchmarks/results/warm_start_profile.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

import _common
from safeswitch.evaluation.planner import Planner
from safeswitch.evaluation.traffic_planner import GapPlanner
from safeswitch.io import write_json
from safeswitch.leftturn.vec_env import LeftTurnVecEnv
from safeswitch.training import warm_start as module
from safeswitch.training.config import load_config
from safeswitch.training.run import build_model, normalized

RESULTS = Path(__file__).parent / "results" / "warm_start_profile.json"


def timed(clock: dict[str, float], key: str, function: Any) -> Any:
    """``function`` adding its wall time to ``clock[key]``."""

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        began = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            clock[key] += time.perf_counter() - began

    return wrapper


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="paper_warm")
    parser.add_argument("--episodes", type=int, default=100, help="scenarios per round")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    config = load_config(args.config)
    configured = config.warm_start.episodes
    if configured == 0:
        parser.error(f"--config {args.config} has no warm start")
    config = replace(config, warm_start=replace(config.warm_start, episodes=args.episodes))
    torch.set_num_threads(1)
    vec = LeftTurnVecEnv(config.n_envs, config=config.env, seed=config.seed)
    env = normalized(vec, config, None)
    model = build_model(config, env, None)

    clock = {"teacher": 0.0, "rollouts": 0.0, "fits": 0.0}
    saved = module.rollout, module.fit_actor, Planner.__call__, GapPlanner.__call__
    module.rollout = timed(clock, "rollouts", module.rollout)  # type: ignore[assignment]
    module.fit_actor = timed(clock, "fits", module.fit_actor)  # type: ignore[assignment]
    for teacher in (Planner, GapPlanner):
        teacher.__call__ = timed(clock, "teacher", teacher.__call__)  # type: ignore[method-assign]
    try:
        report = module.warm_start(model, env, config)
    finally:
        module.rollout, module.fit_actor = saved[:2]  # type: ignore[assignment]
        Planner.__call__, GapPlanner.__call__ = saved[2:]  # type: ignore[method-assign]
    total = report["wall_time_s"]
    phases = {
        "labels (teacher calls)": clock["teacher"],
        "rollouts without the teacher (simulator, logic, clone)": clock["rollouts"]
        - clock["teacher"],
        "fits (actor epochs)": clock["fits"],
    }
    phases["other"] = total - sum(phases.values())
    scale = configured / args.episodes
    result = {
        "benchmark": "warm_start_profile",
        **_common.machine(),
        "config": args.config,
        "episodes_per_round": args.episodes,
        "configured_episodes_per_round": configured,
        "rounds": config.warm_start.rounds + 1,
        "epochs": config.warm_start.epochs,
        "samples": report["samples"],
        "wall_time_s": round(total, 2),
        "phases_s": {k: round(v, 2) for k, v in phases.items()},
        "phases_share": {k: round(v / total, 3) for k, v in phases.items()},
        "extrapolated_wall_time_s": round(total * scale, 0),
    }
    write_json(RESULTS, result)
    _common.emit(result, args.json)
    if not args.json:
        for name, seconds in phases.items():
            print(f"{name:58s} {seconds:8.1f} s  {seconds / total:6.1%}")
        print(f"at {configured} episodes per round: about {total * scale:,.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
