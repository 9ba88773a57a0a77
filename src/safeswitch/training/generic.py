"""Training and evaluation on any registered Gymnasium environment under a switching logic.

``safeswitch train --env ID`` and ``safeswitch evaluate --env ID`` work for

* an environment whose constructor takes ``switching=`` (and ``penalty=``) itself — a
  safeswitch-aware environment such as ``safeswitch/Highway-v0``; or
* any environment with a ``Box`` action space for which a Safety controller is registered
  (:func:`~safeswitch.core.registry.register_safety_controller`): it is wrapped in
  :class:`~safeswitch.core.wrappers.SafeSwitch` with the named logic.

The run directory is the left turn's (``config.yaml``, ``progress.csv``, ``tb/``, checkpoints,
``model.zip``, ``vecnormalize.pkl``, ``metrics.json`` last), and ``--resume`` works the same.
Failures are what the plant declares (``register_safety_controller(..., failure=)``: an
``info`` key or a predicate on the last step's ``info``; by default ``crashed`` or
``collision``), counted in training and evaluation as ``failures``.
"""

from __future__ import annotations

import csv
import inspect
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

from safeswitch.core.config import ConfigError
from safeswitch.core.registry import (
    LogicContextError,
    failure_check,
    failure_of,
    plain_env_id,
    safety_controller_for,
)
from safeswitch.core.wrappers import SafeSwitch
from safeswitch.io import write_json
from safeswitch.training.config import EnvTrainConfig, dump_env_config, load_env_config
from safeswitch.training.constraints import SWITCH_COSTS, ConstraintUpdate, NamedCostConstraints
from safeswitch.training.policies import load_policy
from safeswitch.training.run import (
    build_model,
    learn,
    learner_env,
    load_model,
    normalized,
    open_run,
    save_checkpoint,
    save_final,
    start_run,
)

PROGRESS_FIELDS = (
    "timesteps",
    "wall_time_s",
    "episodes",
    "failures_total",
    "activation_rate",
    "failure_rate",
    "return",
)


def _takes_switching(env_id: str) -> bool:
    entry = gym.spec(env_id).entry_point
    maker: Any = gym.envs.registration.load_env_creator(entry) if isinstance(entry, str) else entry
    try:
        return "switching" in inspect.signature(maker).parameters
    except (TypeError, ValueError):
        return False


def make_supervised_env(
    env_id: str,
    switching: str | None = None,
    penalty: float | None = None,
    logic_params: dict[str, Any] | None = None,
    **kwargs: Any,
) -> gym.Env[Any, Any]:
    """The environment ``env_id`` under a switching logic (see the module docstring);
    ``logic_params`` configure a logic registered with the class of its parameters.

    Raises:
        ConfigError: ``env_id`` takes no ``switching`` and has no registered Safety controller.
        LogicContextError: The logic does not serve this plant (the message starts with
            ``env_id``: the plant inside may be registered under another id).
    """
    env_id = plain_env_id(env_id)
    try:
        return _make_supervised(env_id, switching, penalty, logic_params, **kwargs)
    except LogicContextError as exc:
        raise LogicContextError(f"{env_id}: {exc}") from exc


def _make_supervised(
    env_id: str,
    switching: str | None,
    penalty: float | None,
    logic_params: dict[str, Any] | None,
    **kwargs: Any,
) -> gym.Env[Any, Any]:
    if _takes_switching(env_id):
        extra: dict[str, Any] = {} if switching is None else {"switching": switching}
        if penalty is not None:
            extra["penalty"] = penalty
        if logic_params:
            extra["logic_params"] = logic_params
        return gym.make(env_id, **kwargs, **extra)
    registered = safety_controller_for(env_id)
    if registered is None:
        raise ConfigError(
            f"{env_id} takes no switching logic and no Safety controller is registered for it; "
            "register one with safeswitch.core.registry.register_safety_controller"
        )
    env = gym.make(env_id, **kwargs)
    return SafeSwitch(
        env,
        registered.factory(env),
        switching or "none",
        penalty=-25.0 if penalty is None else penalty,
        state_fn=registered.state_fn,
        logic_params=logic_params,
    )


