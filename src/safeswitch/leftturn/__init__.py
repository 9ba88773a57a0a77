"""The left-turn case study (paper Section IV): controllers, switching logics, rewards,
scenarios, the Gymnasium environment and the natively batched VecEnv.

The public names are imported on first use: the batched simulation (what a campaign's worker
runs) needs neither Stable-Baselines3 nor torch, which the VecEnv brings in.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "LeftTurnConfig": "safeswitch.leftturn.config",
    "LeftTurnEnv": "safeswitch.leftturn.env",
    "LeftTurnTask": "safeswitch.leftturn.task",
    "LeftTurnVecEnv": "safeswitch.leftturn.vec_env",
    "make_vec_env": "safeswitch.leftturn.vec_env",
}

__all__ = ["LeftTurnConfig", "LeftTurnEnv", "LeftTurnTask", "LeftTurnVecEnv", "make_vec_env"]

if TYPE_CHECKING:
    from safeswitch.leftturn.config import LeftTurnConfig
    from safeswitch.leftturn.env import LeftTurnEnv
    from safeswitch.leftturn.task import LeftTurnTask
    from safeswitch.leftturn.vec_env import LeftTurnVecEnv, make_vec_env


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'safeswitch.leftturn' has no attribute {name!r}")
