"""Where a guarded-trained policy collides when deployed under the paper's logic alone.

For each ``--model`` (a run directory trained under ``guarded``) on the README's 1,000 unseen
scenarios (seed 1000003): the policy is driven once under ``guarded`` — recording, episode by
episode, which of the pair's reasons acted, among them the ones where the certified filter
overruled the paper logic's *own* safety action (``guard:…:overrules_primary``) — and once
under ``paper`` alone, recording which episodes collided. Each reason's row says in how many
episodes it acted and how many of those collided under ``paper``; the last line says how many
of the collisions under ``paper`` fall in an episode with an overrule.

With ``--throttle`` instead, each "policy" is a constant throttle, driven with the shipped
``paper`` recipe's environment (``configs/paper.yaml``): how broad a sign of a collision under
``paper`` the overrule is for a behaviour that is the same under both logics
(``docs/learning_experiments.md``, "Rare collisions under ``paper``").

Run: ``python benchmarks/overrule_trace.py --model RUN [RUN ...] [--json] [--out FILE]``
(about 40 s per policy); a run is ``safeswitch train --config
experimental/scratch_shaped_guarded --seed N --out RUN`` or any other run trained under
``guarded``. ``benchmarks/results/overrule_trace.json`` holds that recipe's seeds 2 and 3 (its
runs that collide under ``paper``; seed 1 does not), as ``runs/scratch_shaped_guarded_s2`` and
``_s3``. ``python benchmarks/overrule_trace.py --throttle 0.3 0.6 1.0 --episodes 2000 --seed
8000009 --out benchmarks/results/overrule_breadth.json`` (about 5 s per throttle).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

import numpy as np

import _common
from safeswitch.evaluation.rollout import Policy, rollout
from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.task import StepRecord, build_task
from safeswitch.training.config import load_config
from safeswitch.training.policies import load_policy

SEED, EPISODES = 1_000_003, 1000
OVERRULES = ":overrules_primary"


def drive(
    env: LeftTurnConfig, switching: str, policy: Policy, seed: int, episodes: int
) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """``policy`` under ``switching`` on ``episodes`` random scenarios of ``seed``: the
    logic's reasons, which of them acted in each episode until it ended
    (``[episodes, reasons]``), and which episodes collided."""
    task = build_task(None, dataclasses.replace(env, switching=switching))
    scenarios = task.scenario_set(seed, episodes)
    hit = np.zeros((episodes, len(task.reasons)), dtype=bool)
    live = np.ones(episodes, dtype=bool)

    def record(state: Any, rec: StepRecord, tick: int) -> None:
        on = np.flatnonzero(rec.safety_active & live)
        hit[on, rec.reason[on]] = True
        live[rec.terminated | rec.truncated] = False

    result = rollout(task, scenarios, policy, record)
    return task.reasons, hit, np.asarray(result.collision, dtype=bool)


def trace(
    name: str, env: LeftTurnConfig, policy: Policy, seed: int, episodes: int
) -> dict[str, Any]:
    """The reasons that acted per episode under ``guarded``, and the collisions under ``paper``."""
    reasons, hit, guarded_collisions = drive(env, "guarded", policy, seed, episodes)
    _, _, collisions = drive(env, "paper", policy, seed, episodes)
    overruled = hit[:, [i for i, r in enumerate(reasons) if r.endswith(OVERRULES)]].any(axis=1)
    guarded = hit[:, [i for i, r in enumerate(reasons) if r.startswith("guard:")]].any(axis=1)
    return {
        "model": name,
        "collisions_under_guarded": int(guarded_collisions.sum()),
        "collisions_under_paper": int(collisions.sum()),
        "reasons": {
            r: {
                "episodes": int(hit[:, i].sum()),
                "collided_under_paper": int((hit[:, i] & collisions).sum()),
            }
            for i, r in enumerate(reasons)
            if hit[:, i].any()
        },
        "episodes_with_the_guard": int(guarded.sum()),
        "episodes_with_an_overrule": int(overruled.sum()),
        "paper_collisions_in_them": int((overruled & collisions).sum()),
    }


def constant(throttle: float, episodes: int) -> Policy:
    """A learned controller that always asks for ``throttle``."""
    action = np.full(episodes, 2.0 * throttle - 1.0)  # the learned action in [-1, 1]
    return lambda observation, state, tick: action


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--model", nargs="+", help="run directories trained under guarded")
    what.add_argument("--throttle", type=float, nargs="+", help="constant throttles in [0, 1]")
    parser.add_argument("--episodes", type=int, default=EPISODES)
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--out", type=Path, help="also write the JSON to this file")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.throttle is not None:
        bad = [t for t in args.throttle if not (np.isfinite(t) and 0.0 <= t <= 1.0)]
        if bad:
            parser.error(f"--throttle must be in [0, 1], got {bad}")
        env = load_config("paper").env
        rows = [
            trace(f"throttle {t}", env, constant(t, args.episodes), args.seed, args.episodes)
            for t in args.throttle
        ]
    else:
        rows = [
            trace(run, load_config(f"{run}/config.yaml").env, load_policy(run).as_policy(),
                  args.seed, args.episodes)
            for run in args.model
        ]  # fmt: skip
    result = {
        "benchmark": "overrule_trace", **_common.machine(), "seed": args.seed,
        "episodes": args.episodes, "runs": rows,
    }  # fmt: skip
    if _common.publish(result, args.out, args.json):
        return 0
    for row in rows:
        print(f"{row['model']}: {row['collisions_under_paper']} collisions under paper "
              f"({row['collisions_under_guarded']} under guarded)")  # fmt: skip
        for reason, n in row["reasons"].items():
            print(f"  {reason:42s} {n['episodes']:5d} episodes, "
                  f"{n['collided_under_paper']:3d} of them collide under paper")  # fmt: skip
        print(f"  with the guard: {row['episodes_with_the_guard']} episodes; with an overrule: "
              f"{row['episodes_with_an_overrule']}, holding {row['paper_collisions_in_them']} of "
              f"the {row['collisions_under_paper']} collisions under paper")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
