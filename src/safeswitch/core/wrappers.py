"""The framework around any environment: a Safety controller, a switching logic and the
``R_ADAS`` feedback, as a Gymnasium wrapper and as a Stable-Baselines3 VecEnv wrapper.

Every step, the agent's action is the *learned* action. The wrapper computes the Safety
controller's action from the plant state, lets the switching logic choose through
:func:`~safeswitch.core.switching.supervise` (NaN/inf never reach the environment, the executed
action is inside the action space), steps the environment with the executed action, adds
``penalty`` to the reward on every step the safety action ran (paper Eq. 4) and records the
decision in ``info``:

* ``safety_active`` (bool) — the learned action was overridden (the paper's ``s*``);
* ``reason`` (str) — why, one of the logic's ``reasons`` or ``invalid_learned_action``;
* ``cost`` (float) — 1.0 on such a step, else 0.0 (the Safety-Gymnasium/OmniSafe convention,
  so constrained-RL code can use it as is);
* ``learned_action``, ``executed_action`` (arrays) — what the agent asked for, what ran;
* ``action_clipped`` (bool) — the learned action lay outside the action space and was clipped.

A learned action with a NaN or infinite component is never executed: the last executed action
is proposed in its place (a zero-order hold; the Safety controller's action on an episode's
first step) and the logic judges it like any proposal; the step counts as an intervention.

An SB3 ``Monitor`` placed *outside* the wrapper logs returns with the penalty, one inside
without it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, MutableMapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from safeswitch.core.registry import resolve_logic
from safeswitch.core.switching import (
    FloatArray,
    Supervision,
    SwitchingError,
    SwitchingLogic,
    reason_names,
    supervise,
)

#: ``safety_controller(state) -> actions [B, A]`` in the environment's action space.
SafetyController = Callable[[Any], Any]
#: ``state_fn(env) -> state``: what the Safety controller and the logic see.
StateFn = Callable[[Any], Any]


def require_box(space: gym.Space[Any], what: str) -> spaces.Box:
    """``space`` if it is a ``Box``: the only action space the switch wraps (``what`` names the
    wrapper, or the plant, in the error)."""
    if not isinstance(space, spaces.Box):
        raise SwitchingError(
            f"{what} needs a Box action space (continuous actions), got {space!r}; a discrete "
            "action space has no 'inside the bounds' to clip to"
        )
    return space


def check_penalty(penalty: Any) -> float:
    """``penalty`` as a float, if it is a finite number ``<= 0``.

    Raises:
        SwitchingError: Not a number (a string, a bool, ``None``), not finite, or positive —
            a bonus on every step the Safety controller acts would teach the policy to hand
            over control, the opposite of ``R_ADAS``.
    """
    if isinstance(penalty, bool) or not isinstance(penalty, int | float | np.integer | np.floating):
        raise SwitchingError(f"penalty must be a number <= 0, got {penalty!r}")
    if not np.isfinite(penalty):
        raise SwitchingError(f"penalty must be a finite number <= 0, got {penalty!r}")
    if penalty > 0:
        raise SwitchingError(
            f"penalty must be <= 0, got {penalty!r}: it is added to the reward on every step the "
            "Safety controller acts (R_ADAS), and a bonus there teaches the policy to need it"
        )
    return float(penalty)


def _normalized_inside(venv: VecEnv) -> bool:
    """``venv`` is, or wraps, an SB3 ``VecNormalize`` that normalises observations."""
    from stable_baselines3.common.vec_env import VecNormalize

    current: Any = venv
    while current is not None:
        if isinstance(current, VecNormalize) and current.norm_obs:
            return True
        current = getattr(current, "venv", None)
    return False


def _default_state(space: gym.Space[Any], what: str) -> None:
    if not isinstance(space, spaces.Box):
        raise SwitchingError(
            f"{what}: the default state is the last observation, which needs a Box "
            f"observation space, got {space!r}; pass state_fn"
        )


class _Supervisor:
    """What both wrappers share: the logic, the Safety controller and one supervised step."""

    def __init__(
        self,
        action_space: spaces.Box,
        safety_controller: SafetyController,
        logic: SwitchingLogic[Any],
        penalty: float,
    ) -> None:
        if not callable(safety_controller):
            raise SwitchingError(f"safety_controller must be callable, got {safety_controller!r}")
        self.space = action_space
        self.dim = int(np.prod(action_space.shape))
        self.low = action_space.low.astype(np.float64).reshape(-1)
        self.high = action_space.high.astype(np.float64).reshape(-1)
        self.safety_controller = safety_controller
        self.logic = logic
        self.reasons = reason_names(logic)
        self.penalty = penalty

    def learned(self, actions: Any, batch: int) -> FloatArray:
        if actions is None:
            raise SwitchingError("the learned action is None; pass an array of the action space")
        learned = np.asarray(actions, dtype=np.float64)
        if learned.size != batch * self.dim:
            raise SwitchingError(
                f"learned action of shape {learned.shape} does not fit {batch} environment(s) "
                f"with action space {self.space}"
            )
        return learned.reshape(batch, self.dim)

    def step(self, state: Any, actions: Any, batch: int, held: FloatArray | None) -> Supervision:
        """One supervised step; ``held``: the last executed actions ``[B, A]`` (the fallback
        for an invalid learned action; ``None`` or NaN rows: the safety action)."""
        learned = self.learned(actions, batch)
        safe = np.asarray(self.safety_controller(state), dtype=np.float64)
        if safe.shape != (batch, self.dim):
            raise SwitchingError(
                f"the Safety controller returned shape {safe.shape}; expected {(batch, self.dim)}"
                " (actions [B, A])"
            )
        fallback = safe if held is None else np.where(np.isfinite(held), held, safe)
        return supervise(self.logic, state, learned, safe, self.low, self.high, fallback)

    def executed(self, sup: Supervision) -> NDArray[Any]:
        """The executed actions in the space's dtype and shape, bounds kept after the cast."""
        out = sup.executed.astype(self.space.dtype)
        out = np.clip(out, self.space.low.reshape(-1), self.space.high.reshape(-1))
        return out.reshape((out.shape[0], *self.space.shape))

    def annotate(self, info: MutableMapping[str, Any], sup: Supervision, i: int) -> None:
        active = bool(sup.safety_active[i])
        info["safety_active"] = active
        info["reason"] = self.reasons[int(sup.reason[i])]
        info["cost"] = 1.0 if active else 0.0
        info["learned_action"] = sup.learned[i].copy()
        info["executed_action"] = sup.executed[i].copy()
        info["action_clipped"] = bool(sup.clipped[i])


