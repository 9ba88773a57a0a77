import numpy as np
import pytest

from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.task import LeftTurnTask


@pytest.fixture(scope="session")
def task():
    return LeftTurnTask(LeftTurnConfig())


def cruise_action(speed, target=25 / 3.6, gain=0.5, base=0.2):
    """A scripted learned controller: P control of the throttle towards ``target`` [m/s]."""
    throttle = np.clip(base + gain * (target - np.asarray(speed, dtype=float)), 0.0, 1.0)
    return 2.0 * throttle - 1.0
