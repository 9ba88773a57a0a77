"""How much a 1.2 M-step training run depends on its seed.

Trains ``configs/paper.yaml`` once per seed (about 3 minutes each on this machine) and prints
each run's training collisions and its evaluation on the fixed unseen scenario set. Usage:
``python benchmarks/train_seeds.py [seed ...]`` (default: 1 2).
"""

from __future__ import annotations

import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from safeswitch.training.config import load_config
from safeswitch.training.run import train

ROOT = Path(__file__).resolve().parent.parent


def main(seeds: list[int]) -> int:
    base = load_config(ROOT / "configs" / "paper.yaml")
    rows = []
    for seed in seeds or [1, 2]:
        with tempfile.TemporaryDirectory() as tmp:
            metrics = train(replace(base, seed=seed), Path(tmp) / "run", progress_bar=False)
        e = metrics["evaluation"]
        rows.append(
            {
                "seed": seed,
                "training_collisions": metrics["training"]["collisions"],
                **{
                    k: e[k]
                    for k in (
                        "collisions",
                        "safety_activation_episodes",
                        "comfort_violation_fraction",
                        "stops",
                        "mean_time_to_clear_s",
                    )
                },
            }
        )
        print(json.dumps(rows[-1]))
    return 0


if __name__ == "__main__":
    sys.exit(main([int(s) for s in sys.argv[1:]]))