class _Switched:
    """What both wrappers hold: the supervisor, where the state comes from, the last
    observation and executed action, and the last step's supervision."""

    supervisor: _Supervisor
    state_fn: StateFn | None
    _observation: Any
    _held: FloatArray | None
    last_supervision: Supervision | None

    def _switch(
        self,
        plant: Any,
        what: str,
        safety_controller: SafetyController,
        logic: SwitchingLogic[Any] | str,
        penalty: float,
        state_fn: StateFn | None,
        logic_params: Mapping[str, Any] | None,
    ) -> None:
        """Check ``plant``'s spaces (``what`` names the wrapper in an error) and set up the
        supervisor; nothing observed or held yet."""
        space = require_box(plant.action_space, what)
        if state_fn is None:
            _default_state(plant.observation_space, what)
        self.supervisor = _Supervisor(
            space,
            safety_controller,
            resolve_logic(logic, plant, logic_params),
            check_penalty(penalty),
        )
        self.state_fn = state_fn
        self._observation = None
        self._held = None
        self.last_supervision = None

    @property
    def logic(self) -> SwitchingLogic[Any]:
        return self.supervisor.logic

    def _state(self, plant: Any, rows: int) -> Any:
        """``state_fn(plant)``, or the last observation as a ``[rows, obs_dim]`` float64
        array."""
        if self.state_fn is not None:
            return self.state_fn(plant)
        if self._observation is None:
            raise RuntimeError("call reset() before step()")
        return np.asarray(self._observation, dtype=np.float64).reshape(rows, -1)


