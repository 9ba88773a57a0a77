"""PPO whose actor can learn on its own schedule: frozen, then ramped up, at its own rate.

A policy that starts from behaviour cloning (:mod:`safeswitch.training.warm_start`) is already
good; PPO with a freshly initialised value function and Adam's full-size first steps undoes it
within a few dozen updates (in our runs the clone went from almost no safety actions to one in
most rollouts soon after the actor was released at Table II's rate). So the actor (the
policy network and its output layer) gets its own Adam parameter group whose learning rate is
0 for the first ``actor_frozen_steps`` timesteps — the value function learns the cloned
policy's returns — and then rises linearly to ``actor_learning_rate`` (or, without one, the
configured learning rate) over ``actor_ramp_steps``. The value function keeps the configured
learning rate throughout. With the defaults (no separate rate, no frozen steps) this is SB3's
PPO unchanged.

The schedule is saved with the model (SB3 saves the attributes), so ``load`` and ``--resume``
rebuild the same parameter groups.

With ``intervention_imitation`` > 0 the actor also learns from the Safety controller's
interventions after each update (:mod:`safeswitch.training.interventions`); anchored
(:meth:`SwitchPPO.anchor_to`), it also stays near a reference policy on chosen environments.

With ``action_bound_loss`` > 0 the Gaussian's mean is pulled back inside the action bounds
after each update (:meth:`SwitchPPO.keep_means_in_bounds`). The environment clips every action
to its bounds, so where the mean has drifted far beyond one (PPO's actor asks for 2.7 where
full throttle is 1) every sample of a small exploration noise is clipped to the same action:
the advantages there no longer tell the actor anything, and the policy cannot learn to ease
off. The same remedy as the bound loss of rl_games' PPO (ours: applied as a fit after the
update, like the interventions' fit, not inside PPO's loss).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.utils import obs_as_tensor

from safeswitch.leftturn.info import BatchInfos
from safeswitch.training.interventions import recorder_of


class SwitchPPO(PPO):
    """SB3's PPO with an optional separate learning-rate schedule for the actor.

    Args:
        actor_learning_rate: The actor's Adam step size after the ramp (``None``: one parameter
            group, the configured learning rate for everything — plain PPO).
        actor_frozen_steps: Timesteps during which the actor does not learn.
        actor_ramp_steps: Timesteps over which its rate then rises linearly from 0.
        learn_log_std: Whether the Gaussian's log standard deviation is learned (``False``:
            it stays at ``log_std_init``; exploration noise of a fixed size).
        log_std_final: With ``learn_log_std=False``, the fixed log standard deviation is
            annealed linearly from its initial value to this over the run, one value per
            rollout (set before the rollout, so that the importance ratios of the update that
            follows are computed under the noise the actions were drawn with).
        intervention_imitation: Weight of the fit toward the executed safety action on the
            rollout's intervention states after each update (0: none, plain PPO; needs an
            :class:`~safeswitch.training.interventions.InterventionRecorder` around the
            environment).
        action_bound_loss: Weight of the fit that pulls a mean beyond the action bounds back
            to them on the rollout's states after each update (0: none, plain PPO).
        action_bound_margin: How far beyond a bound the mean may lie before that fit pulls
            it, in standard deviations of the exploration noise at the state (0: the bound).
        *args, **kwargs: Passed to :class:`~stable_baselines3.PPO`.
    """

    def __init__(
        self,
        *args: Any,
        actor_learning_rate: float | None = None,
        actor_frozen_steps: int = 0,
        actor_ramp_steps: int = 0,
        learn_log_std: bool = True,
        log_std_final: float | None = None,
        intervention_imitation: float = 0.0,
        action_bound_loss: float = 0.0,
        action_bound_margin: float = 0.0,
        **kwargs: Any,
    ) -> None:
        self.actor_learning_rate = actor_learning_rate
        self.actor_frozen_steps = actor_frozen_steps
        self.actor_ramp_steps = actor_ramp_steps
        self.learn_log_std = learn_log_std
        self.log_std_final = log_std_final
        self.intervention_imitation = intervention_imitation
        self.action_bound_loss = action_bound_loss
        self.action_bound_margin = action_bound_margin
        #: ``(reference policy, environment mask, weight)`` (see :meth:`anchor_to`).
        self._anchor: tuple[Any, np.ndarray, float] | None = None
        #: While true, rollouts are collected but :meth:`train` updates nothing (``safeswitch
        #: adapt`` pauses learning while its selected policy meets every target). Not saved.
        self.learning_paused = False
        super().__init__(*args, **kwargs)

    def _setup_model(self) -> None:
        super()._setup_model()
        policy = self.policy
        log_std = getattr(policy, "log_std", None)
        if isinstance(log_std, torch.nn.Parameter):
            log_std.requires_grad_(self.learn_log_std)
        separate = self.actor_learning_rate is not None or self.actor_frozen_steps > 0
        if not separate and self.learn_log_std:
            return
        actor = self.actor_parameters()
        mine = {id(p) for p in actor}
        rest = [p for p in policy.parameters() if p.requires_grad and id(p) not in mine]
        groups = [{"params": rest}, {"params": actor}] if separate else [{"params": rest + actor}]
        optimizer_class: Any = policy.optimizer_class
        policy.optimizer = optimizer_class(
            groups, lr=self.lr_schedule(1.0), **policy.optimizer_kwargs
        )

    def schedule_actor(self, rate: float | None, frozen_steps: int, ramp_steps: int) -> None:
        """From now on the actor learns on its own schedule (see the module docstring), with
        ``frozen_steps`` and ``ramp_steps`` counted from the current timestep: the optimiser
        is rebuilt with the actor in its own group (its moments start afresh) — what a loaded
        policy that keeps learning elsewhere needs while its value function catches up."""
        self.actor_learning_rate = rate
        self.actor_frozen_steps = self.num_timesteps + frozen_steps
        self.actor_ramp_steps = ramp_steps
        policy = self.policy
        actor = self.actor_parameters()
        mine = {id(p) for p in actor}
        rest = [p for p in policy.parameters() if p.requires_grad and id(p) not in mine]
        optimizer_class: Any = policy.optimizer_class
        policy.optimizer = optimizer_class(
            [{"params": rest}, {"params": actor}], lr=self.lr_schedule(1.0),
            **policy.optimizer_kwargs,
        )  # fmt: skip

    def actor_parameters(self) -> list[torch.nn.Parameter]:
        """The parameters of the action distribution's mean (and its log std if learned)."""
        policy = self.policy
        params = list(policy.mlp_extractor.policy_net.parameters())
        params += list(policy.action_net.parameters())
        log_std = getattr(policy, "log_std", None)
        if isinstance(log_std, torch.nn.Parameter) and log_std.requires_grad:
            params.append(log_std)
        return params

    def collect_rollouts(self, *args: Any, **kwargs: Any) -> bool:
        log_std = getattr(self.policy, "log_std", None)
        if self.log_std_final is not None and isinstance(log_std, torch.nn.Parameter):
            start = float(self.policy_kwargs.get("log_std_init", 0.0))
            done = 1.0 - self._current_progress_remaining
            value = start + (self.log_std_final - start) * done
            with torch.no_grad():
                log_std.fill_(value)
            self.logger.record("train/log_std", value)
        recorder = recorder_of(self.env)
        if recorder is not None:
            recorder.clear()  # the next update learns from this rollout's interventions only
        return bool(super().collect_rollouts(*args, **kwargs))

    def _update_info_buffer(
        self, infos: list[dict[str, Any]], dones: np.ndarray | None = None
    ) -> None:
        # SB3 reads ``episode`` and ``is_success`` from every environment's info, each step;
        # the left turn's infos are built on access and carry those keys only where an
        # episode ended, so only those are read (the same buffers; about 5 % of a run's CPU time).
        if isinstance(infos, BatchInfos):
            ended = np.flatnonzero(infos.done)
            ended_dones = None if dones is None else np.asarray(dones)[ended]
            super()._update_info_buffer([infos[i] for i in ended], ended_dones)
            return
        super()._update_info_buffer(infos, dones)

    def train(self) -> None:
        if self.learning_paused:
            return
        super().train()
        if self.intervention_imitation > 0:
            self.imitate_interventions()
        if self.action_bound_loss > 0:
            self.keep_means_in_bounds()
        if self._anchor is not None:
            self.keep_anchor()

    def anchor_to(self, reference: Any, columns: np.ndarray, weight: float = 1.0) -> None:
        """After each update, also fit the actor toward ``reference``'s mean action (a frozen
        policy of the same architecture) on the rollout's states of environments ``columns``
        (a mask over the environments): a trust region toward that policy where it must not
        change — ``safeswitch adapt`` anchors the original policy on the environments that
        rehearse its distribution (the idea of learning without forgetting, Li & Hoiem, ECCV
        2016, on the actor's output). Not saved with the model: call it again after loading."""
        columns = np.asarray(columns, dtype=bool)
        if columns.shape != (self.n_envs,):
            raise ValueError(f"columns needs one flag per environment ({self.n_envs}), got "
                             f"shape {columns.shape}")  # fmt: skip
        reference.set_training_mode(False)
        self._anchor = (reference, columns, float(weight))

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_anchor", "learning_paused"]

    def _rollout_states(self, columns: np.ndarray | None = None) -> np.ndarray:
        """The rollout buffer's observations ``[N, *obs_shape]``, of the environments
        ``columns`` (a mask; ``None``: all)."""
        buffer = self.rollout_buffer
        observations = buffer.observations
        # SB3 flattens the buffer environment by environment once an update has read it
        if buffer.generator_ready:
            observations = observations.reshape(self.n_envs, -1, *observations.shape[1:])
            chosen = observations if columns is None else observations[columns]
        else:
            chosen = observations if columns is None else observations[:, columns]
        return np.asarray(chosen).reshape(-1, *observations.shape[2:])

    def keep_means_in_bounds(self) -> None:
        """The fit of ``action_bound_loss``: on the rollout's states whose mean lies more than
        ``action_bound_margin`` noise standard deviations beyond an action bound, ``n_epochs``
        passes in minibatches of ``batch_size`` minimising ``weight · mean ‖μ(s) − m(s)‖²``,
        ``m(s)`` the nearest mean allowed — nothing where every mean is allowed. Logs the
        share of states beyond (``train/means_out_of_bounds``) and the loss."""
        states = self._rollout_states()
        with torch.no_grad():
            mean, allowed = self._mean_and_allowed(obs_as_tensor(states, self.device))
            out = (mean != allowed).any(dim=-1).numpy()
        self.logger.record("train/means_out_of_bounds", float(out.mean()) if len(out) else 0.0)
        if not out.any():
            return
        self._fit(states[out], self._bound_loss, self.action_bound_loss, "bound")

    def _mean_and_allowed(self, observation: Any) -> tuple[torch.Tensor, torch.Tensor]:
        """The policy's Gaussian mean on ``observation`` and the nearest mean within
        ``action_bound_margin`` standard deviations of the bounds (not differentiated)."""
        normal = self._normal(self.policy, observation)
        margin = self.action_bound_margin * normal.stddev.detach()
        return normal.mean, self._clip_to_bounds(normal.mean, margin).detach()

    def _bound_loss(self, observation: Any, rows: np.ndarray) -> torch.Tensor:
        mean, allowed = self._mean_and_allowed(observation)
        return (mean - allowed).pow(2).sum(dim=-1).mean()

    def keep_anchor(self) -> None:
        """The fit of :meth:`anchor_to` on this rollout's anchored states."""
        assert self._anchor is not None
        reference, columns, weight = self._anchor
        states = self._rollout_states(columns)
        if not len(states):
            return
        with torch.no_grad():
            target = self._executed_mean(reference, obs_as_tensor(states, self.device))
        self._fit_actor(states, target, weight, "anchor")

    def imitate_interventions(self) -> None:
        """Fit the actor toward the executed safety action on the rollout's intervention
        states: ``n_epochs`` passes in minibatches of ``batch_size``, the loss of
        :mod:`safeswitch.training.interventions` (nothing at all without an intervention)."""
        recorder = recorder_of(self.env)
        batch = recorder.batch() if recorder is not None else None
        self.logger.record("train/intervention_states", 0 if batch is None else len(batch[0]))
        if batch is None:
            return
        states, targets = batch
        target = torch.as_tensor(targets, dtype=torch.float32)
        self._fit_actor(states, target, self.intervention_imitation, "imitation")

    @staticmethod
    def _normal(policy: Any, observation: Any) -> torch.distributions.Normal:
        """``policy``'s action distribution on ``observation`` (a Box action: a Gaussian)."""
        normal = policy.get_distribution(observation).distribution
        assert isinstance(normal, torch.distributions.Normal)
        return normal

    def _mean(self, policy: Any, observation: Any) -> torch.Tensor:
        """``policy``'s Gaussian mean on ``observation`` (not clipped)."""
        return self._normal(policy, observation).mean

    def _clip_to_bounds(
        self, action: torch.Tensor, margin: torch.Tensor | float = 0.0
    ) -> torch.Tensor:
        """``action`` clipped to the action space's bounds, as the environment clips it; with
        ``margin``, to the bounds widened by it on both sides."""
        space = self.action_space
        low = torch.as_tensor(np.asarray(getattr(space, "low", -np.inf)), dtype=torch.float32)
        high = torch.as_tensor(np.asarray(getattr(space, "high", np.inf)), dtype=torch.float32)
        return torch.maximum(torch.minimum(action, high + margin), low - margin)

    def _executed_mean(self, policy: Any, observation: Any) -> torch.Tensor:
        """``policy``'s mean action on ``observation``, clipped to the action bounds as the
        environment clips it."""
        return self._clip_to_bounds(self._mean(policy, observation))

    def _fit_actor(
        self, states: np.ndarray, target: torch.Tensor, weight: float, name: str
    ) -> None:
        """``n_epochs`` passes in minibatches of ``batch_size`` minimising
        ``weight · mean ‖clip(μ(s)) − target‖²`` (logged as ``train/{name}_loss``)."""

        def loss(observation: Any, rows: np.ndarray) -> torch.Tensor:
            executed = self._executed_mean(self.policy, observation)
            return (executed - target[rows]).pow(2).sum(dim=-1).mean()

        self._fit(states, loss, weight, name)

    def _fit(
        self,
        states: np.ndarray,
        loss_of: Callable[[Any, np.ndarray], torch.Tensor],
        weight: float,
        name: str,
    ) -> None:
        """``n_epochs`` passes over ``states`` in minibatches of ``batch_size``, each step
        minimising ``weight · loss_of(observations, rows)`` (``rows``: the minibatch's indices
        into ``states``); the mean loss is logged as ``train/{name}_loss``."""
        self.policy.set_training_mode(True)
        losses = []
        count = len(states)
        size = int(self.batch_size or count)
        for _ in range(self.n_epochs):
            order = torch.randperm(count).numpy()  # torch: seeded with the run
            for start in range(0, count, size):
                rows = order[start : start + size]
                observation = obs_as_tensor(states[rows], self.device)
                loss = weight * loss_of(observation, rows)
                self.policy.optimizer.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
                self.policy.optimizer.step()
                losses.append(float(loss.detach()))
        self.logger.record(f"train/{name}_loss", float(np.mean(losses)))

    def actor_rate(self, timesteps: int) -> float:
        """The actor's learning rate after ``timesteps`` (see the module docstring); without an
        ``actor_learning_rate``, the configured learning rate is the one it ramps up to."""
        rate = self.actor_learning_rate
        if rate is None:
            rate = float(self.lr_schedule(self._current_progress_remaining))
        since = timesteps - self.actor_frozen_steps
        if since < 0:
            return 0.0
        if self.actor_ramp_steps == 0:
            return rate
        return rate * min(1.0, since / self.actor_ramp_steps)

    def _update_learning_rate(
        self, optimizers: list[torch.optim.Optimizer] | torch.optim.Optimizer
    ) -> None:
        super()._update_learning_rate(optimizers)
        groups = self.policy.optimizer.param_groups
        if len(groups) > 1:
            groups[1]["lr"] = self.actor_rate(self.num_timesteps)
            self.logger.record("train/actor_learning_rate", groups[1]["lr"])
