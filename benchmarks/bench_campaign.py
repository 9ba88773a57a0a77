"""Campaign throughput on Ray: scaling from 1 to 2 workers, Ray's start-up, and a million
episodes of the shipped policy.

1. Ray's start-up: a local cluster started and shut down, nothing run (median of 3).
2. Scaling: the same campaign (``--episodes`` of a controller under ``paper``, shards of
   10,000) with 1 and with 2 workers, in one run; the ratio of their work times (start-up
   excluded; the machine has 2 cores).
3. ``--million``: 1,000,000 episodes of the policy under ``paper`` with 2 workers.

Run: ``python benchmarks/bench_campaign.py [--episodes 100000] [--controller rule]
[--model shipped] [--million] [--json]``; writes ``benchmarks/results/campaign.json``
(``campaign_learned.json`` with ``--controller learned``, the shipped policy;
``campaign_learned_<model>.json`` with another ``--model``, a run directory's path separators
as underscores). Run it on an otherwise idle
machine: a second job on one of the two cores halves what two workers can give.
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

import _common
from safeswitch.app.campaign import Cell, Space, campaign
from safeswitch.app.distributed import cluster
from safeswitch.io import write_json

RESULTS = Path(__file__).resolve().parent / "results" / "campaign.json"


def startup(rounds: int = 3) -> float:
    times = []
    for _ in range(rounds):
        began = time.perf_counter()
        with cluster(2):
            pass
        times.append(time.perf_counter() - began)
    return statistics.median(times)


def timed(cell: Cell, episodes: int, workers: int, seed: int) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        result = campaign(
            [cell], Space("random", episodes, seed), Path(tmp) / "c", workers=workers,
            shard_size=10_000, progress=False,
        )  # fmt: skip
    s = result.summary
    work = s["wall_time_s"] - s["ray_startup_s"]
    return {
        "workers": workers,
        "episodes": episodes,
        "wall_time_s": s["wall_time_s"],
        "ray_startup_s": s["ray_startup_s"],
        "work_s": work,
        "episodes_per_s": episodes / work,
        **{k: s["cells"][cell.key][k] for k in SHOWN},
    }


#: What a campaign's summary must show beside its speed (failures, and what could hide one).
SHOWN = ("failures", "collisions", "lost_control_episodes", "speeding_episodes", "max_speed_kmh",
         "cleared_episodes", "mean_efficiency")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=100_000)
    parser.add_argument("--controller", default="rule")
    parser.add_argument(
        "--model", default="shipped",
        help="the learned controller's policy (default the shipped one; e.g. paper-warm)",
    )  # fmt: skip
    parser.add_argument("--million", action="store_true", help="also 1 M episodes of the policy")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    learned = args.controller == "learned"
    cell = Cell(args.controller, args.model if learned else None)
    result: dict[str, object] = {"benchmark": "campaign", **_common.machine(), "threads": 2}
    result["ray_startup_s"] = startup()
    one = timed(cell, args.episodes, 1, 5)
    two = timed(cell, args.episodes, 2, 5)
    result["scaling"] = {"one_worker": one, "two_workers": two,
                         "speedup": one["work_s"] / two["work_s"]}  # fmt: skip
    print(
        f"Ray start-up {result['ray_startup_s']:.1f} s; {args.episodes:,} episodes of "
        f"{cell.key}: 1 worker {one['work_s']:.0f} s, 2 workers {two['work_s']:.0f} s — "
        f"{one['work_s'] / two['work_s']:.2f}×",
        file=sys.stderr,
    )
    if args.million:
        million = timed(Cell("learned", args.model), 1_000_000, 2, 7)
        result["million_shipped" if args.model == "shipped" else "million"] = million
        print(
            f"1,000,000 episodes of {args.model}, 2 workers: {million['wall_time_s']:.0f} s "
            f"({million['episodes_per_s']:,.0f} episodes/s), {million['failures']} failures "
            f"({million['collisions']} collisions, {million['lost_control_episodes']} lost "
            f"control), {million['speeding_episodes']:,} speeding",
            file=sys.stderr,
        )
    name = "campaign.json" if args.controller == "rule" else f"campaign_{args.controller}.json"
    if learned and args.model != "shipped":
        # A run directory is a path: its separators become underscores in the file name.
        slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", args.model.strip("/"))
        name = f"campaign_learned_{slug}.json"
        result["model"] = args.model
    write_json(RESULTS.with_name(name), result)
    _common.emit(result, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
