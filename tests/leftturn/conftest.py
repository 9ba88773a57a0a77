import numpy as np
import pytest

from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.spaces import speed_tracking_action
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.sim.params import VehicleParams


@pytest.fixture(scope="session")
def task():
    return LeftTurnTask(LeftTurnConfig())


def cruise_action(speed, target=25 / 3.6, gain=0.5):
    """A scripted learned controller: P control of the throttle towards ``target`` [m/s]
    around the throttle that holds it."""
    return speed_tracking_action(VehicleParams(), target, np.asarray(speed, dtype=float), gain)
