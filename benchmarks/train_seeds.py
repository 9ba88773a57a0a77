"""How much a 1.2 M-step training run depends on its seed (and what a configuration gives).

Trains a configuration (default ``--config paper``, the shipped paper policy's) once per
seed — about 3 minutes each on this machine, plus the warm start if the configuration has one
(about 7 minutes for ``--config paper``) — and prints each run's
collisions during training (warm start included) and its evaluation on the fixed unseen
scenario set (seed 1000003). Usage:
``python benchmarks/train_seeds.py [--config PATH] [seed ...]`` (default seeds: 1 2).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from safeswitch.training.config import load_config
from safeswitch.training.run import train

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="paper")
    parser.add_argument("seeds", nargs="*", type=int, default=[1, 2])
    args = parser.parse_args(argv)
    base = load_config(args.config)
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as tmp:
            metrics = train(replace(base, seed=seed), Path(tmp) / "run", progress_bar=False)
        e, warm = metrics["evaluation"], metrics["warm_start"]
        row = {
            "config": Path(args.config).name,
            "seed": seed,
            "warm_start_collisions": warm["collisions"] if warm else None,
            "training_collisions": metrics["training"]["collisions"],
            "training_safety_episodes": metrics["training"]["safety_activation_episodes"],
            "wall_time_s": metrics["wall_time_s"] + (warm["wall_time_s"] if warm else 0.0),
            **{
                k: e[k]
                for k in (
                    "collisions",
                    "safety_activation_episodes",
                    "comfort_violation_fraction",
                    "stops",
                    "mean_time_to_clear_s",
                    "cut_episodes",
                )
            },
        }
        print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
