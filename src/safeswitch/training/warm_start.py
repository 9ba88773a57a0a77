"""Warm start: behaviour cloning of a planner into the PPO actor before PPO begins (ours).

PPO from a random initialisation lands, on this task, in one of two basins: always yield
(safe, comfortable, slow) or cut and lean on the Safety controller (README, Training). The
planner (:mod:`safeswitch.evaluation.planner`) shows what a throttle-only controller can do
under the paper logic, so the actor first learns to imitate it:

1. the planner drives ``episodes`` scenarios under the run's switching logic; every tick's
   observation is stored with the planner's action;
2. ``rounds`` DAgger rounds: the cloned policy drives new scenarios and the planner labels each
   tick with what it would have done (so the clone learns to recover from its own mistakes).
   These rounds run under the *certified* switching logic whatever the run uses: an imperfect
   clone must not collide while it is being taught (training stays collision-free), and the
   filter's backup keeps its states near the ones it will meet;
3. after each round the actor is fitted to all labels so far (mean squared error of the
   Gaussian's mean, ``epochs`` passes, Adam).

In traffic the teacher can be the gap planner (``teacher: gap_planner``,
:mod:`safeswitch.evaluation.traffic_planner`), which waits for a gap the certified filter
accepts among all the vehicles; the planner sees only the north car.

The observation statistics of ``VecNormalize`` are set from the demonstrations, so the clone
sees exactly the inputs PPO will give it, and by default stay so for the whole run
(``freeze_obs_stats``). The scenarios come from the run's seed on
environment ids no training environment uses.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecNormalize

from safeswitch.evaluation.planner import Planner
from safeswitch.evaluation.rollout import Policy, rollout
from safeswitch.evaluation.traffic_planner import GapPlanner
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.task import TaskState
from safeswitch.training.config import TrainConfig
from safeswitch.training.ppo import SwitchPPO

#: Environment ids of the demonstration scenarios: round ``r`` uses ``(r + 1) · this + i``.
DEMO_ENV_OFFSET = 1_000_000


class FrozenRunningMeanStd(RunningMeanStd):
    """Running statistics that no longer update: ``VecNormalize``'s observation statistics
    after a warm start with ``freeze_obs_stats`` (pickled with it, so a resumed run and a
    loaded policy keep them)."""

    def update(self, arr: NDArray[np.float64]) -> None:
        """Leave the statistics as they are."""


def actor_mean(model: SwitchPPO, obs: torch.Tensor) -> torch.Tensor:
    """The Gaussian's mean ``[B, 1]`` for normalised observations ``[B, 6]``."""
    policy = model.policy
    features = policy.extract_features(obs)
    assert isinstance(features, torch.Tensor)  # a flat Box observation: one tensor
    latent = policy.mlp_extractor.forward_actor(features)
    return policy.action_net(latent)


def fit_actor(
    model: SwitchPPO,
    obs: NDArray[np.float32],
    actions: NDArray[np.float32],
    epochs: int,
    lr: float,
    *,
    clipped: bool = False,
) -> float:
    """Fit the actor's mean to ``actions`` ``[N]`` at normalised ``obs`` ``[N, 6]``; returns
    the last epoch's mean squared error. ``clipped``: the policy acts with its mean clipped
    to [-1, 1], so a mean beyond a bound the label sits on is no error (a full-throttle label
    leaves a mean of 1.8 where it is)."""
    x = torch.as_tensor(obs)
    y = torch.as_tensor(actions).reshape(-1, 1)
    # A learned log std gets no gradient from this loss, so Adam leaves it alone.
    optimiser = torch.optim.Adam(model.actor_parameters(), lr=lr)
    generator = torch.Generator().manual_seed(int(model.seed or 0))
    batch = 1024
    loss_sum = 0.0
    for _ in range(epochs):
        order = torch.randperm(x.shape[0], generator=generator)
        loss_sum = 0.0
        for start in range(0, x.shape[0], batch):
            idx = order[start : start + batch]
            loss = torch.mean(action_error(actor_mean(model, x[idx]), y[idx], clipped) ** 2)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            loss_sum += float(loss.detach()) * len(idx)
    return loss_sum / max(x.shape[0], 1)


def action_error(mean: torch.Tensor, label: torch.Tensor, clipped: bool) -> torch.Tensor:
    """``mean − label``; with ``clipped``, 0 where the label is on a bound of [-1, 1] and the
    mean beyond it."""
    error = mean - label
    if clipped:
        error = torch.where(label >= 1.0, torch.clamp(error, max=0.0), error)
        error = torch.where(label <= -1.0, torch.clamp(error, min=0.0), error)
    return error


