"""Training speed and decision latency.

Trains one policy from a configuration (default ``--config paper_scratch``, Table II from
scratch: 1.2 M steps, 16 environments, 1 torch thread) into a temporary run directory and
reports wall time and steps per second (for a configuration with a warm start, such as
``--config paper``, the warm start's wall time separately), then times the trained
policy's decision for a single observation (normalisation + forward pass, median of 2,000
calls, 1 torch thread; a go predictor's probability, which the task computes, is not timed:
``benchmarks/runtime_latency.py`` times the whole decision). Run on an otherwise idle machine:
``python benchmarks/bench_train.py [--config FILE] [--timesteps N] [--json] [--out FILE]``.

The machine this project runs on is a shared virtual machine whose speed changes from day to
day (the same recipe took 278 s one day and 465 s the next), so the result also holds the
machine's speed measured just before and just after the training: ``reference`` —
milliseconds per PPO update of a 3 × 128 tanh actor and critic on a minibatch of 2,048 (one
torch thread) and per step of the left turn's batched scene with 128 environments. Two runs'
wall times compare through their references' ratio.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from stable_baselines3.common.torch_layers import create_mlp

import _common
from safeswitch.io import write_json
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.vec_env import LeftTurnVecEnv
from safeswitch.training import train
from safeswitch.training.config import load_config
from safeswitch.training.policies import load_policy

ROOT = Path(__file__).resolve().parent.parent


def decision_latency_ms(run: Path, calls: int = 2000) -> float:
    torch.set_num_threads(1)
    policy = load_policy(run)
    # one scenario's first observation as the policy's task builds it (with a go predictor's
    # probability where the recipe has one; computing it is the task's, not timed here)
    task = build_task(None, policy.config.env)
    obs = task.observe(task.initial(task.scenario_set(0, 1)))
    for _ in range(50):
        policy.act(obs)
    times = []
    for _ in range(calls):
        t0 = time.perf_counter()
        policy.act(obs)
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def machine_reference(updates: int = 100, steps: int = 300) -> dict[str, float]:
    """Milliseconds per PPO-sized update and per batched step (the module docstring)."""
    torch.set_num_threads(1)
    torch.manual_seed(0)

    actor, critic = [
        torch.nn.Sequential(*create_mlp(7, 1, [128] * 3, torch.nn.Tanh)) for _ in (0, 1)
    ]
    optimiser = torch.optim.Adam([*actor.parameters(), *critic.parameters()], lr=1e-4)
    x, y = torch.randn(2048, 7), torch.randn(2048, 1)

    def update() -> None:
        loss = ((actor(x) - y) ** 2).mean() + ((critic(x) - y) ** 2).mean()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()

    env = LeftTurnVecEnv(128, switching="certified", seed=0)
    env.reset()
    action = np.ones((128, 1), dtype=np.float32)
    update()
    env.step(action)
    t0 = time.perf_counter()
    for _ in range(updates):
        update()
    t1 = time.perf_counter()
    for _ in range(steps):
        env.step(action)
    t2 = time.perf_counter()
    env.close()
    return {"update_ms": 1e3 * (t1 - t0) / updates, "env_step_ms": 1e3 * (t2 - t1) / steps}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="paper_scratch")
    parser.add_argument("--timesteps", type=int, help="override the configuration's timesteps")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--out", type=Path, help="also write the result as JSON to this file")
    args = parser.parse_args(argv)
    config = load_config(args.config)
    if args.timesteps:
        config = replace(config, timesteps=args.timesteps)
    config = replace(config, eval_episodes=0)
    before = machine_reference()
    with tempfile.TemporaryDirectory() as tmp:
        metrics = train(config, Path(tmp) / "run", progress_bar=False)
        after = machine_reference()
        latency = decision_latency_ms(Path(tmp) / "run")
    result = {
        "benchmark": "train",
        **_common.machine(),
        "config": args.config,
        "timesteps": metrics["timesteps"],
        "n_envs": config.n_envs,
        "torch_threads": config.torch_threads,
        "wall_time_s": metrics["wall_time_s"],
        "warm_start_wall_time_s": (metrics["warm_start"] or {}).get("wall_time_s", 0.0),
        "steps_per_s": metrics["steps_per_s"],
        "decision_latency_ms": latency,
        "reference": {"before": before, "after": after},
    }
    if args.out:
        write_json(args.out, result)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(
        f"PPO training, {result['timesteps']:,} steps, {config.n_envs} environments, "
        f"{config.torch_threads} torch threads: {result['wall_time_s']:.0f} s "
        f"({result['steps_per_s']:,.0f} steps/s)"
    )
    if result["warm_start_wall_time_s"]:
        print(f"  of which the warm start: {result['warm_start_wall_time_s']:.0f} s")
    print(f"decision latency, one observation, 1 torch thread: {latency:.3f} ms")
    print(
        "the machine before / after: "
        f"{before['update_ms']:.1f} / {after['update_ms']:.1f} ms per update, "
        f"{before['env_step_ms']:.2f} / {after['env_step_ms']:.2f} ms per step"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
