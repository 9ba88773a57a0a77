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
"""

from __future__ import annotations

from typing import Any

import torch
from stable_baselines3 import PPO


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
        **kwargs: Any,
    ) -> None:
        self.actor_learning_rate = actor_learning_rate
        self.actor_frozen_steps = actor_frozen_steps
        self.actor_ramp_steps = actor_ramp_steps
        self.learn_log_std = learn_log_std
        self.log_std_final = log_std_final
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
        return bool(super().collect_rollouts(*args, **kwargs))

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