def _labelling_driver(
    planner: Policy,
    learner: tuple[SwitchPPO, NDArray[np.float64], NDArray[np.float64]] | None,
    store: tuple[list[NDArray[np.float32]], list[NDArray[np.float32]]],
) -> Policy:
    """A rollout policy that stores every observation with the planner's action and drives
    with the planner (``learner`` None) or with the clone (``(model, obs mean, obs std)``)."""

    def drive(obs: NDArray[np.float32], state: TaskState, tick: int) -> NDArray[np.float64]:
        expert = planner(obs, state, tick)
        store[0].append(obs.copy())
        store[1].append(expert.astype(np.float32))
        if learner is None:
            return expert
        model, mean, std = learner
        z = torch.as_tensor(((obs - mean) / std).astype(np.float32))
        with torch.no_grad():
            return np.clip(actor_mean(model, z).numpy()[:, 0].astype(np.float64), -1.0, 1.0)

    return drive


def warm_start(model: SwitchPPO, env: VecNormalize, config: TrainConfig) -> dict[str, Any]:
    """Clone the planner into ``model``'s actor and set ``env``'s observation statistics.

    Returns:
        What it did: episodes driven, samples, collisions and episodes with a safety action
        (all rounds), the final fit's mean squared error, wall time.
    """
    ws = config.warm_start
    began = time.perf_counter()
    # the training task, in traffic too (the clone then sees the traffic observation)
    traffic = config.traffic_settings
    task = build_task(None, config.train_env, traffic=traffic)
    planner: Policy = (
        GapPlanner(task, ws.gap_planner)
        if ws.teacher == "gap_planner"
        else Planner(task, ws.planner)
    )
    learner_task = build_task(
        None, dataclasses.replace(config.train_env, switching="certified"), traffic=traffic
    )
    store: tuple[list[NDArray[np.float32]], list[NDArray[np.float32]]] = ([], [])
    observations, labels = store
    collisions = safety_episodes = 0
    mse = float("nan")
    size = int(np.prod(task.observation_bounds[0].shape))
    mean, std = np.zeros(size), np.ones(size)
    for round_ in range(ws.rounds + 1):
        ids = (round_ + 1) * DEMO_ENV_OFFSET + np.arange(ws.episodes)
        scenarios = task.draw_scenarios(config.seed, ids, np.zeros(ws.episodes, dtype=np.int64))

        drive = _labelling_driver(planner, None if round_ == 0 else (model, mean, std), store)
        result = rollout(task if round_ == 0 else learner_task, scenarios, drive)
        collisions += int(result.collision.sum())
        safety_episodes += int((result.safety_steps > 0).sum())
        if round_ == 0:
            demos = np.concatenate(observations).astype(np.float64)
            mean, std = demos.mean(axis=0), np.sqrt(demos.var(axis=0) + env.epsilon)
        x = ((np.concatenate(observations) - mean) / std).astype(np.float32)
        x = np.clip(x, -env.clip_obs, env.clip_obs)
        mse = fit_actor(model, x, np.concatenate(labels), ws.epochs, ws.learning_rate)
    assert isinstance(env.obs_rms, RunningMeanStd)  # a Box observation space: one set
    rms = FrozenRunningMeanStd(shape=mean.shape) if ws.freeze_obs_stats else env.obs_rms
    rms.mean, rms.var, rms.count = mean.copy(), std**2 - env.epsilon, float(len(demos))
    env.obs_rms = rms
    return {
        "episodes": ws.episodes * (ws.rounds + 1),
        "samples": int(sum(len(o) for o in observations)),
        "collisions": collisions,
        "safety_activation_episodes": safety_episodes,
        "mse": round(mse, 6),
        "wall_time_s": round(time.perf_counter() - began, 2),
    }


