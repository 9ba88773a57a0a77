"""safeswitch: safe reinforcement learning with a rule-based Safety controller, a learned
controller and a switching logic between them (Aksjonov & Kyrki), on an embedded simulator.

Importing the package registers the Gymnasium id ``safeswitch/LeftTurn-v0``. The framework's
public names (:class:`SafeSwitch`, :class:`SafeSwitchVecEnv`, :class:`SwitchingLogic`,
:class:`Decision`, :func:`register_logic`, …) are imported on first use, so ``import
safeswitch`` stays light.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

import gymnasium as _gym

__version__ = "0.3.0"

ENV_ID = "safeswitch/LeftTurn-v0"
#: highway-env's highway with continuous actions under a switching logic (needs the
#: ``highway-env`` package; see :mod:`safeswitch.examples.highway`).
HIGHWAY_ENV_ID = "safeswitch/Highway-v0"

#: The left turn with SUMO driving the north car (extra ``safeswitch[sumo]``).
SUMO_ENV_ID = "safeswitch/LeftTurnSumo-v0"

#: The left turn among traffic from every leg (``traffic=`` a preset or settings).
TRAFFIC_ENV_ID = "safeswitch/LeftTurnTraffic-v0"

if ENV_ID not in _gym.registry:
    _gym.register(id=ENV_ID, entry_point="safeswitch.leftturn.env:LeftTurnEnv")
if TRAFFIC_ENV_ID not in _gym.registry:
    _gym.register(
        id=TRAFFIC_ENV_ID,
        entry_point="safeswitch.leftturn.env:LeftTurnEnv",
        kwargs={"traffic": "medium"},
    )
if SUMO_ENV_ID not in _gym.registry:
    _gym.register(id=SUMO_ENV_ID, entry_point="safeswitch.sumo.task:LeftTurnSumoEnv")
if HIGHWAY_ENV_ID not in _gym.registry:
    _gym.register(id=HIGHWAY_ENV_ID, entry_point="safeswitch.examples.highway:make_highway_env")

#: Public name → the module that defines it.
_EXPORTS = {
    "SafeSwitch": "safeswitch.core.wrappers",
    "SafeSwitchVecEnv": "safeswitch.core.wrappers",
    "SwitchingLogic": "safeswitch.core.switching",
    "Decision": "safeswitch.core.switching",
    "Guarded": "safeswitch.core.switching",
    "NeverSwitch": "safeswitch.core.switching",
    "SwitchingError": "safeswitch.core.switching",
    "supervise": "safeswitch.core.switching",
    "register_logic": "safeswitch.core.registry",
    "make_logic": "safeswitch.core.registry",
    "logic_names": "safeswitch.core.registry",
}

__all__ = [
    "ENV_ID",
    "HIGHWAY_ENV_ID",
    "SUMO_ENV_ID",
    "TRAFFIC_ENV_ID",
    "Decision",
    "Guarded",
    "NeverSwitch",
    "SafeSwitch",
    "SafeSwitchVecEnv",
    "SwitchingError",
    "SwitchingLogic",
    "__version__",
    "logic_names",
    "make_logic",
    "register_logic",
    "supervise",
]

if TYPE_CHECKING:
    from safeswitch.core.registry import logic_names, make_logic, register_logic
    from safeswitch.core.switching import (
        Decision,
        Guarded,
        NeverSwitch,
        SwitchingError,
        SwitchingLogic,
        supervise,
    )
    from safeswitch.core.wrappers import SafeSwitch, SafeSwitchVecEnv


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'safeswitch' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value
