"""The exported controller without the training stack: numpy, numba (the switch's compiled
kernels) and onnxruntime; importing it imports neither torch, Stable-Baselines3 nor Gymnasium
(``tests/deploy/test_runtime.py`` checks ``sys.modules``). See docs/deploy.md.

Example::

    from safeswitch.runtime import Controller, Measurement

    controller = Controller("exported/", deadline_s=0.005)
    pedals, decision = controller.decide(observation, measurement)
"""

from __future__ import annotations

from safeswitch.runtime.controller import (
    DEADLINE_MISSED,
    Controller,
    ControllerLoadError,
    Measurement,
    Pedals,
    SwitchDecision,
    measurement_of,
)

__all__ = [
    "DEADLINE_MISSED",
    "Controller",
    "ControllerLoadError",
    "Measurement",
    "Pedals",
    "SwitchDecision",
    "measurement_of",
]
