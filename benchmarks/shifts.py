"""Left-turn policies, frozen, on shifted scenario distributions (issue #39's go predictor and
issue #40's shifts): on 2,000 unseen random scenarios per shift (seed 1000003), each under the
logic it is deployed with, the episodes that needed the safety action, the collisions, the
cleared episodes and the efficiency against the oracle.

The shifts: the training distribution itself, the oncoming car faster (32-38 and 38-44 km/h,
``benchmarks/adapt.py``'s north-fast) or slower (12-20 and 6-12 km/h, north-slow), the ego
arriving at 28-30 km/h (ego-fast), starting 22-28 m before the conflict point (ego-close), and
both at once at 25-30 km/h (ego-close-fast).

Run: ``python benchmarks/shifts.py [--models certified RUN ...] [--at REV ...] [--episodes N]
[--out results/shifts.json]``; ``--at REV`` adds the `certified` policy shipped at the git
revision ``REV`` (e.g. ``bee852d``, the go predictor fitted on the training scene alone;
``bae2585``, the last without a go predictor). One torch thread.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import _common
from adapt import SHIFTS as ADAPT_SHIFTS
from safeswitch.app.evaluate import evaluate

ROOT = Path(__file__).resolve().parent.parent
SHIFTS = {  # adapt.py's shifts by their settings, and two between them and the training scene
    "trained": [],
    "north 38-44 km/h (north-fast)": ADAPT_SHIFTS["north-fast"][1],
    "north 32-38 km/h": ["env.scenarios.north_speed_kmh=[32, 38]"],
    "north 12-20 km/h": ["env.scenarios.north_speed_kmh=[12, 20]"],
    "north 6-12 km/h (north-slow)": ADAPT_SHIFTS["north-slow"][1],
    "ego 28-30 km/h (ego-fast)": ADAPT_SHIFTS["ego-fast"][1],
    "ego 22-28 m out (ego-close)": ADAPT_SHIFTS["ego-close"][1],
    "ego 22-28 m out at 25-30 km/h (ego-close-fast)": ADAPT_SHIFTS["ego-close-fast"][1],
}
KEPT = ("episodes", "collisions", "failures", "safety_activation_episodes", "cleared_episodes",
        "mean_efficiency", "speeding_episodes", "comfort_violation_fraction")  # fmt: skip


def measure(model: str, episodes: int, seed: int) -> dict[str, dict[str, object]]:
    rows = {}
    for name, settings in SHIFTS.items():
        summary = evaluate("learned", model, "random", episodes, seed, None, None,
                           settings=settings)  # fmt: skip
        rows[name] = {k: summary[k] for k in KEPT}
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=["certified"])
    parser.add_argument("--at", nargs="*", default=[], metavar="REV")
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=1_000_003)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    models = {m: measure(m, args.episodes, args.seed) for m in args.models}
    for revision in args.at:
        with tempfile.TemporaryDirectory() as tmp:
            folder = "src/safeswitch/policies/certified"
            tree = _common.export_revision(ROOT, revision, Path(tmp), (folder,))
            models[f"certified at {revision}"] = measure(str(tree / folder), args.episodes,
                                                         args.seed)  # fmt: skip
    result = {"machine": _common.machine(), "episodes": args.episodes, "seed": args.seed,
              "shifts": SHIFTS, "models": models}  # fmt: skip
    if not _common.publish(result, args.out, args.json):
        for model, rows in models.items():
            for shift, r in rows.items():
                print(f"{model[-40:]:>40}  {shift:<30} safety {r['safety_activation_episodes']:>4}"
                      f"  collisions {r['collisions']}  cleared {r['cleared_episodes']:>4}  "
                      f"efficiency {r['mean_efficiency']:.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
