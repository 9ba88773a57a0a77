"""Any registered Gymnasium environment under a switching logic, as a plant of the one training
pipeline (:mod:`safeswitch.training.pipeline`) and for evaluation.

``safeswitch train --env ID`` and ``safeswitch evaluate --env ID`` work for

* an environment whose constructor takes ``switching=`` (and ``penalty=``) itself — a
  safeswitch-aware environment such as ``safeswitch/Highway-v0``; or
* any environment with a ``Box`` action space for which a Safety controller is registered
  (:func:`safeswitch.register_safety_controller`): it is wrapped in
  :class:`~safeswitch.core.wrappers.SafeSwitch` with the named logic.

The run directory is the left turn's (``config.yaml``, ``progress.csv``, ``tb/``, checkpoints,
``model.zip``, ``vecnormalize.pkl``, ``metrics.json`` last; ``safeswitch train`` then draws
``training_curves.png``), and ``--resume`` works the same.
Failures are what the plant declares (``register_safety_controller(..., failure=)``: an
``info`` key or a predicate on the last step's ``info``; by default ``crashed`` or
``collision``), counted in training and evaluation as ``failures``.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecMonitor

from safeswitch.core.config import ConfigError
from safeswitch.core.registry import (
    LogicContextError,
    failure_check,
    failure_of,
    plain_env_id,
    safety_controller_for,
)
from safeswitch.core.switching import SwitchingError
from safeswitch.core.tally import StepTally
from safeswitch.core.wrappers import SafeSwitch, require_box
from safeswitch.training.callbacks import RunMonitor
from safeswitch.training.config import EnvTrainConfig, dump_env_config
from safeswitch.training.constraints import (
    CONSTRAINTS_LOG,
    SWITCH_COSTS,
    ConstraintUpdate,
    NamedCostConstraints,
)
from safeswitch.training.plant import Plant
from safeswitch.training.policies import load_policy
from safeswitch.training.validation import BestPolicy

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
    env = gym.make(env_id, **kwargs)
    try:  # a plant the switch cannot wrap is refused for that, not for its missing controller
        require_box(env.action_space, f"SafeSwitch around {env_id}")
        if registered is None:
            raise ConfigError(
                f"{env_id} takes no switching logic and no Safety controller is registered for "
                "it; register one with safeswitch.register_safety_controller"
            )
    except (SwitchingError, ConfigError):
        env.close()
        raise
    return SafeSwitch(
        env,
        registered.factory(env),
        switching or "none",
        penalty=-25.0 if penalty is None else penalty,
        state_fn=registered.state_fn,
        logic_params=logic_params,
    )


#: TensorBoard tags of a plant's progress columns.
TAGS = {
    "failures_total": "safety/failures_total",
    "activation_rate": "safety/activation_rate",
    "failure_rate": "safety/failure_rate",
    "return": "reward/return",
}


class EnvMonitor(RunMonitor):
    """Failures (as the plant declares them), safety activations and returns of a run on any
    environment, logged once per rollout to ``progress.csv`` and TensorBoard
    (``safety/failures_total``, ``safety/activation_rate``, ``safety/failure_rate``,
    ``reward/return``; the arguments are :class:`~safeswitch.training.callbacks.RunMonitor`'s,
    ``failed``: whether an episode's last ``info`` is a failure)."""

    def __init__(
        self,
        progress_csv: Path,
        checkpoint_every: int,
        save_checkpoint: Callable[[EnvMonitor], object],
        totals: dict[str, float] | None = None,
        failed: Callable[[dict[str, Any]], bool] | None = None,
    ) -> None:
        self.failed = failed or failure_check(None)
        totals = dict(totals or {})
        if "collisions" in totals:  # a checkpoint written before failures were declared
            totals.setdefault("failures", totals.pop("collisions"))
        counters: dict[str, float] = {
            "failures": 0,
            "safety_steps": 0,
            "episodes": 0,
            "steps": 0,
            "wall_time_s": 0.0,
        } | totals
        super().__init__(progress_csv, checkpoint_every, save_checkpoint, counters, PROGRESS_FIELDS)
        self._rollout: dict[str, list[float]] = {"safety": [], "failure": [], "return": []}

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
        self.checkpoint_if_due()
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
        self.write_row(row, TAGS)
        self._rollout = {"safety": [], "failure": [], "return": []}


def check_costs(config: EnvTrainConfig, make_env: Callable[[], gym.Env[Any, Any]]) -> None:
    """One step of the plant, to check that it publishes every cost the configuration
    constrains in ``info["costs"]``.

    Raises:
        ConfigError: Naming the first cost it does not publish and the ones it does.
    """
    env = make_env()
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
    :func:`~safeswitch.core.registry.failure_of`). ``safety_reasons``: the steps the Safety
    controller acted, by the logic's reason (``info["reason"]``), most frequent first;
    ``cost_steps``: per named cost the plant publishes (``info["costs"]``), the steps it was
    positive; ``safety_cost_steps``: how many of those the Safety controller drove."""
    failed = failed or failure_check(None)
    returns, lengths, safety, failures = [], [], [], 0
    tally = StepTally()
    for k in range(episodes):
        obs, _ = env.reset(seed=seed + k)
        total, steps, active, done = 0.0, 0, 0, False
        info: dict[str, Any] = {}
        while not done:
            obs, reward, terminated, truncated, info = env.step(act(obs))
            total += float(reward)
            steps += 1
            active += tally.add(info)
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
        **tally.summary(),
    }


class GymLearning:
    """A Gymnasium plant's learning-only wrapper: the constraints on its named costs and the
    switch's (``constraints``; none: the environments as they are)."""

    def __init__(self, vec: VecEnv, constraints: dict[str, Any]) -> None:
        self.constrained = NamedCostConstraints(vec, constraints) if constraints else None
        self.env: VecEnv = self.constrained or vec

    def schedules(self, run: Path | None = None) -> list[BaseCallback]:
        if self.constrained is None:
            return []
        return [ConstraintUpdate(self.constrained, run / CONSTRAINTS_LOG if run else None)]

    def state(self) -> dict[str, Any]:
        return {} if self.constrained is None else {"constraints": self.constrained.state()}

    def restore(self, checkpoint: dict[str, Any]) -> None:
        if self.constrained is not None and "constraints" in checkpoint:
            self.constrained.restore(checkpoint["constraints"])