class SafeSwitch(_Switched, gym.Wrapper[Any, Any, Any, Any]):
    """The paper's framework around any Gymnasium environment with a ``Box`` action space.

    Args:
        env: The environment (the plant).
        safety_controller: ``safety_controller(state) -> actions [1, A]`` in the action space.
        logic: A :class:`~safeswitch.core.switching.SwitchingLogic` or the name of a registered
            one (its factory gets ``env``).
        penalty: Added to the reward on every step the learned action was overridden
            (``R_ADAS``, paper Eq. 4): a number ``<= 0``.
        state_fn: ``state_fn(env) -> state`` — what the Safety controller and the logic see;
            by default the last observation as a ``[1, obs_dim]`` float64 array.
        logic_params: Parameters of a logic given by name, as plain data (a logic registered
            with ``config=``; see :func:`~safeswitch.core.registry.make_logic`).

    Raises:
        SwitchingError: A non-Box action space, an unknown or malformed logic, a penalty that
            is not a finite number ``<= 0``, or no ``state_fn`` for a non-Box observation space.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        safety_controller: SafetyController,
        logic: SwitchingLogic[Any] | str,
        *,
        penalty: float = -25.0,
        state_fn: StateFn | None = None,
        logic_params: Mapping[str, Any] | None = None,
    ) -> None:
        super().__init__(env)
        self._switch(env, "SafeSwitch", safety_controller, logic, penalty, state_fn, logic_params)

    def state(self) -> Any:
        """What the Safety controller and the logic see now."""
        return self._state(self.env, 1)

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        self._observation = observation
        self._held = None
        return observation, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        sup = self.supervisor.step(self.state(), action, 1, self._held)
        self.last_supervision = sup
        self._held = sup.executed
        observation, reward, terminated, truncated, info = self.env.step(
            self.supervisor.executed(sup)[0]
        )
        self._observation = observation
        info = dict(info)
        self.supervisor.annotate(info, sup, 0)
        reward = float(reward) + (self.supervisor.penalty if sup.safety_active[0] else 0.0)
        return observation, reward, terminated, truncated, info


class SafeSwitchVecEnv(_Switched, VecEnvWrapper):
    """:class:`SafeSwitch` for a Stable-Baselines3 ``VecEnv``, batched over its environments:
    one Safety-controller call and one ``decide`` per step.

    Args:
        venv: The vectorised environment.
        safety_controller: ``safety_controller(state) -> actions [N, A]``.
        logic: A switching logic or the name of a registered one (its factory gets ``venv``).
        penalty: Added to the reward of every environment whose learned action was overridden
            (a number ``<= 0``).
        state_fn: ``state_fn(venv) -> state`` for all ``N`` environments; by default the last
            observations as an ``[N, obs_dim]`` float64 array (after an automatic reset: the
            new episode's first observation, as SB3 returns it).
        logic_params: Parameters of a logic given by name, as plain data.

    Stack it *inside* ``VecNormalize`` (``VecNormalize(SafeSwitchVecEnv(venv, …))``): the
    Safety controller and the logic must see the plant's own observations, the policy the
    normalised ones. A ``VecNormalize`` inside it is refused unless ``state_fn`` says where
    the plant state comes from.
    """

    def __init__(
        self,
        venv: VecEnv,
        safety_controller: SafetyController,
        logic: SwitchingLogic[Any] | str,
        *,
        penalty: float = -25.0,
        state_fn: StateFn | None = None,
        logic_params: Mapping[str, Any] | None = None,
    ) -> None:
        super().__init__(venv)
        if state_fn is None and _normalized_inside(venv):
            raise SwitchingError(
                "SafeSwitchVecEnv wraps a VecNormalize: the Safety controller and the logic "
                "would see normalised observations; put VecNormalize outside "
                "(VecNormalize(SafeSwitchVecEnv(venv, ...))) or pass state_fn"
            )
        self._switch(
            venv, "SafeSwitchVecEnv", safety_controller, logic, penalty, state_fn, logic_params
        )
        self._pending: Supervision | None = None

    def state(self) -> Any:
        """What the Safety controller and the logic see now, for every environment."""
        return self._state(self.venv, self.num_envs)

    def reset(self) -> VecEnvObs:
        observation = self.venv.reset()
        self._observation = observation
        self._held = None
        return observation

    def step_async(self, actions: np.ndarray) -> None:
        sup = self.supervisor.step(self.state(), actions, self.num_envs, self._held)
        self._pending = sup
        self.venv.step_async(self.supervisor.executed(sup))

    def step_wait(self) -> VecEnvStepReturn:
        sup = self._pending
        if sup is None:
            raise RuntimeError("step_wait() called without step_async()")
        self._pending = None
        self.last_supervision = sup
        observation, rewards, dones, infos = self.venv.step_wait()
        self._observation = observation
        # hold the executed actions; an environment that starts a new episode has none
        self._held = np.where(dones[:, None], np.nan, sup.executed)
        rewards = rewards + np.where(sup.safety_active, self.supervisor.penalty, 0.0).astype(
            rewards.dtype
        )
        annotated: Sequence[MutableMapping[str, Any]] = infos
        for i in range(self.num_envs):
            self.supervisor.annotate(annotated[i], sup, i)
        return observation, rewards, dones, infos
