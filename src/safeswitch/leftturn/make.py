"""Where a left-turn scene is made: the only module that knows every scene — the paper's
(:class:`~safeswitch.leftturn.task.LeftTurnTask`, the north car alone) and traffic from every
leg (:class:`~safeswitch.leftturn.traffic.LeftTurnTrafficTask`). The Gymnasium ``Env``, the
``VecEnv``, training and evaluation ask it for their task; the scene modules never import one
another's subclasses."""

from __future__ import annotations

from typing import Any

from safeswitch.core.config import to_dict
from safeswitch.leftturn.config import (
    FROM_CONFIG,
    LeftTurnConfig,
    episode_horizon_s,
    resolve_config,
    traffic_config,
)
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.leftturn.traffic import LeftTurnTrafficTask


def build_task(
    render_mode: str | None,
    config: LeftTurnConfig | dict[str, Any] | None,
    learned_scope: str = FROM_CONFIG,
    traffic: Any = None,
    **overrides: Any,
) -> LeftTurnTask:
    """The task behind an environment: ``render_mode`` checked, ``config`` resolved with the
    constructor's keyword arguments (see :func:`~safeswitch.leftturn.config.resolve_config`;
    ``learned_scope`` sets ``episode.learned_scope``); with ``traffic`` (a preset's name, a dict
    or a :class:`~safeswitch.leftturn.config.TrafficConfig`) the task in traffic."""
    if render_mode not in (None, "rgb_array", "human"):
        raise ValueError(f"render_mode must be None, 'rgb_array' or 'human', got {render_mode!r}")
    resolved = resolve_config(config, **overrides)
    if learned_scope is not FROM_CONFIG:
        episode = {**to_dict(resolved.episode), "learned_scope": learned_scope}
        resolved = resolve_config(resolved, episode=episode)
    settings = traffic_config(traffic)
    if settings is None:
        task = LeftTurnTask(resolved)
    else:
        horizon = episode_horizon_s(resolved.episode, settings)
        if horizon != resolved.episode.horizon_s:
            episode = {**to_dict(resolved.episode), "horizon_s": horizon}
            resolved = resolve_config(resolved, episode=episode)
        task = LeftTurnTrafficTask(resolved, settings)
    task.go_model  # noqa: B018 -- read now: a model that does not fit fails before anything runs
    return task