class EnvMonitor(BaseCallback):
    """Failures (as the plant declares them), safety activations and returns of a run on any
    environment, logged once per rollout to ``progress.csv`` and TensorBoard
    (``safety/failures_total``, ``safety/activation_rate``, ``safety/failure_rate``,
    ``reward/return``)."""

    def __init__(
        self,
        progress_csv: Path,
        checkpoint_every: int,
        save_checkpoint: Callable[[EnvMonitor], object],
        totals: dict[str, float] | None = None,
        failed: Callable[[dict[str, Any]], bool] | None = None,
    ) -> None:
        super().__init__()
        self.progress_csv = progress_csv
        self.checkpoint_every = checkpoint_every
        self.save_checkpoint = save_checkpoint
        self.failed = failed or failure_check(None)
        totals = dict(totals or {})
        if "collisions" in totals:  # a checkpoint written before failures were declared
            totals.setdefault("failures", totals.pop("collisions"))
        self.totals: dict[str, float] = {
            "failures": 0,
            "safety_steps": 0,
            "episodes": 0,
            "steps": 0,
            "wall_time_s": 0.0,
        } | totals
        self._started = time.perf_counter()
        self._wall_before = float(self.totals["wall_time_s"])
        self._next_checkpoint = 0
        self._rollout: dict[str, list[float]] = {"safety": [], "failure": [], "return": []}

    @property
    def wall_time_s(self) -> float:
        return self._wall_before + time.perf_counter() - self._started

    def _on_training_start(self) -> None:
        every = self.checkpoint_every
        self._next_checkpoint = (self.num_timesteps // every + 1) * every

    def _on_step(self) -> bool:
        for info, done in zip(self.locals["infos"], self.locals["dones"], strict=True):
            active = bool(info.get("safety_active", False))
            self.totals["steps"] += 1
            self.totals["safety_steps"] += active
            self._rollout["safety"].append(float(active))
            if done:
                failed = self.failed(info)
                self.totals["episodes"] += 1
                self.totals["failures"] += failed
                self._rollout["failure"].append(float(failed))
                if "episode" in info:
                    self._rollout["return"].append(float(info["episode"]["r"]))
        if self.num_timesteps >= self._next_checkpoint:
            self.totals["wall_time_s"] = self.wall_time_s
            self.save_checkpoint(self)
            self._next_checkpoint += self.checkpoint_every
        return True

    def _on_rollout_end(self) -> None:
        r = self._rollout
        row: dict[str, float] = {
            "timesteps": self.num_timesteps,
            "wall_time_s": round(self.wall_time_s, 3),
            "episodes": self.totals["episodes"],
            "failures_total": self.totals["failures"],
            "activation_rate": float(np.mean(r["safety"])) if r["safety"] else 0.0,
        }
        if r["failure"]:
            row["failure_rate"] = float(np.mean(r["failure"]))
        if r["return"]:
            row["return"] = float(np.mean(r["return"]))
        for key, tag in (
            ("failures_total", "safety/failures_total"),
            ("activation_rate", "safety/activation_rate"),
            ("failure_rate", "safety/failure_rate"),
            ("return", "reward/return"),
        ):
            if key in row:
                self.logger.record(tag, row[key])
        new_file = not self.progress_csv.exists()
        with open(self.progress_csv, "a", newline="", encoding="utf-8") as handle:
            writer = csv.DictWriter(handle, fieldnames=PROGRESS_FIELDS)
            if new_file:
                writer.writeheader()
            writer.writerow({k: row.get(k, "") for k in PROGRESS_FIELDS})
        self._rollout = {"safety": [], "failure": [], "return": []}


def _make_vec(config: EnvTrainConfig) -> VecMonitor:
    def make() -> gym.Env[Any, Any]:
        return make_supervised_env(
            config.env_id,
            config.switching,
            config.penalty,
            config.logic_params,
            **config.env_kwargs,
        )

    vec = DummyVecEnv([make] * config.n_envs)
    vec.seed(config.seed)
    return VecMonitor(vec)


def check_costs(config: EnvTrainConfig) -> None:
    """One step of the plant, to check that it publishes every cost the configuration
    constrains in ``info["costs"]``.

    Raises:
        ConfigError: Naming the first cost it does not publish and the ones it does.
    """
    env = make_supervised_env(
        config.env_id, config.switching, config.penalty, config.logic_params,
        **config.env_kwargs,
    )  # fmt: skip
    try:
        env.reset(seed=config.seed)
        info = env.step(env.action_space.sample())[4]
    finally:
        env.close()
    published = info.get("costs", {})
    missing = sorted(set(config.constraints) - set(SWITCH_COSTS) - set(published))
    if missing:
        raise ConfigError(
            f"constraints.{missing[0]}: {config.env_id} publishes no such cost in "
            f"info['costs'] (it publishes: {', '.join(sorted(published)) or 'none'})"
        )


def run_episodes(
    env: gym.Env[Any, Any],
    act: Callable[[Any], Any],
    episodes: int,
    seed: int,
    failed: Callable[[dict[str, Any]], bool] | None = None,
) -> dict[str, Any]:
    """``episodes`` episodes of ``act`` (observation → action), reset with seeds ``seed``,
    ``seed + 1``, …; returns ``evaluate --json``'s fields for a generic environment, failures
    read with ``failed`` (the plant's declared failure, see
    :func:`~safeswitch.core.registry.failure_of`)."""
    failed = failed or failure_check(None)
    returns, lengths, safety, failures = [], [], [], 0
    for k in range(episodes):
        obs, _ = env.reset(seed=seed + k)
        total, steps, active, done = 0.0, 0, 0, False
        info: dict[str, Any] = {}
        while not done:
            obs, reward, terminated, truncated, info = env.step(act(obs))
            total += float(reward)
            steps += 1
            active += bool(info.get("safety_active", False))
            done = terminated or truncated
        returns.append(total)
        lengths.append(steps)
        safety.append(active)
        failures += failed(info)
    return {
        "episodes": episodes,
        "failures": failures,
        "steps": int(sum(lengths)),
        "safety_activation_episodes": int(sum(a > 0 for a in safety)),
        "safety_activation_steps": int(sum(safety)),
        "safety_share": float(sum(safety) / sum(lengths)) if lengths else None,
        "mean_return": float(np.mean(returns)) if returns else None,
        "mean_episode_steps": float(np.mean(lengths)) if lengths else None,
    }


def train_env(
    config: EnvTrainConfig,
    out: str | Path,
    resume: bool = False,
    progress_bar: bool = True,
    callbacks: list[BaseCallback] | None = None,
) -> dict[str, Any]:
    """Train (or resume) a run on ``config.env_id``; returns ``metrics.json``'s contents.
    ``callbacks``: further SB3 callbacks (e.g. a benchmark's own recording)."""
    run = Path(out)
    checkpoint = open_run(run, resume)
    if checkpoint is not None:
        config = load_env_config(run / "config.yaml")
    torch.set_num_threads(config.torch_threads)
    vec = _make_vec(config)  # a logic that does not fit the plant fails here, nothing written
    if config.constraints:
        check_costs(config)  # a cost the plant does not publish: refused before anything is written
    if checkpoint is None:
        start_run(run, dump_env_config(config))
    constrained = NamedCostConstraints(vec, config.constraints) if config.constraints else None
    if constrained is not None and checkpoint is not None and "constraints" in checkpoint:
        constrained.restore(checkpoint["constraints"])
    env = normalized(constrained or vec, config, checkpoint)
    if checkpoint is not None:
        model = load_model(checkpoint, learner_env(env, config), run)
    else:
        model = build_model(config, learner_env(env, config), run / "tb")

    def save(m: EnvMonitor) -> Path:
        state: dict[str, Any] = {"totals": m.totals}
        if constrained is not None:
            state["constraints"] = constrained.state()
        return save_checkpoint(run, model, env, state)

    failed = failure_of(plain_env_id(config.env_id))
    monitor = EnvMonitor(
        run / "progress.csv",
        config.checkpoint_every,
        save,
        checkpoint["totals"] if checkpoint else None,
        failed,
    )
    learn(
        model, run, config.timesteps, monitor, lambda: save(monitor), resume, progress_bar,
        [*(callbacks or []), *([ConstraintUpdate(constrained)] if constrained else [])],
    )  # fmt: skip
    wall = monitor.wall_time_s
    save_final(run, model, env)
    started = time.perf_counter()
    evaluation: dict[str, Any] = {}
    if config.eval_episodes:
        policy = load_policy(run)
        eval_env = make_supervised_env(
            config.env_id,
            config.switching,
            config.penalty,
            config.logic_params,
            **config.env_kwargs,
        )
        evaluation = run_episodes(
            eval_env, policy.act_one, config.eval_episodes, config.eval_seed, failed
        )
        eval_env.close()
    t = monitor.totals
    metrics: dict[str, Any] = {
        "env_id": config.env_id,
        "switching": config.switching,
        "timesteps": int(model.num_timesteps),
        "wall_time_s": round(wall, 2),
        "steps_per_s": round(model.num_timesteps / max(wall, 1e-9), 1),
        "n_envs": config.n_envs,
        "torch_threads": config.torch_threads,
        "seed": config.seed,
        "training": {
            "failures": int(t["failures"]),
            "safety_activation_steps": int(t["safety_steps"]),
            "episodes": int(t["episodes"]),
            "steps": int(t["steps"]),
        },
        "evaluation": {
            "seed": config.eval_seed,
            **evaluation,
            "wall_time_s": round(time.perf_counter() - started, 2),
        },
    }
    if constrained is not None:
        metrics["constraints"] = constrained.state()
    write_json(run / "metrics.json", metrics)
    return metrics
