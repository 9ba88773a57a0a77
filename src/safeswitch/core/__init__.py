"""The plant-agnostic framework: controllers, switching logics and their composition."""

from safeswitch.core.pid import PIDGains, PIDState, pid_step

__all__ = ["PIDGains", "PIDState", "pid_step"]
