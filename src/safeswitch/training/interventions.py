"""Learning from the Safety controller's interventions (ours; off by default).

When the switch overrules the learned action, the action it executes instead is a
demonstration of what to do in that state — the idea of HG-DAgger (Kelly et al., *HG-DAgger:
Interactive Imitation Learning with Human Experts*, ICRA 2019) and of expert-guided policy
optimisation (EGPO, Peng et al., *Safe Driving via Expert Guided Policy Optimization*, CoRL
2021), here with a rule-based expert that is in the loop anyway. With
``policy.intervention_imitation`` = ``w`` > 0, after each PPO update the actor takes the same
number of passes over the rollout's *intervention states* alone, each minimising

    w · mean ‖clip(μ(s), low, high) − a_safe(s)‖²

(``μ`` the policy's mean action, clipped to the action bounds as the environment clips it,
``a_safe`` the executed safety action). States on which the learned action ran contribute
nothing: a rollout without an intervention leaves PPO's update exactly as it was. The penalty
``R_ADAS`` still charges each intervention; this adds the direction the penalty does not give.

What counts as the safety action in the learned action's terms: the executed action of
:class:`~safeswitch.core.wrappers.SafeSwitch` (same action space); for the left turn, whose
learned controller commands the throttle while the Safety controller brakes, a closed
throttle (``-1``), the nearest the learned controller can come to braking.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from safeswitch.leftturn.info import BatchInfos

#: The left turn's learned action nearest to the Safety controller's braking: throttle off.
LEFT_TURN_SAFE_ACTION = -1.0


def interventions(
    infos: Sequence[dict[str, Any]], action_dim: int
) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """Which environments' last step ran the safety action ``[N]``, and that action in the
    learned action's terms ``[N, A]`` (see the module docstring; rows where it did not run
    are zeros)."""
    n = len(infos)
    targets = np.zeros((n, action_dim))
    if isinstance(infos, BatchInfos):  # the left turn's batched record, read as arrays
        mask = np.asarray(infos.record.safety_active, dtype=bool).copy()
        targets[mask] = LEFT_TURN_SAFE_ACTION
        return mask, targets
    mask = np.zeros(n, dtype=bool)
    for i, info in enumerate(infos):
        if info.get("safety_active", False):
            mask[i] = True
            targets[i] = np.asarray(info["executed_action"], dtype=np.float64).reshape(-1)
    return mask, targets


class InterventionRecorder(VecEnvWrapper):
    """Keeps, for the current rollout, every state (as the policy saw it: the observation the
    wrapped — normalising — environment returned) on which the safety action ran, with that
    action. Wraps the environment the learner steps, outside ``VecNormalize``."""

    def __init__(self, venv: VecEnv) -> None:
        super().__init__(venv)
        shape = venv.action_space.shape
        self.action_dim = int(np.prod(shape)) if shape else 1
        self._last: NDArray[Any] | None = None
        self._states: list[NDArray[Any]] = []
        self._targets: list[NDArray[np.float64]] = []

    def reset(self) -> VecEnvObs:
        observation = self.venv.reset()
        self._last = np.array(observation, copy=True)
        return observation

    def step_async(self, actions: NDArray[Any]) -> None:
        self.venv.step_async(actions)

    def step_wait(self) -> VecEnvStepReturn:
        observation, rewards, dones, infos = self.venv.step_wait()
        mask, targets = interventions(infos, self.action_dim)
        if self._last is not None and mask.any():
            self._states.append(self._last[mask].copy())
            self._targets.append(targets[mask])
        self._last = np.array(observation, copy=True)
        return observation, rewards, dones, infos

    def clear(self) -> None:
        """Forget what was recorded (at the start of a rollout)."""
        self._states, self._targets = [], []

    def batch(self) -> tuple[NDArray[Any], NDArray[np.float64]] | None:
        """The recorded states ``[M, ...]`` and safety actions ``[M, A]``, or ``None``."""
        if not self._states:
            return None
        return np.concatenate(self._states), np.concatenate(self._targets)


def recorder_of(env: VecEnv | None) -> InterventionRecorder | None:
    """The :class:`InterventionRecorder` among ``env``'s wrappers, if any."""
    while isinstance(env, VecEnvWrapper):
        if isinstance(env, InterventionRecorder):
            return env
        env = env.venv
    return None
