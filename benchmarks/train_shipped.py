"""Reproduce the shipped policies: train each from its configuration and copy the run's
artefacts into ``src/safeswitch/policies/<name>/``.

Usage: ``python benchmarks/train_shipped.py [name ...]`` (default: all). The commands are the
same as ``safeswitch train --config configs/<name>.yaml --out runs/<name>``.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from safeswitch.training.config import load_config
from safeswitch.training.run import train

ROOT = Path(__file__).resolve().parent.parent
POLICIES = {"paper": "paper", "no_adas": "no_adas", "certified": "certified", "none": "none"}
ARTEFACTS = (
    "model.zip",
    "vecnormalize.pkl",
    "config.yaml",
    "metrics.json",
    "training_curves.png",
    "progress.csv",
)


def main(names: list[str]) -> int:
    for name in names or list(POLICIES):
        if name not in POLICIES:
            print(f"unknown policy {name!r}; choose from {list(POLICIES)}", file=sys.stderr)
            return 2
        run = ROOT / "runs" / name
        shutil.rmtree(run, ignore_errors=True)
        metrics = train(load_config(ROOT / "configs" / f"{name}.yaml"), run, progress_bar=False)
        target = ROOT / "src" / "safeswitch" / "policies" / POLICIES[name]
        target.mkdir(parents=True, exist_ok=True)
        for artefact in ARTEFACTS:
            shutil.copy2(run / artefact, target / artefact)
        print(
            f"{name}: {metrics['wall_time_s']:.0f} s, training collisions "
            f"{metrics['training']['collisions']}, evaluation {metrics['evaluation']}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
