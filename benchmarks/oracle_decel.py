"""How much of the oracle's speed comes from the brakes: its mean time to clear on the README's
1,000 random evaluation scenarios with its deceleration capped at the plant's brakes and comfort
limit (the default), 2.0 m/s², and 1.2 m/s² (what a closed throttle alone gives the learned
controller, which has no brake pedal).

Run: ``python benchmarks/oracle_decel.py [--json]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

import _common
from safeswitch.app.reproduce import EVAL_SEED
from safeswitch.evaluation.oracle import Oracle, OracleLimits
from safeswitch.leftturn.config import resolve_config
from safeswitch.leftturn.task import LeftTurnTask


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--episodes", type=int, default=1000)
    args = parser.parse_args(argv)
    task = LeftTurnTask(resolve_config(switching="none", adas_penalty=False))
    n = args.episodes
    scenarios = task.scenario_set(EVAL_SEED, n)
    limits = OracleLimits.from_config(task.config)
    rows = []
    for decel in (limits.max_decel, 2.0, 1.2):
        plan = Oracle(task, dataclasses.replace(limits, max_decel=decel)).plan(scenarios)
        rows.append(
            {
                "max_decel": decel,
                "mean_time_to_clear_s": float(np.nanmean(plan.time_to_clear)),
                "cut_episodes": int((plan.outcome == 1).sum()),
            }
        )
    if args.json:
        _common.emit({"benchmark": "oracle_decel", "episodes": n, "rows": rows}, True)
        return 0
    print(f"oracle on {n} random scenarios (seed {EVAL_SEED})")
    for r in rows:
        print(
            f"  max decel {r['max_decel']:.1f} m/s²: mean time to clear "
            f"{r['mean_time_to_clear_s']:.2f} s, {r['cut_episodes']} cut first"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
