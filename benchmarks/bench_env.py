"""Environment throughput: steps per second of the Gymnasium Env and of the batched VecEnv.

One step = controllers, switching logic, plant, rewards, observation, auto-reset and the
(lazy) info list — everything ``VecEnv.step`` does. Actions are uniform random in [-1, 1];
``switching="paper"``. Run: ``python benchmarks/bench_env.py [--json]``.
"""

from __future__ import annotations

import argparse
import sys

import _common
import safeswitch  # noqa: F401  (registers the environment id)
from safeswitch.bench import env_steps_per_s, vec_env_steps_per_s

VEC_SIZES = (1, 64, 1024, 4096)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--seconds", type=float, default=1.5, help="timing per row")
    parser.add_argument("--switching", default="paper", choices=("paper", "none"))
    args = parser.parse_args(argv)
    single = env_steps_per_s(args.switching, args.seconds)
    rows = [
        {"num_envs": n, "steps_per_s": vec_env_steps_per_s(n, args.switching, args.seconds)}
        for n in VEC_SIZES
    ]
    result = {
        "benchmark": "env",
        **_common.machine(),
        "switching": args.switching,
        "single_env_steps_per_s": single,
        "vec_env": rows,
    }
    if args.json:
        _common.emit(result, True)
        return 0
    print(f"safeswitch/LeftTurn-v0, switching={args.switching}, one core")
    print(f"Gymnasium Env (batch of 1): {single:,.0f} steps/s")
    print(f"{'VecEnv num_envs':>16} {'steps/s':>12}")
    for r in rows:
        print(f"{r['num_envs']:>16} {r['steps_per_s']:>12,.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
