"""Falsification against random sampling: failures found per 1,000 simulated episodes.

For each target (the rule under ``paper``, the creeping adversary under ``paper``, the shipped
policy under ``paper`` — its collisions, then its safety actions — and the rule under
``certified``), ``safeswitch falsify`` runs the cross-entropy search and uniform random
sampling with the same budget in the same run (2 Ray workers) and reports how many failures
each found, their ratio, and the smallest footprint separation seen (the margin, for a target
that does not collide).

Run: ``python benchmarks/bench_falsify.py [--budget 20000] [--json]``; writes
``benchmarks/results/falsify.json`` (the figures go to a temporary folder).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import _common
from safeswitch.app.falsify import Target, falsify
from safeswitch.io import write_json

RESULTS = Path(__file__).resolve().parent / "results" / "falsify.json"
TARGETS = (  # (what, the failure searched for)
    (Target("rule", None, "paper"), "collision"),
    (Target("adversary:creep", None, "paper"), "collision"),
    (Target("learned", "shipped", "paper"), "collision"),
    (Target("learned", "shipped", "paper"), "safety"),
    (Target("rule", None, "certified"), "collision"),
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=int, default=20_000, help="episodes per method")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, (target, failure) in enumerate(TARGETS):
            summary = falsify(
                target, Path(tmp) / str(k), budget=args.budget, failure=failure,
                workers=args.workers, progress=False,
            )  # fmt: skip
            m = summary["methods"]
            row = {
                "controller": target.controller,
                "model": target.model,
                "switching": target.switching,
                "failure": failure,
                "budget_per_method": args.budget,
                "random_failures": m["random"]["failures"],
                "search_failures": m["cross-entropy"]["failures"],
                "search_over_random": summary["search_over_random"],
                "random_min_separation_m": m["random"]["min_separation_m"],
                "search_min_separation_m": m["cross-entropy"]["min_separation_m"],
                "wall_time_s": summary.get("wall_time_s"),
            }
            rows.append(row)
            ratio = row["search_over_random"]
            print(
                f"{target.controller:16} {target.switching:9} {failure:9} "
                f"random {row['random_failures']:6} "
                f"search {row['search_failures']:6} "
                f"({'n/a' if ratio is None else f'{ratio:.1f}×'}); min separation "
                f"{row['random_min_separation_m']:.3f} / {row['search_min_separation_m']:.3f} m",
                file=sys.stderr,
            )
    result = {"benchmark": "falsify", **_common.machine(), "targets": rows}
    write_json(RESULTS, result)
    _common.emit(result, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
