"""Environment throughput: steps per second of the Gymnasium Env and of the batched VecEnv.

One step = controllers, switching logic, plant, rewards, observation, auto-reset and the
(lazy) info list — everything ``VecEnv.step`` does. Actions are uniform random in [-1, 1];
``switching="paper"``. Run: ``python benchmarks/bench_env.py [--json]``.
"""

from __future__ import annotations

import argparse
import sys

import gymnasium as gym
import numpy as np

import _common
import safeswitch  # noqa: F401  (registers the environment id)
from safeswitch.leftturn import make_vec_env

VEC_SIZES = (1, 64, 1024, 4096)


def single_env_steps_per_s(switching: str, seconds: float) -> float:
    env = gym.make("safeswitch/LeftTurn-v0", switching=switching).unwrapped
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (1000, 1)).astype(np.float32)
    counter = {"k": 0}

    def hundred_steps() -> None:
        for _ in range(100):
            _, _, terminated, truncated, _ = env.step(actions[counter["k"] % 1000])
            counter["k"] += 1
            if terminated or truncated:
                env.reset()

    return 100 / _common.time_per_call(hundred_steps, seconds)


def vec_env_steps_per_s(num_envs: int, switching: str, seconds: float) -> float:
    env = make_vec_env(num_envs, switching=switching, seed=0)
    env.reset()
    actions = np.random.default_rng(0).uniform(-1, 1, (16, num_envs, 1))
    counter = {"k": 0}

    def one_step() -> None:
        env.step(actions[counter["k"] % 16])
        counter["k"] += 1

    return num_envs / _common.time_per_call(one_step, seconds)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--seconds", type=float, default=1.5, help="timing per row")
    parser.add_argument("--switching", default="paper", choices=("paper", "none"))
    args = parser.parse_args(argv)
    single = single_env_steps_per_s(args.switching, args.seconds)
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
