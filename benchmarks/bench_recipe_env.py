"""A training recipe's environment speed: the VecEnv it trains on, an evaluation rollout and
the gap planner in its traffic, this checkout against a git revision.

Three figures per tree, each in a fresh process, one core:

- **decisions/s**: ``VecEnv.step`` of the recipe's own training environment (its ``n_envs``,
  its traffic, its decision interval, its observation), random actions; a decision is
  ``episode.decision_interval`` ticks.
- **rollout episodes/s**: :func:`~safeswitch.evaluation.rollout.rollout` of a random driver on
  ``--episodes`` scenes of the recipe's traffic (what every evaluation runs).
- **gap planner episodes/s** (a recipe in traffic): the same scenes driven by the gap planner,
  whose go check simulates its drive ahead (the teacher, the report's row, the go predictor's
  labels).

The revision's ``src/`` and ``experiments/`` are exported to a temporary folder; the two trees
alternate for ``--rounds`` rounds and the medians are reported with their ratio — a comparison
made in one run, on the same machine state.

Run: ``python benchmarks/bench_recipe_env.py [--config NAME] [--against REV] [--rounds N]
[--episodes N] [--seconds S] [--out FILE]``; default the go-predictor traffic recipe against
``HEAD``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import _common
from safeswitch.io import write_json

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).parent / "results"

_MEASURE = """
import json, sys, time
import numpy as np
from safeswitch.bench import time_per_call
from safeswitch.evaluation.rollout import rollout
from safeswitch.training.config import load_any_config
from safeswitch.training.run import LeftTurnPlant
recipe, seconds, episodes = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
config = load_any_config(recipe)
env = LeftTurnPlant(config).vec_env()
env.reset()
actions = np.random.default_rng(0).uniform(-1, 1, (16, config.n_envs, 1)).astype(np.float32)
count = [0]
def decide():
    env.step(actions[count[0] % 16])
    count[0] += 1
out = {"decisions_per_s": config.n_envs / time_per_call(decide, seconds)}
task = env.task
ids = np.arange(episodes)
scenes = task.draw_scenarios(1000003, ids, np.zeros_like(ids))
rng = np.random.default_rng(1)
def random_driver(obs, state, tick):
    return rng.uniform(-1, 1, episodes)
drivers = {"rollout_episodes_per_s": lambda: random_driver}
if config.traffic is not None:
    from safeswitch.evaluation.traffic_planner import GapPlanner
    drivers["gap_planner_episodes_per_s"] = lambda: GapPlanner(task)
for name, make in drivers.items():
    start = time.perf_counter()
    rollout(task, scenes, make())
    out[name] = episodes / (time.perf_counter() - start)
print(json.dumps(out))
"""


def measure(tree: Path, recipe: str, seconds: float, episodes: int) -> dict[str, float]:
    """The figures of the package in ``tree`` (its ``src/``), in a fresh process."""
    env = dict(os.environ, PYTHONPATH=str(tree / "src"))
    args = [sys.executable, "-c", _MEASURE, recipe, str(seconds), str(episodes)]
    done = subprocess.run(args, env=env, capture_output=True, text=True, check=True)
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="experimental/traffic_certified_go_model_dagger_wide")
    parser.add_argument("--against", default="HEAD", metavar="REV")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=64, help="scenes per rollout")
    parser.add_argument("--seconds", type=float, default=5.0, help="timing of the VecEnv")
    parser.add_argument("--out", type=Path, help="the result's JSON (default: results/)")
    args = parser.parse_args(argv)
    revision = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", args.against],
        capture_output=True, text=True, check=True,
    ).stdout.strip()  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        exported = _common.export_revision(ROOT, revision, Path(tmp), ("src", "experiments"))
        trees = {"this checkout": ROOT, revision: exported}
        for tree in trees.values():  # compile and cache numba's machine code first
            measure(tree, args.config, 0.2, 4)
        runs: dict[str, list[dict[str, float]]] = {name: [] for name in trees}
        for _ in range(args.rounds):
            for name, tree in trees.items():
                runs[name].append(measure(tree, args.config, args.seconds, args.episodes))
    keys = list(runs["this checkout"][0])
    medians = {
        n: {k: statistics.median(r[k] for r in rows) for k in keys} for n, rows in runs.items()
    }
    ratio = {k: medians["this checkout"][k] / medians[revision][k] for k in keys}
    result = {
        "benchmark": "recipe_env", **_common.machine(), "config": args.config,
        "against": revision, "rounds": args.rounds, "episodes": args.episodes,
        "median": medians, "ratio": ratio, "runs": runs,
    }  # fmt: skip
    name = args.config.replace("experimental/", "experimental_").replace("/", "_")
    out = args.out or RESULTS / f"recipe_env_{name}_against_{revision}.json"
    write_json(out, result)
    print(f"{args.config}: one core, median of {args.rounds} alternating rounds")
    for k in keys:
        row = "  ".join(f"{n}: {m[k]:>10,.1f}" for n, m in medians.items())
        print(f"{k:>28}  {row}  ratio {ratio[k]:.2f}")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
