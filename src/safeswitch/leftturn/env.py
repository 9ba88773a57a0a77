"""The Gymnasium environment ``safeswitch/LeftTurn-v0``: a thin shell over a batch of one."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from safeswitch.leftturn.config import FROM_CONFIG, LeftTurnConfig
from safeswitch.leftturn.info import scenario_info, step_info
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.spaces import action_space, observation_space
from safeswitch.leftturn.statistics import PUBLISHED_COSTS, tick_cost_limits, tick_costs_of
from safeswitch.leftturn.task import (
    LeftTurnTask,
    StepRecord,
    TaskState,
    learned_actions,
)


class LeftTurnEnv(gym.Env[NDArray[np.float32], NDArray[np.float32]]):
    """Unprotected left turn in front of a non-yielding oncoming car (paper Section IV).

    Observation: ``(x_e, y_e, v_e, x_n, y_n, v_n)`` float32. Action: ``Box(-1, 1, (1,))``,
    throttle ``= (a + 1) / 2`` (the paper's; ``controllers.learned_speed_command_kmh`` and
    ``controllers.learned_brake`` give it another meaning). Reward: Eq. 5. ``terminated`` on a
    collision, ``truncated`` at the fixed horizon. Each step's ``info`` is described in
    :func:`safeswitch.leftturn.info.step_info`.

    The ``k``-th episode after ``reset(seed=s)`` plays the scenario drawn from ``(s, env_index,
    k)``: the same as environment ``env_index`` of a :class:`LeftTurnVecEnv` with seed ``s``.

    Args:
        switching: ``"paper"``, ``"certified"`` or ``"none"``.
        adas_penalty: Whether ``R_ADAS`` is in the reward.
        scenario: ``None`` (random), ``"cut"``, ``"yield1"`` or ``"yield2"``.
        config: Full configuration (a :class:`LeftTurnConfig` or a dict). The three arguments
            above override its fields when given; left out, the configuration's values hold
            (by default ``"paper"``, ``True`` and ``None``).
        render_mode: ``None``, ``"rgb_array"`` (``render()`` returns the picture) or
            ``"human"`` (a window, drawn on every step; needs ``pygame`` and a display — where
            there is none, the first frame raises an error saying so; ``safeswitch render``
            writes a GIF instead).
        env_index: Which stream of scenarios this environment draws from.
        learned_scope: ``"window"`` (Algorithm 1: the learned controller drives while both cars
            are at the intersection), ``"episode"`` (throughout) or ``"never"``; left out, the
            configuration's (``"window"`` by default).
        traffic: ``None`` (the paper's scene), a preset (``"light"``, ``"medium"``,
            ``"heavy"``, ``"train"``, ``"test"``), a dict of
            :class:`~safeswitch.leftturn.config.TrafficConfig` settings (``preset`` to start
            from one) or a ``TrafficConfig``: other vehicles on every approach
            (:mod:`safeswitch.leftturn.traffic`; ``safeswitch/LeftTurnTraffic-v0`` defaults to
            ``"medium"``).
        perception: How the ego sees the north car: a dict of
            :class:`~safeswitch.leftturn.config.PerceptionConfig` keys (``position_error_m``,
            ``speed_error_mps``, ``latency_s``, ``dropout_prob``, ``dropout_max_s``,
            ``sight_distance_m``, ``errors``) or a ``PerceptionConfig``; left out, the
            configuration's (perfect perception by default). The paper's scene only.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 50}  # noqa: RUF012

    def __init__(
        self,
        switching: str = FROM_CONFIG,
        adas_penalty: bool = FROM_CONFIG,
        scenario: str | None = FROM_CONFIG,
        config: LeftTurnConfig | dict[str, Any] | None = None,
        render_mode: str | None = None,
        env_index: int = 0,
        learned_scope: str = FROM_CONFIG,
        traffic: Any = None,
        perception: Any = FROM_CONFIG,
    ) -> None:
        self.task = self.make_task(
            render_mode, config, learned_scope, traffic, switching=switching,
            adas_penalty=adas_penalty, scenario=scenario,
            perception=perception,
        )  # fmt: skip
        self.config = self.task.config
        self.render_mode = render_mode
        self.observation_space = observation_space(self.task)  # type: ignore[assignment]
        self.action_space = action_space()  # type: ignore[assignment]
        self.env_index = int(env_index)
        self._seed: int | None = None
        self._episode = 0
        self._state: TaskState | None = None
        self._record: StepRecord | None = None
        self._cost_limits = tick_cost_limits(self.config)

    def make_task(self, render_mode: str | None, config: Any, learned_scope: str,
                  traffic: Any, **overrides: Any) -> LeftTurnTask:  # fmt: skip
        """The task behind the environment (:func:`~safeswitch.leftturn.make.build_task`; a
        subclass may run it on another simulator)."""
        return build_task(render_mode, config, learned_scope, traffic, **overrides)

    @property
    def state(self) -> TaskState:
        """The task state, a batch of one (after :meth:`reset`)."""
        if self._state is None:
            raise RuntimeError("call reset() before step() or render()")
        return self._state

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        super().reset(seed=seed)
        if options:
            raise ValueError(f"LeftTurnEnv.reset takes no options, got {sorted(options)}")
        if seed is not None:
            self._seed, self._episode = int(seed), 0
        elif self._seed is None:
            self._seed = int(self.np_random.integers(0, 2**63 - 1))
        scenarios = self.task.draw_scenarios(
            self._seed, np.array([self.env_index]), np.array([self._episode])
        )
        self._episode += 1
        self._state = self.task.initial(scenarios)
        self._record = None
        info = {"scenario": scenario_info(self._state.scenarios, 0)}
        if self.render_mode == "human":
            self.render()
        return self.task.observe(self._state)[0], info

    def step(
        self, action: NDArray[np.float32]
    ) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        limits = self._cost_limits
        costs: tuple[float, ...]
        if self.config.episode.decision_interval == 1:
            self._state, record = self.task.hold(self.state, learned_actions(action, 1))
            costs = tick_costs_of(record, 0, limits)
        else:  # the step's ticks summed, each while the episode was live
            sums = [0.0, 0.0, 0.0, 0.0]

            def on_tick(tick: StepRecord, live: NDArray[np.bool_]) -> None:
                if live[0]:
                    for k, value in enumerate(tick_costs_of(tick, 0, limits)):
                        sums[k] += value

            self._state, record = self.task.hold(self.state, learned_actions(action, 1), on_tick)
            costs = tuple(sums)
        self._record = record
        if self.render_mode == "human":
            self.render()
        info = step_info(record, 0, self.task.reasons)
        info["costs"] = dict(zip(PUBLISHED_COSTS, costs, strict=True))
        return (
            record.observed[0],
            float(record.reward[0]),
            bool(record.terminated[0]),
            bool(record.truncated[0]),
            info,
        )

    def render(self) -> NDArray[np.uint8] | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode='rgb_array' or 'human'")
            return None
        from safeswitch.leftturn.render import render_scene

        frame = render_scene(self.task, self.state, 0, self._record)
        if self.render_mode == "rgb_array":
            return frame
        self._window = show_frame(frame, getattr(self, "_window", None))
        return None

    def close(self) -> None:
        window = getattr(self, "_window", None)
        if window is not None:
            import pygame

            pygame.display.quit()
            self._window = None


def show_frame(frame: NDArray[np.uint8], window: Any) -> Any:
    """Draw ``frame`` in a pygame window (opened on the first call); returns the window.

    Raises:
        RuntimeError: pygame is missing, or there is no display to open a window on.
    """
    try:
        import pygame
    except ImportError as exc:
        raise RuntimeError(
            "render_mode='human' needs pygame (pip install pygame-ce); or use "
            "render_mode='rgb_array', or `safeswitch render --out episode.gif`"
        ) from exc
    if window is None:
        try:
            pygame.display.init()
            window = pygame.display.set_mode(frame.shape[1::-1])
        except pygame.error as exc:
            raise RuntimeError(
                f"render_mode='human' needs a display and none can be opened here ({exc}); use "
                "render_mode='rgb_array', or `safeswitch render --out episode.gif`"
            ) from exc
        pygame.display.set_caption("safeswitch/LeftTurn-v0")
    pygame.surfarray.blit_array(window, frame.swapaxes(0, 1))
    pygame.event.pump()
    pygame.display.flip()
    return window
