"""safeswitch: safe reinforcement learning with a rule-based Safety controller, a learned
controller and a switching logic between them (Aksjonov & Kyrki), on an embedded simulator.

Importing the package registers the Gymnasium id ``safeswitch/LeftTurn-v0`` (and the others
below) once Gymnasium is imported, before or after: the package itself does not import
Gymnasium, so the deployment runtime (:mod:`safeswitch.runtime`) runs without it. The
framework's public names (:class:`SafeSwitch`, :class:`SafeSwitchVecEnv`,
:class:`SwitchingLogic`, :class:`Decision`, :func:`register_logic`,
:func:`register_safety_controller`, …) are imported on first use, so ``import safeswitch``
stays light.
"""

from __future__ import annotations

import sys
from importlib import import_module
from importlib.abc import MetaPathFinder
from importlib.machinery import ModuleSpec
from importlib.util import find_spec
from types import ModuleType
from typing import TYPE_CHECKING, Any

__version__ = "0.3.0"

ENV_ID = "safeswitch/LeftTurn-v0"
#: highway-env's highway with continuous actions under a switching logic (needs the
#: ``highway-env`` package; see :mod:`safeswitch.examples.highway`).
HIGHWAY_ENV_ID = "safeswitch/Highway-v0"

#: The left turn with SUMO driving the north car (extra ``safeswitch[sumo]``).
SUMO_ENV_ID = "safeswitch/LeftTurnSumo-v0"

#: The left turn among traffic from every leg (``traffic=`` a preset or settings).
TRAFFIC_ENV_ID = "safeswitch/LeftTurnTraffic-v0"


def _register_envs(gym: Any) -> None:
    """Register the package's Gymnasium ids (once)."""
    ids: dict[str, dict[str, Any]] = {
        ENV_ID: {"entry_point": "safeswitch.leftturn.env:LeftTurnEnv"},
        TRAFFIC_ENV_ID: {
            "entry_point": "safeswitch.leftturn.env:LeftTurnEnv",
            "kwargs": {"traffic": "medium"},
        },
        SUMO_ENV_ID: {"entry_point": "safeswitch.sumo.task:LeftTurnSumoEnv"},
        HIGHWAY_ENV_ID: {"entry_point": "safeswitch.examples.highway_plant:make_highway_env"},
    }
    for env_id, spec in ids.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, **spec)


class _RegisterWithGymnasium(MetaPathFinder):
    """Registers the ids the moment Gymnasium is imported, so that ``import safeswitch`` does
    not import Gymnasium itself: the deployment runtime (:mod:`safeswitch.runtime`) runs where
    there is no training stack. It finds Gymnasium's real module spec and registers once that
    module has run."""

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> ModuleSpec | None:
        if name != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = find_spec(name)
        loader = None if spec is None else spec.loader
        if loader is None or not hasattr(loader, "exec_module"):
            return spec
        run = loader.exec_module

        def exec_module(module: ModuleType) -> None:
            run(module)
            _register_envs(module)

        loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec


if "gymnasium" in sys.modules:
    _register_envs(sys.modules["gymnasium"])
elif not any(isinstance(f, _RegisterWithGymnasium) for f in sys.meta_path):
    sys.meta_path.insert(0, _RegisterWithGymnasium())

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
    "register_safety_controller": "safeswitch.core.registry",
    "make_logic": "safeswitch.core.registry",
    "logic_names": "safeswitch.core.registry",
    "adapt": "safeswitch.app.adapt",
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
    "adapt",
    "logic_names",
    "make_logic",
    "register_logic",
    "register_safety_controller",
    "supervise",
]

if TYPE_CHECKING:
    from safeswitch.app.adapt import adapt
    from safeswitch.core.registry import (
        logic_names,
        make_logic,
        register_logic,
        register_safety_controller,
    )
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
