"""An off-policy variant of the learning method: Stable-Baselines3's SAC in place of PPO.

The same task, reward (``--config``'s, default ``experimental/scratch_wide``: the paper logic,
R_ADAS, a decision every 5 ticks, comfort penalties that keep growing past the limits), network
(3 × 128, Tanh) and observation normalisation as the PPO recipes; SAC with SB3's defaults
otherwise (automatic entropy tuning, γ 0.99, batch 256, replay buffer 10⁶), ``--envs``
environments and ``--gradient-steps`` updates per batched step, from a random initialisation.
Every tenth of the run the deterministic policy is validated on 500 scenarios of seed 2000003;
at the end it is evaluated on the README's 1,000 unseen scenarios (seed 1000003). Training
collisions are counted as in ``safeswitch train``. A documented variant (issue #18: "only if PPO
cannot"), not a training command: a run is not resumable and ships nothing.

Run: ``python benchmarks/sac_variant.py [--timesteps N] [--seed S] [--envs N]
[--gradient-steps N]`` (600,000 decisions take about a quarter of an hour on one thread);
writes ``benchmarks/results/sac_variant.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize

import _common
from safeswitch.evaluation.evaluate import run_controller, summary_against_oracle
from safeswitch.leftturn.task import build_task
from safeswitch.leftturn.vec_env import LeftTurnVecEnv
from safeswitch.training.config import load_config

RESULTS = Path(__file__).parent / "results" / "sac_variant.json"
FIELDS = ("collisions", "safety_activation_episodes", "comfort_violation_fraction", "stops",
          "cut_episodes", "cleared_episodes", "mean_efficiency", "mean_return")  # fmt: skip


class Evaluation:
    """Deterministic episodes of a model on a fixed scenario set (the oracle planned once)."""

    def __init__(self, task: Any, env: VecNormalize, episodes: int, seed: int) -> None:
        self.task, self.env = task, env
        ids = np.arange(episodes)
        self.scenarios = task.draw_scenarios(seed, ids, np.zeros(episodes, dtype=int))
        self.plan: Any = None

    def __call__(self, model: SAC) -> dict[str, Any]:
        def policy(obs: Any, state: Any, tick: int) -> Any:
            action, _ = model.predict(self.env.normalize_obs(obs), deterministic=True)
            return np.asarray(action, dtype=np.float64).reshape(-1)

        result, self.plan = run_controller(
            self.task, policy, self.scenarios, plan=self.plan, trace=False
        )
        summary = summary_against_oracle(result, self.plan, self.task.config.episode.horizon_s)
        return {key: summary[key] for key in FIELDS}


class Monitor(BaseCallback):
    """Training collisions, and a validation every ``every`` steps."""

    def __init__(self, validate: Evaluation, every: int) -> None:
        super().__init__()
        self.validate, self.every, self.next = validate, every, every
        self.collisions, self.rows = 0, []
        self.started = time.perf_counter()

    def _on_step(self) -> bool:
        self.collisions += int(self.locals["infos"].record.collision.sum())
        if self.num_timesteps >= self.next:
            self.next += self.every
            row = {"timesteps": self.num_timesteps, "wall_time_s": round(
                time.perf_counter() - self.started, 1), "training_collisions": self.collisions,
                **self.validate(self.model)}  # fmt: skip
            self.rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
        return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="experimental/scratch_wide", help="task and reward")
    parser.add_argument("--timesteps", type=int, default=600_000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--envs", type=int, default=32)
    parser.add_argument("--gradient-steps", type=int, default=4)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    config = load_config(args.config)
    env = VecNormalize(LeftTurnVecEnv(args.envs, config=config.env, seed=args.seed),
                       norm_obs=True, norm_reward=True, gamma=0.99)  # fmt: skip
    task = build_task(None, config.env)
    model = SAC(
        "MlpPolicy", env, seed=args.seed, device="cpu", batch_size=256, gamma=0.99,
        gradient_steps=args.gradient_steps, learning_starts=10_000,
        policy_kwargs={"net_arch": [128, 128, 128], "activation_fn": torch.nn.Tanh},
    )  # fmt: skip
    monitor = Monitor(Evaluation(task, env, 500, 2_000_003), max(args.timesteps // 10, 1))
    model.learn(total_timesteps=args.timesteps, callback=monitor)
    wall = time.perf_counter() - monitor.started
    test = Evaluation(task, env, 1000, 1_000_003)(model)
    result = {
        "benchmark": "sac_variant",
        **_common.machine(),
        "config": args.config,
        "seed": args.seed,
        "envs": args.envs,
        "gradient_steps": args.gradient_steps,
        "timesteps": int(model.num_timesteps),
        "wall_time_s": round(wall, 1),
        "training_collisions": monitor.collisions,
        "validation": monitor.rows,
        "evaluation": test,
    }
    tmp = RESULTS.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, RESULTS)
    print(json.dumps({k: v for k, v in result.items() if k != "validation"}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
