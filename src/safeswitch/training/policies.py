"""Trained policies as rollout controllers: a run directory, one of its checkpoints, an
interrupted run, or a policy that ships with the package.

A policy is only as good as the observation statistics it was trained with: a policy trained
with ``VecNormalize`` and fed raw observations drives confidently and wrongly. So loading
refuses a policy whose run normalised observations but whose ``vecnormalize.pkl`` is missing or
unreadable, and reads the statistics with SB3's own ``VecNormalize.load``.
"""

from __future__ import annotations

import pickle
import zipfile
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from numpy.typing import NDArray
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from safeswitch.evaluation.rollout import Policy
from safeswitch.leftturn.task import TaskState
from safeswitch.training.config import EnvTrainConfig, TrainConfig, load_any_config
from safeswitch.training.ppo import SwitchPPO
from safeswitch.training.shipped import SHIPPED, SHIPPED_DIR

__all__ = ["SHIPPED", "SHIPPED_DIR", "PolicyLoadError", "TrainedPolicy", "load_policy"]


class PolicyLoadError(ValueError):
    """A policy cannot be loaded as asked; the message says which file and why."""


@dataclass
class TrainedPolicy:
    """A PPO policy with the observation statistics it was trained with.

    Attributes:
        model: The SB3 model.
        normalizer: The run's ``VecNormalize`` (observation statistics; ``None`` if the run
            did not normalise observations).
        config: The run's training configuration.
        path: The folder the model was loaded from (a run or one of its checkpoints).
    """

    model: SwitchPPO
    normalizer: VecNormalize | None
    config: TrainConfig | EnvTrainConfig
    path: Path

    def normalise(self, obs: NDArray[np.float32]) -> NDArray[np.float32]:
        if self.normalizer is None:
            return obs
        return np.asarray(self.normalizer.normalize_obs(obs), dtype=np.float32)

    def act(self, obs: NDArray[np.float32], deterministic: bool = True) -> NDArray[np.float64]:
        """Actions ``[B]`` in [-1, 1] for observations ``[B, obs_dim]`` (``[B, A]`` for a
        policy with more than one action, observations ``[B, *obs_shape]``; deterministic: the
        Gaussian's mean, see :meth:`_mean_action`)."""
        normalised = self.normalise(obs)
        if deterministic and self._actor is not None:
            actions = self._mean_action(normalised)
        else:
            actions, _ = self.model.predict(normalised, deterministic=deterministic)
        width = int(np.prod(self.model.action_space.shape or (1,)))
        shape = (obs.shape[0],) if width == 1 else (obs.shape[0], width)
        return np.asarray(actions, dtype=np.float64).reshape(shape)

    @cached_property
    def _actor(self) -> list[torch.nn.Module] | None:
        """The actor's layers (Linear and Tanh only, then the action head) for
        :meth:`_mean_action`, or ``None`` when the policy is built otherwise (then SB3's
        ``predict`` serves)."""
        policy = self.model.policy
        layers = [*policy.mlp_extractor.policy_net, policy.action_net]
        plain = (
            isinstance(policy.features_extractor, FlattenExtractor)
            and not policy.squash_output
            and isinstance(policy.action_space, spaces.Box)
            and all(isinstance(m, (torch.nn.Linear, torch.nn.Tanh)) for m in layers)
        )
        return layers if plain else None

    def _mean_action(self, obs: NDArray[np.float32]) -> NDArray[np.float32]:
        """SB3's deterministic ``predict`` (the Gaussian's mean, clipped to the action space)
        computed layer by layer, with the tanh in numpy: this CPU build of torch evaluates tanh
        element by element (1.2 ms for 4,096 × 128 against numpy's 0.09 ms), which made
        inference two thirds of a campaign's time. Equal to ``predict`` up to float32 rounding
        in the last bit of a tanh (``tests/training/test_policies.py``)."""
        space = self.model.policy.action_space
        assert isinstance(space, spaces.Box)  # checked by _actor
        return np.clip(self.raw_mean(obs), space.low, space.high)

    def raw_mean(self, obs: NDArray[np.float32]) -> NDArray[np.float32]:
        """The Gaussian's mean on normalised observations ``[B, obs_dim]``, before it is
        clipped to the action bounds (what :meth:`_mean_action` clips; a mean far beyond a
        bound is one no sample of a small exploration noise falls within). Needs a plain
        MLP actor (:attr:`_actor`)."""
        layers = self._actor
        assert layers is not None, "the actor is not a plain MLP of Linear and Tanh layers"
        with torch.inference_mode():
            x = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32).reshape(len(obs), -1))
            for layer in layers:
                if isinstance(layer, torch.nn.Linear):
                    x = torch.nn.functional.linear(x, layer.weight, layer.bias)
                else:
                    values = x.numpy()
                    np.tanh(values, out=values)
            return x.numpy()

    def act_one(self, obs: Any, deterministic: bool = True) -> NDArray[Any]:
        """The action for one observation of any environment (its action space's shape)."""
        batch = np.asarray(obs, dtype=np.float32)[None]
        actions, _ = self.model.predict(self.normalise(batch), deterministic=deterministic)
        return np.asarray(actions)[0]

    def as_policy(self, deterministic: bool = True) -> Policy:
        def policy(obs: NDArray[np.float32], state: TaskState, tick: int) -> NDArray[np.float64]:
            return self.act(obs, deterministic)

        return policy


