"""Trained policies as rollout controllers: load a run directory or a shipped policy."""

from __future__ import annotations

import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from safeswitch.evaluation.rollout import Policy
from safeswitch.leftturn.task import TaskState
from safeswitch.training.ppo import SwitchPPO

#: Where the shipped policies live, one folder each.
SHIPPED_DIR = Path(__file__).resolve().parent.parent / "policies"
SHIPPED = {
    "shipped": "paper",
    "paper": "paper",
    "paper-scratch": "paper_scratch",
    "no-adas": "no_adas",
    "certified": "certified",
    "none": "none",
}


@dataclass
class TrainedPolicy:
    """A PPO policy with the observation statistics it was trained with.

    Attributes:
        model: The SB3 model.
        obs_mean: Running mean of the observations ``[6]`` (zeros if not normalised).
        obs_var: Running variance ``[6]`` (ones if not normalised).
        clip_obs: Clipping of normalised observations.
        epsilon: Added to the variance, as ``VecNormalize`` does.
        path: Where it was loaded from.
    """

    model: SwitchPPO
    obs_mean: NDArray[np.float64]
    obs_var: NDArray[np.float64]
    clip_obs: float
    epsilon: float
    path: Path

    def normalise(self, obs: NDArray[np.float32]) -> NDArray[np.float32]:
        z = (obs - self.obs_mean) / np.sqrt(self.obs_var + self.epsilon)
        return np.clip(z, -self.clip_obs, self.clip_obs).astype(np.float32)

    def act(self, obs: NDArray[np.float32], deterministic: bool = True) -> NDArray[np.float64]:
        """Actions ``[B]`` in [-1, 1] for observations ``[B, 6]``."""
        actions, _ = self.model.predict(self.normalise(obs), deterministic=deterministic)
        return np.asarray(actions, dtype=np.float64).reshape(obs.shape[0])

    def as_policy(self, deterministic: bool = True) -> Policy:
        def policy(obs: NDArray[np.float32], state: TaskState, tick: int) -> NDArray[np.float64]:
            return self.act(obs, deterministic)

        return policy


def resolve_model_dir(model: str | Path) -> Path:
    """A run directory, or the folder of a shipped policy named ``shipped``, ``paper``,
    ``paper-scratch``, ``no-adas``, ``certified`` or ``none``."""
    path = SHIPPED_DIR / SHIPPED[str(model)] if str(model) in SHIPPED else Path(model)
    if not (path / "model.zip").is_file():
        known = ", ".join(sorted(SHIPPED))
        raise FileNotFoundError(
            f"no trained policy at {path} (expected model.zip there); pass a run directory "
            f"or one of: {known}"
        )
    return path


def load_policy(model: str | Path) -> TrainedPolicy:
    """Load a policy from a run directory or by shipped name (see :func:`resolve_model_dir`)."""
    path = resolve_model_dir(model)
    ppo = SwitchPPO.load(path / "model.zip", device="cpu")
    stats = path / "vecnormalize.pkl"
    if stats.is_file():
        with open(stats, "rb") as handle:
            vecnorm = pickle.load(handle)
        return TrainedPolicy(
            ppo,
            vecnorm.obs_rms.mean.copy(),
            vecnorm.obs_rms.var.copy(),
            float(vecnorm.clip_obs),
            float(vecnorm.epsilon),
            path,
        )
    return TrainedPolicy(ppo, np.zeros(6), np.ones(6), np.inf, 0.0, path)
