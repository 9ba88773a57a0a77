"""Drivers that try to crash, under each highway-env switching logic.

Three adversaries (``safeswitch.examples.highway_drivers.Adversary``: uniformly random actions,
a weaving driver at full throttle with sudden lane changes, a brake-checker) drive
``safeswitch/Highway-v0`` under each ``--logics`` value, ``--episodes`` episodes each (reset
seeds from ``--seed``); reported per pair: crashes, off-road episodes and the share of steps on
which the Safety controller acted. One process per logic.

Run: ``python benchmarks/highway_adversaries.py [--logics ttc certified] [--episodes 150]
[--seed 0] [--out FILE] [--json]``; writes ``benchmarks/results/highway_adversaries.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym

import _common
import safeswitch
from safeswitch.examples.highway_drivers import Adversary, drive
from safeswitch.io import write_json

RESULTS = Path(__file__).resolve().parent / "results" / "highway_adversaries.json"


def run_logic(switching: str, episodes: int, seed: int) -> list[dict[str, Any]]:
    rows = []
    for k, kind in enumerate(Adversary.KINDS):
        env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching=switching)
        start = time.perf_counter()
        row = drive(env, Adversary(kind, seed=seed + k), episodes, seed=seed * 100_000 + k * 10_000)
        env.close()
        rows.append({"switching": switching, "driver": kind, **row,
                     "wall_time_s": round(time.perf_counter() - start, 1)})  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logics", nargs="+", default=["ttc", "certified"])
    parser.add_argument("--episodes", type=int, default=150)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    with _common.pool(len(args.logics)) as pool:
        futures = [pool.submit(run_logic, logic, args.episodes, args.seed) for logic in args.logics]
        rows = [row for future in futures for row in future.result()]
    result = {"benchmark": "highway_adversaries", **_common.machine(), "episodes": args.episodes,
              "seed": args.seed, "rows": rows}  # fmt: skip
    write_json(args.out, result)
    if args.json:
        _common.emit(result, True)
        return 0
    print("| logic | driver | crashes | off road | safety share of steps |")
    print("| --- | --- | ---: | ---: | ---: |")
    for r in rows:
        print(f"| `{r['switching']}` | {r['driver']} | {r['crashes']} / {r['episodes']} | "
              f"{r['off_road']} | {r['safety_share']:.3f} |")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
