import numpy as np
import pytest

from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.sim.vehicle import VehicleParams, steady_state_throttle


@pytest.fixture(scope="session")
def task():
    return LeftTurnTask(LeftTurnConfig())


def cruise_action(speed, target=25 / 3.6, gain=0.5):
    """A scripted learned controller: P control of the throttle towards ``target`` [m/s]
    around the throttle that holds it."""
    base = steady_state_throttle(VehicleParams(), np.asarray(target))
    throttle = np.clip(base + gain * (target - np.asarray(speed, dtype=float)), 0.0, 1.0)
    return 2.0 * throttle - 1.0