def start_from_policy(
    model: SwitchPPO,
    env: VecNormalize,
    source: str,
    freeze_obs_stats: bool,
    extend_inputs: bool = False,
) -> dict[str, Any]:
    """Start ``model`` from a trained policy (``warm_start.policy``): its network's weights
    (actor, critic and log std; the optimiser starts afresh) and its observation statistics
    into ``env`` (frozen if ``freeze_obs_stats``, as after a cloning).

    With ``extend_inputs`` the source may observe the first ``d`` of this run's ``D`` values:
    the first layers' weights for the other ``D - d`` inputs start at zero (normalised with
    the source's statistics, every observation gets the source's outputs), and the statistics
    of all ``D`` start from the source's (0 and 1 for the new ones) with a count of
    :data:`EXTENDED_STATS_COUNT`, so that this run's states re-estimate them within its first
    rollouts.

    Raises:
        ConfigError: ``source`` did not normalise its observations, or is not a trained
            policy (its shape is :func:`check_start_policy`'s to refuse, before the run
            directory is written).
    """
    from safeswitch.core.config import ConfigError

    began = time.perf_counter()
    trained = _start_policy(source)
    if trained.normalizer is None:
        raise ConfigError(
            f"warm_start.policy={source!r} did not normalise its observations and this run "
            "does (ppo.normalize_observations)"
        )
    theirs = trained.model.policy.state_dict()
    source_rms = trained.normalizer.obs_rms
    assert isinstance(source_rms, RunningMeanStd) and isinstance(env.obs_rms, RunningMeanStd)
    width, ours = source_rms.mean.shape[0], env.obs_rms.mean.shape[0]
    if extend_inputs and width < ours:
        theirs = extend_first_layers(theirs, model.policy.state_dict(), width)
    model.policy.load_state_dict(theirs)  # its shape checked by check_start_policy first
    rms = FrozenRunningMeanStd(shape=(ours,)) if freeze_obs_stats else env.obs_rms
    mean, var = np.zeros(ours), np.ones(ours)
    mean[:width], var[:width] = source_rms.mean, source_rms.var
    count = source_rms.count if width == ours else min(source_rms.count, EXTENDED_STATS_COUNT)
    rms.mean, rms.var, rms.count = mean, var, count
    env.obs_rms = rms
    return {
        "policy": str(trained.path),
        "parameters": int(sum(v.numel() for v in theirs.values())),
        "inputs": {"source": int(width), "run": int(ours)},
        "wall_time_s": round(time.perf_counter() - began, 2),
    }


#: The count the observation statistics restart from when a start policy's inputs are
#: extended (``warm_start.extend_inputs``): about one rollout of 128 environments × 64 steps
#: (8,192 states) weighs as much as what the source's statistics are then worth.
EXTENDED_STATS_COUNT = 8192.0


def extend_first_layers(
    theirs: dict[str, torch.Tensor], ours: dict[str, torch.Tensor], width: int
) -> dict[str, torch.Tensor]:
    """``theirs`` (a policy's state dict observing ``width`` values) with every weight that
    reads the observation widened to ``ours``'s inputs, the new columns zero."""
    out = dict(theirs)
    for key, weight in theirs.items():
        target = ours[key]
        if weight.ndim == 2 and weight.shape[1] == width and target.shape[1] > width:
            wide = torch.zeros_like(target)
            wide[:, :width] = weight
            out[key] = wide
    return out


def _start_policy(source: str) -> Any:
    """The trained policy ``warm_start.policy`` names (a ``TrainedPolicy``).

    Raises:
        ConfigError: There is none there (named).
    """
    from safeswitch.core.config import ConfigError
    from safeswitch.training.policies import load_policy

    try:
        return load_policy(source)
    except FileNotFoundError as error:
        raise ConfigError(f"warm_start.policy={source!r}: {error}") from error


def check_start_policy(
    source: str,
    net_arch: tuple[int, ...],
    obs_shape: tuple[int, ...],
    extend_inputs: bool = False,
) -> None:
    """Refuse, before a run directory is written, a ``warm_start.policy`` this run cannot
    start from: none there, other hidden layers or another observation (with
    ``extend_inputs``: one that is not at most as wide as this run's).

    Raises:
        ConfigError: Naming the value and what differs.
    """
    from safeswitch.core.config import ConfigError

    trained = _start_policy(source)
    layers = tuple(
        m.out_features
        for m in trained.model.policy.mlp_extractor.policy_net
        if isinstance(m, torch.nn.Linear)
    )
    shape = tuple(trained.model.observation_space.shape or ())
    fits = shape == tuple(obs_shape) or (
        extend_inputs and len(shape) == len(obs_shape) == 1 and shape[0] < obs_shape[0]
    )
    if layers != tuple(net_arch) or not fits:
        hint = "" if extend_inputs else (
            "; warm_start.extend_inputs takes a policy that observes the first of this run's "
            "values"
        )  # fmt: skip
        raise ConfigError(
            f"warm_start.policy={source!r}: its network is not this run's (hidden layers "
            f"{list(layers)} there, {list(net_arch)} here; observations {shape} there, "
            f"{tuple(obs_shape)} here{hint})"
        )
