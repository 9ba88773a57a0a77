"""The plant-agnostic framework: controllers, switching logics and their composition.

The public names are imported on first use, so that configuration (which reads
:mod:`safeswitch.core.config` and :mod:`safeswitch.core.pid_gains`) loads no compiled code."""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "PIDGains": "safeswitch.core.pid_gains",
    "PIDState": "safeswitch.core.pid",
    "pid_step": "safeswitch.core.pid",
}

__all__ = ["PIDGains", "PIDState", "pid_step"]

if TYPE_CHECKING:
    from safeswitch.core.pid import PIDState, pid_step
    from safeswitch.core.pid_gains import PIDGains


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'safeswitch.core' has no attribute {name!r}")
