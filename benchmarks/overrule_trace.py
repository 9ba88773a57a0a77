"""Where a guarded-trained policy collides when deployed under the paper's logic alone.

For each ``--model`` (a run directory trained under ``guarded``) on the README's 1,000 unseen
scenarios (seed 1000003): the policy is driven once under ``guarded`` — recording, episode by
episode, which of the pair's reasons acted, among them the ones where the certified filter
overruled the paper logic's *own* safety action (``guard:…:overrules_primary``) — and once
under ``paper`` alone, recording which episodes collided. Each reason's row says in how many
episodes it acted and how many of those collided under ``paper``; the last line says how many
of the collisions under ``paper`` fall in an episode with an overrule.

Run: ``python benchmarks/overrule_trace.py --model RUN [RUN ...] [--json] [--out FILE]``
(about 40 s per policy); a run is ``safeswitch train --config
experimental/scratch_shaped_guarded --seed N --out RUN`` or any other run trained under
``guarded``. ``benchmarks/results/overrule_trace.json`` holds that recipe's seeds 2 and 3 (its
runs that collide under ``paper``; seed 1 does not), as ``runs/scratch_shaped_guarded_s2`` and
``_s3``.
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
from safeswitch.leftturn.task import StepRecord, build_task
from safeswitch.training.config import load_config
from safeswitch.training.policies import load_policy

SEED, EPISODES = 1_000_003, 1000
OVERRULES = ":overrules_primary"


def drive(run: str, switching: str) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """The run's policy under ``switching``: its reasons, which of them acted in each episode
    (``[episodes, reasons]``), and which episodes collided."""
    env = load_config(f"{run}/config.yaml").env
    task = build_task(None, dataclasses.replace(env, switching=switching))
    scenarios = task.draw_scenarios(SEED, np.arange(EPISODES), np.zeros(EPISODES, dtype=int))
    hit = np.zeros((EPISODES, len(task.reasons)), dtype=bool)

    def record(state: Any, rec: StepRecord, tick: int) -> None:
        on = np.flatnonzero(rec.safety_active)
        hit[on, rec.reason[on]] = True

    result = rollout(task, scenarios, load_policy(run).as_policy(), record)
    return task.reasons, hit, np.asarray(result.collision, dtype=bool)


def trace(run: str) -> dict[str, Any]:
    """The reasons that acted per episode under ``guarded``, and the collisions under ``paper``."""
    reasons, hit, guarded_collisions = drive(run, "guarded")
    _, _, collisions = drive(run, "paper")
    overruled = hit[:, [i for i, r in enumerate(reasons) if r.endswith(OVERRULES)]].any(axis=1)
    return {
        "model": run,
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
        "episodes_with_an_overrule": int(overruled.sum()),
        "paper_collisions_in_them": int((overruled & collisions).sum()),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", nargs="+", required=True, help="run directories")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--out", type=Path, help="also write the JSON to this file")
    args = parser.parse_args(argv)
    rows = [trace(run) for run in args.model]
    result = {"benchmark": "overrule_trace", **_common.machine(), "seed": SEED, "runs": rows}
    if _common.publish(result, args.out, args.json):
        return 0
    for row in rows:
        print(f"{row['model']}: {row['collisions_under_paper']} collisions under paper "
              f"({row['collisions_under_guarded']} under guarded)")  # fmt: skip
        for reason, n in row["reasons"].items():
            print(f"  {reason:42s} {n['episodes']:5d} episodes, "
                  f"{n['collided_under_paper']:3d} of them collide under paper")  # fmt: skip
        print(f"  with an overrule: {row['episodes_with_an_overrule']} episodes, holding "
              f"{row['paper_collisions_in_them']} of the {row['collisions_under_paper']} "
              "collisions under paper")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