class EpisodeValidator(BestPolicy):
    """Validation on any plant: the deterministic policy drives ``validation.episodes``
    episodes reset with seeds ``validation.seed``, ``+ 1``, …; ``collisions_then_return``
    ranks the fewest failures (as the plant declares them) first."""

    fields = ("timesteps", "mean_return", "failures", "safety_activation_episodes",
              "safety_share", "best")  # fmt: skip

    def __init__(
        self,
        config: EnvTrainConfig,
        run: Path,
        make_env: Callable[[], gym.Env[Any, Any]],
        failed: Callable[[dict[str, Any]], bool],
    ) -> None:
        super().__init__(config, run)
        self.make_env, self.failed = make_env, failed

    def validate(self) -> dict[str, Any]:
        v = self.config.validation
        env = self.make_env()
        try:
            return run_episodes(env, self._policy().act_one, v.episodes, v.seed, self.failed)
        finally:
            env.close()

    def key(self, summary: dict[str, Any]) -> tuple[float, ...]:
        mean_return = float(summary["mean_return"])
        if self.config.validation.criterion == "collisions_then_return":
            return (-float(summary["failures"]), mean_return)
        return (mean_return,)

    def record(self, summary: dict[str, Any]) -> dict[str, Any]:
        super().record(summary)
        self.logger.record(f"{self.scalars}/failures", summary["failures"])
        self.logger.record(f"{self.scalars}/safety_share", summary["safety_share"])
        return {}


class GymPlant(Plant):
    """A Gymnasium plant under a switching logic as the one pipeline's plant.

    Args:
        config: The run's configuration.
        make_env: Builds one environment (default: ``config.env_id`` under its switching
            logic, see :func:`make_supervised_env`).
    """

    def __init__(
        self, config: EnvTrainConfig, make_env: Callable[[], gym.Env[Any, Any]] | None = None
    ) -> None:
        self.config = config
        self.make_env = make_env or partial(
            make_supervised_env, config.env_id, config.switching, config.penalty,
            config.logic_params, **config.env_kwargs,
        )  # fmt: skip
        self.failed = failure_of(plain_env_id(config.env_id))

    def dump(self) -> str:
        return dump_env_config(self.config)

    def vec_env(self) -> VecMonitor:
        vec = DummyVecEnv([self.make_env] * self.config.n_envs)
        vec.seed(self.config.seed)
        return VecMonitor(vec)

    def check(self, vec: VecEnv) -> None:
        if self.config.constraints:
            check_costs(self.config, self.make_env)

    def learning(self, vec: VecEnv) -> GymLearning:
        return GymLearning(vec, self.config.constraints)

    def monitor(
        self, run: Path, save: Callable[[Any], object], totals: dict[str, float] | None
    ) -> EnvMonitor:
        return EnvMonitor(
            run / "progress.csv", self.config.checkpoint_every, save, totals, self.failed
        )

    def validator(self, run: Path) -> EpisodeValidator | None:
        if not self.config.validation.every:
            return None
        return EpisodeValidator(self.config, run, self.make_env, self.failed)

    def evaluate(self, run: Path) -> dict[str, Any]:
        policy = load_policy(run)
        env = self.make_env()
        try:
            c = self.config
            return run_episodes(env, policy.act_one, c.eval_episodes, c.eval_seed, self.failed)
        finally:
            env.close()

    def header(self, run: Path) -> dict[str, Any]:
        return {"env_id": self.config.env_id, "switching": self.config.switching}

    def training(self, totals: dict[str, float]) -> dict[str, Any]:
        t = totals
        return {
            "failures": int(t["failures"]),
            "safety_activation_steps": int(t["safety_steps"]),
            "episodes": int(t["episodes"]),
            "steps": int(t["steps"]),
        }
