"""An off-policy variant of the learning method: Stable-Baselines3's SAC or TD3 in place of PPO.

The same task, reward and learning-only wrappers as the PPO recipe of ``--config`` (default
``experimental/scratch_wide``: the paper logic, R_ADAS, a decision every 5 ticks, comfort
penalties that keep growing past the limits; a recipe with progress shaping, reason penalties
or a minimum-time cost gets them exactly as ``safeswitch train`` builds them), the same network
(3 × 128, Tanh, actor and critics), discount (the recipe's ``ppo.gamma``) and observation and
reward normalisation; SB3's defaults otherwise (replay buffer 10⁶, batch 256; SAC: automatic
entropy tuning; TD3: a fixed Gaussian exploration noise of ``--noise``), ``--envs`` environments and
``--gradient-steps`` updates per batched step, from a random initialisation. Every tenth of the
run the deterministic policy is validated on 500 scenarios of seed 2000003; at the end it is
evaluated on the README's 1,000 unseen scenarios (seed 1000003). Both under the logic the recipe
validates under (``validation.switching``, else the one it trains under). Training collisions
are counted as in ``safeswitch train``. A documented variant (issue #18: "only if PPO cannot"),
not a training command: a run is not resumable and ships nothing.

Run: ``python benchmarks/offpolicy_variant.py [--algo sac|td3] [--config NAME] [--timesteps N]
[--seed S] [--envs N] [--gradient-steps N] [--noise SIGMA]`` (600,000 decisions take about a
quarter of an hour on one thread); writes ``benchmarks/results/<algo>_variant.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import VecNormalize

import _common
from safeswitch.evaluation.evaluate import run_controller, summary_against_oracle
from safeswitch.io import write_json
from safeswitch.leftturn.task import build_task
from safeswitch.leftturn.vec_env import LeftTurnVecEnv
from safeswitch.training.config import load_config
from safeswitch.training.run import LearningEnv

RESULTS = Path(__file__).parent / "results"
FIELDS = ("collisions", "safety_activation_episodes", "comfort_violation_fraction", "stops",
          "cut_episodes", "cleared_episodes", "mean_efficiency", "mean_return")  # fmt: skip


class Evaluation:
    """Deterministic episodes of a model on a fixed scenario set (the oracle planned once)."""

    def __init__(self, task: Any, env: VecNormalize, episodes: int, seed: int) -> None:
        self.task, self.env = task, env
        self.scenarios = task.scenario_set(seed, episodes)
        self.plan: Any = None

    def __call__(self, model: OffPolicyAlgorithm) -> dict[str, Any]:
        def policy(obs: Any, state: Any, tick: int) -> Any:
            action, _ = model.predict(self.env.normalize_obs(obs), deterministic=True)
            return np.asarray(action, dtype=np.float64).reshape(-1)

        result, self.plan = run_controller(
            self.task, policy, self.scenarios, plan=self.plan, trace=False
        )
        summary = summary_against_oracle(result, self.plan, self.task.config.episode.horizon_s)
        return {key: summary[key] for key in FIELDS}


class Monitor(BaseCallback):
    """Training collisions (as the task records them, beneath every wrapper), and a validation
    every ``every`` steps."""

    def __init__(self, vec: LeftTurnVecEnv, validate: Evaluation, every: int) -> None:
        super().__init__()
        self.vec, self.validate, self.every, self.next = vec, validate, every, every
        self.collisions, self.rows = 0, []
        self.started = time.perf_counter()

    def _on_step(self) -> bool:
        record = self.vec.last_record
        assert record is not None
        self.collisions += int(record.collision.sum())
        if self.num_timesteps >= self.next:
            self.next += self.every
            row = {"timesteps": self.num_timesteps, "wall_time_s": round(
                time.perf_counter() - self.started, 1), "training_collisions": self.collisions,
                **self.validate(self.model)}  # fmt: skip
            self.rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
        return True


def build(algo: str, env: VecNormalize, args: argparse.Namespace) -> OffPolicyAlgorithm:
    """SAC or TD3 with the paper's network for actor and critics, SB3's defaults otherwise."""
    common: dict[str, Any] = {
        "seed": args.seed, "device": "cpu", "batch_size": 256, "gamma": args.gamma,
        "gradient_steps": args.gradient_steps, "learning_starts": 10_000,
        "policy_kwargs": {"net_arch": [128, 128, 128], "activation_fn": torch.nn.Tanh},
    }  # fmt: skip
    if algo == "sac":
        return SAC("MlpPolicy", env, **common)
    noise = NormalActionNoise(np.zeros(1), np.full(1, args.noise))
    return TD3("MlpPolicy", env, action_noise=noise, **common)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", choices=("sac", "td3"), default="sac")
    parser.add_argument("--config", default="experimental/scratch_wide", help="task and reward")
    parser.add_argument("--timesteps", type=int, default=600_000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--envs", type=int, default=32)
    parser.add_argument("--gradient-steps", type=int, default=4)
    parser.add_argument("--noise", type=float, default=0.2, help="TD3's exploration std")
    parser.add_argument("--out", type=Path, help="results file (default results/<algo>_variant)")
    args = parser.parse_args(argv)
    if not args.noise > 0:
        parser.error(f"--noise must be > 0, got {args.noise!r}")
    torch.set_num_threads(1)
    config = load_config(args.config)
    args.gamma = config.ppo.gamma
    vec = LeftTurnVecEnv(args.envs, config=config.env, seed=args.seed)
    learning = LearningEnv(vec, config.ppo)
    env = VecNormalize(learning.env, norm_obs=True, norm_reward=True, gamma=args.gamma)
    deploy = config.validation.switching or config.env.switching
    task = build_task(None, config.env, switching=deploy)
    model = build(args.algo, env, args)
    monitor = Monitor(vec, Evaluation(task, env, 500, 2_000_003), max(args.timesteps // 10, 1))
    model.learn(
        total_timesteps=args.timesteps, callback=CallbackList([monitor, *learning.schedules()])
    )
    wall = time.perf_counter() - monitor.started
    test = Evaluation(task, env, 1000, 1_000_003)(model)
    result = {
        "benchmark": f"{args.algo}_variant",
        **_common.machine(),
        "algo": args.algo,
        "config": args.config,
        "trained_under": config.env.switching,
        "evaluated_under": deploy,
        "seed": args.seed,
        "envs": args.envs,
        "gradient_steps": args.gradient_steps,
        **({"noise": args.noise} if args.algo == "td3" else {}),
        "timesteps": int(model.num_timesteps),
        "wall_time_s": round(wall, 1),
        "training_collisions": monitor.collisions,
        "validation": monitor.rows,
        "evaluation": test,
    }
    path = args.out or RESULTS / f"{args.algo}_variant.json"
    write_json(path, result)
    print(json.dumps({k: v for k, v in result.items() if k != "validation"}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
