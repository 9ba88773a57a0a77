"""The Table I controllers on the plant (SPEC §2)."""

import numpy as np
import pytest

from safeswitch.core.pid import PIDState, pid_step
from safeswitch.sim.vehicle import VehicleState, vehicle_step


@pytest.mark.parametrize("v0", [6.94, 10.0])
def test_pid_b_holds_the_emergency_deceleration(task, v0):
    c = task.config
    gains, target = c.controllers.brake_pid, c.controllers.emergency_decel
    state = VehicleState.at(np.zeros(1), 0.0, 0.0, v0, throttle=1.0)  # throttle still open
    pid = PIDState.zeros((1,), task.brake_feedforward())
    accel, decels = 0.0, []
    while state.speed[0] > 0:
        brake, pid = pid_step(gains, pid, np.array([target + accel]), c.episode.dt)
        state, out = vehicle_step(c.vehicle, state, 0.0, brake, 0.0, c.episode.dt)
        accel = out.accel_lon[0]
        decels.append(-accel)
    decels = np.array(decels)
    assert np.mean(decels[5:-5]) == pytest.approx(target, rel=0.1)
    # The stop fits in what the paper switching logic reserves for it.
    p = c.paper
    reserved = v0**2 / (2 * target) + v0 * p.latency_s + p.stop_margin_m
    assert state.x[0] <= reserved
