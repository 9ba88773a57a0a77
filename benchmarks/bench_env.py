"""Environment throughput: steps per second of the Gymnasium Env and of the batched VecEnv.

One step = controllers, switching logic, plant, rewards, observation, auto-reset and the
(lazy) info list — everything ``VecEnv.step`` does. Actions are uniform random in [-1, 1];
``switching="paper"``. One core (numeric libraries single-threaded).

Run: ``python benchmarks/bench_env.py [--json]``. With ``--against REV`` the same figures are
measured for this checkout and for the git revision ``REV`` (its ``src/`` exported to a
temporary folder), alternating between the two in separate processes for ``--rounds`` rounds,
and the median of each is reported with their ratio: a comparison made in one run, on the same
machine state, so that a slower or faster host does not masquerade as a code change.
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

VEC_SIZES = (1, 64, 1024, 4096)
ROOT = Path(__file__).resolve().parent.parent

_MEASURE = """
import importlib, json, sys
import safeswitch
from safeswitch.core import registry
# The installed entry points name this checkout's modules; a revision whose logics lived
# elsewhere registers them from where they were (a run-time registration wins).
HOMES = {
    "paper": ("safeswitch.leftturn.logics.paper", "safeswitch.leftturn.switching"),
    "guarded": ("safeswitch.leftturn.logics.paper", "safeswitch.leftturn.switching"),
    "certified": ("safeswitch.leftturn.logics.certified", "safeswitch.leftturn.certified"),
}
for name, modules in HOMES.items():
    for module in modules:
        try:
            factory = getattr(importlib.import_module(module), name + "_logic")
        except ImportError:
            continue
        registry.register_logic(name, factory, replace=True)
        break
from safeswitch.bench import env_steps_per_s, vec_env_steps_per_s
switching, seconds, sizes = sys.argv[1], float(sys.argv[2]), json.loads(sys.argv[3])
out = {"single": env_steps_per_s(switching, seconds)}
for n in sizes:
    out[str(n)] = vec_env_steps_per_s(n, switching, seconds)
print(json.dumps(out))
"""


def measure(src: Path, switching: str, seconds: float, sizes: tuple[int, ...]) -> dict[str, float]:
    """The figures of the package under ``src``, measured in a fresh process."""
    env = dict(os.environ, PYTHONPATH=str(src))
    args = [sys.executable, "-c", _MEASURE, switching, str(seconds), json.dumps(list(sizes))]
    done = subprocess.run(args, env=env, capture_output=True, text=True, check=True)
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def export(revision: str, folder: Path) -> Path:
    """``src/`` of a git revision, unpacked into ``folder``."""
    return _common.export_revision(ROOT, revision, folder, ("src",)) / "src"


def compare(revision: str, switching: str, seconds: float, rounds: int) -> dict[str, object]:
    sizes = (1, 4096)
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"this checkout": ROOT / "src", revision: export(revision, Path(tmp))}
        for src in trees.values():  # compile and cache numba's machine code first
            measure(src, switching, 0.1, sizes)
        runs: dict[str, list[dict[str, float]]] = {name: [] for name in trees}
        for _ in range(rounds):
            for name, src in trees.items():
                runs[name].append(measure(src, switching, seconds, sizes))
    keys = ("single", *(str(n) for n in sizes))
    medians = {
        name: {k: statistics.median(r[k] for r in rows) for k in keys}
        for name, rows in runs.items()
    }
    mine, theirs = medians["this checkout"], medians[revision]
    return {
        "against": revision,
        "rounds": rounds,
        "median_steps_per_s": medians,
        "ratio": {k: mine[k] / theirs[k] for k in keys},
        "runs": runs,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--seconds", type=float, default=1.5, help="timing per row")
    parser.add_argument("--switching", default="paper", help="a registered switching logic")
    parser.add_argument("--against", metavar="REV", help="compare with this git revision")
    parser.add_argument("--rounds", type=int, default=5, help="alternating rounds (--against)")
    args = parser.parse_args(argv)
    if args.against:
        result = {"benchmark": "env", **_common.machine(), "switching": args.switching}
        result |= compare(args.against, args.switching, args.seconds, args.rounds)
        if args.json:
            _common.emit(result, True)
            return 0
        print(f"safeswitch/LeftTurn-v0, switching={args.switching}, one core, median of "
              f"{args.rounds} alternating rounds")  # fmt: skip
        medians = result["median_steps_per_s"]
        assert isinstance(medians, dict)
        ratio = result["ratio"]
        assert isinstance(ratio, dict)
        for key, label in (("single", "Gymnasium Env"), ("4096", "VecEnv, 4,096 envs")):
            row = "  ".join(f"{name}: {m[key]:>12,.0f}" for name, m in medians.items())
            print(f"{label:>20}  {row}  ratio {ratio[key]:.3f}")
        return 0
    figures = measure(ROOT / "src", args.switching, args.seconds, VEC_SIZES)
    rows = [{"num_envs": n, "steps_per_s": figures[str(n)]} for n in VEC_SIZES]
    result = {
        "benchmark": "env",
        **_common.machine(),
        "switching": args.switching,
        "single_env_steps_per_s": figures["single"],
        "vec_env": rows,
    }
    if args.json:
        _common.emit(result, True)
        return 0
    print(f"safeswitch/LeftTurn-v0, switching={args.switching}, one core")
    print(f"Gymnasium Env (batch of 1): {figures['single']:,.0f} steps/s")
    print(f"{'VecEnv num_envs':>16} {'steps/s':>12}")
    for r in rows:
        print(f"{r['num_envs']:>16} {r['steps_per_s']:>12,.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