class _Spaces(VecEnv):
    """A VecEnv that only has spaces: what ``VecNormalize.load`` needs to check the statistics
    against (nothing is ever stepped)."""

    def __init__(self, observation_space: spaces.Space[Any], action_space: spaces.Space[Any]):
        super().__init__(1, observation_space, action_space)

    def reset(self) -> Any:
        raise NotImplementedError

    def step_async(self, actions: np.ndarray) -> None:
        raise NotImplementedError

    def step_wait(self) -> Any:
        raise NotImplementedError

    def close(self) -> None:
        return None

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [None]  # SB3 asks for the render mode at construction

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        raise NotImplementedError

    def env_method(
        self, method_name: str, *args: Any, indices: Any = None, **kwargs: Any
    ) -> list[Any]:
        raise NotImplementedError

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False]


def resolve_model_dir(model: str | Path) -> Path:
    """The folder holding ``model.zip``: a shipped policy by name (:data:`SHIPPED`), a run
    directory or its ``model.zip``, one of its checkpoints (``run/checkpoints/step_…``), or —
    for a run that was interrupted before it finished — its latest complete checkpoint."""
    path = SHIPPED_DIR / SHIPPED[str(model)] if str(model) in SHIPPED else Path(model)
    if path.suffix == ".zip" and path.is_file():  # SB3 users pass the model file itself
        if path.name != "model.zip":
            raise FileNotFoundError(
                f"{path}: a policy is loaded from its run directory, where it is model.zip "
                "beside config.yaml and vecnormalize.pkl; pass that directory"
            )
        path = path.parent
    if (path / "model.zip").is_file():
        return path
    checkpoints = sorted(
        (p for p in (path / "checkpoints").glob("step_*") if (p / "state.json").is_file()),
        key=lambda p: p.name,
    )
    if checkpoints and (checkpoints[-1] / "model.zip").is_file():
        return checkpoints[-1]
    known = ", ".join(sorted(SHIPPED))
    raise FileNotFoundError(
        f"no trained policy at {path} (expected model.zip there, or a checkpoint under "
        f"{path / 'checkpoints'}); pass a run directory, a checkpoint or one of: {known}"
    )


def run_config_path(model_dir: Path) -> Path:
    """The ``config.yaml`` of the run a model folder belongs to: the run's own, one level up
    for its ``best/`` and ``last/`` policies, two for a checkpoint."""
    for folder in (model_dir, model_dir.parent, model_dir.parent.parent):
        if (folder / "config.yaml").is_file():
            return folder / "config.yaml"
    raise FileNotFoundError(f"no config.yaml for the policy in {model_dir} (nor in its run)")


def trained_env_id(policy: TrainedPolicy) -> str:
    """The Gymnasium id of the environment the policy was trained on."""
    if isinstance(policy.config, EnvTrainConfig):
        return policy.config.env_id
    return "safeswitch/LeftTurnTraffic-v0" if policy.config.traffic else "safeswitch/LeftTurn-v0"


def check_fits(
    policy: TrainedPolicy,
    env_id: str,
    observation_space: spaces.Space[Any],
    action_space: spaces.Space[Any],
) -> None:
    """Refuse, before the first step, a policy whose observation or action space is not the
    environment's (one line naming both).

    Raises:
        PolicyLoadError: The shapes differ.
    """
    mine = (policy.model.observation_space.shape, policy.model.action_space.shape)
    theirs = (observation_space.shape, action_space.shape)
    if mine != theirs:
        raise PolicyLoadError(
            f"the policy in {policy.path} was trained on {trained_env_id(policy)} (observation "
            f"{mine[0]}, action {mine[1]}); {env_id} has observation {theirs[0]}, action "
            f"{theirs[1]}"
        )


def load_policy(model: str | Path) -> TrainedPolicy:
    """Load a policy (see :func:`resolve_model_dir` for what ``model`` may name).

    Sets torch to one thread: inference batches are small (a 3 × 128 network on at most a few
    thousand observations), and a second thread competing with another busy process made an
    evaluation 17 times slower on a two-core machine (3.5 s against 60 s, 200 episodes in
    traffic).

    Raises:
        FileNotFoundError: Nothing to load there.
        PolicyLoadError: ``model.zip`` or ``vecnormalize.pkl`` is corrupt or missing although
            the run normalised observations.
        safeswitch.core.config.ConfigError: The run's ``config.yaml`` is invalid.
    """
    path = resolve_model_dir(model)
    config = load_any_config(run_config_path(path))
    torch.set_num_threads(1)
    try:
        ppo = SwitchPPO.load(path / "model.zip", device="cpu")
    except (zipfile.BadZipFile, EOFError, KeyError, ValueError, RuntimeError) as exc:
        raise PolicyLoadError(f"{path / 'model.zip'} is not a readable SB3 model ({exc})") from exc
    stats = path / "vecnormalize.pkl"
    if not config.ppo.normalize_observations:
        return TrainedPolicy(ppo, None, config, path)
    if not stats.is_file():
        raise PolicyLoadError(
            f"{stats} is missing: the run normalised its observations "
            "(ppo.normalize_observations), and without its statistics the policy would see "
            "raw observations and act wrongly"
        )
    try:
        normalizer = VecNormalize.load(str(stats), _Spaces(ppo.observation_space, ppo.action_space))
    except (pickle.UnpicklingError, EOFError, AttributeError, ValueError, TypeError) as exc:
        raise PolicyLoadError(f"{stats} is truncated or corrupt ({exc})") from exc
    normalizer.training = False
    normalizer.norm_reward = False
    return TrainedPolicy(ppo, normalizer, config, path)
