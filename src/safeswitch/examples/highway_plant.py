"""``safeswitch/Highway-v0``: highway-env's highway with continuous actions under a switching
logic, with the Safety controller that logic reasons about (:mod:`safeswitch.examples.highway`
for the plant's state, ``ttc`` and its controller; :mod:`safeswitch.examples.highway_certified`
for ``certified``). highway-env is imported only when an environment is made."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from safeswitch.core.wrappers import SafeSwitch
from safeswitch.examples.highway import (
    HIGHWAY_CONFIG,
    HighwaySafetyController,
    highway_rules,
    highway_state,
)
from safeswitch.examples.highway_certified import CertifiedHighwayController, certified_rules


def make_highway_env(
    switching: str = "ttc",
    penalty: float = -1.0,
    config: dict[str, Any] | None = None,
    render_mode: str | None = None,
    logic_params: dict[str, Any] | None = None,
) -> SafeSwitch:
    """``safeswitch/Highway-v0``: highway-env's ``highway-fast-v0`` with continuous actions
    under a switching logic.

    Args:
        switching: A registered logic (``certified``, ``ttc``, ``none`` or a plugin's);
            ``certified`` comes with the Safety controller it reasons about
            (:class:`~safeswitch.examples.highway_certified.CertifiedHighwayController`),
            every other with :class:`HighwaySafetyController`.
        penalty: ``R_ADAS`` on a step the Safety controller acted (ours: highway-env's
            normalised reward lies in [0, 1] per step, so -1 costs a step's worth of reward; the
            paper's -25 was set against a per-tick reward of up to 4).
        config: highway-env configuration entries that replace :data:`HIGHWAY_CONFIG`'s.
        render_mode: Passed to highway-env (``"rgb_array"`` for pictures).
        logic_params: Parameters of the logic (``ttc``: :class:`TTCParams`' keys).
    """
    import highway_env  # noqa: F401  (registers highway-fast-v0)

    env = gym.make(
        "highway-fast-v0", config={**HIGHWAY_CONFIG, **(config or {})}, render_mode=render_mode
    )
    controller: Any = HighwaySafetyController(highway_rules(env))
    if switching == "certified":
        controller = CertifiedHighwayController(certified_rules(env))
    return SafeSwitch(
        env,
        controller,
        switching,
        penalty=penalty,
        state_fn=highway_state,
        logic_params=logic_params,
    )


__all__ = ["make_highway_env"]
