"""The core framework with a plant of a different kind: a car following a lead car in 1-D.

Nothing here imports the simulator or the left-turn case study: a user brings their own plant,
Safety controller and switching rule, and the core supervisor keeps them honest.
"""

from dataclasses import dataclass

import numpy as np

from safeswitch.core.pid import PIDState, pid_step
from safeswitch.core.pid_gains import PIDGains
from safeswitch.core.switching import Decision, reason_names, supervise

DT = 0.1
MAX_BRAKE = 8.0  # [m/s²]
MAX_ACCEL = 3.0  # [m/s²]


@dataclass
class Gap:
    distance: np.ndarray  # bumper to bumper [m]
    speed: np.ndarray  # follower [m/s]
    lead_speed: np.ndarray  # [m/s]


def margin(distance, speed, lead_speed):
    """Gap left if both brake fully from now on: the lead never stops in less than v²/2b."""
    return distance + lead_speed**2 / (2 * MAX_BRAKE) - speed**2 / (2 * MAX_BRAKE)


class BrakingEnvelope:
    """Accept an acceleration if, after one tick of it, full braking still stops the follower
    at least 1 m behind wherever the lead car can stop (a responsibility-sensitive distance)."""

    reasons = ("learned", "too_close")

    def decide(self, s: Gap, learned: np.ndarray, safe: np.ndarray) -> Decision:
        v1 = np.maximum(s.speed + learned[:, 0] * DT, 0.0)
        travelled = 0.5 * (s.speed + v1) * DT
        unsafe = margin(s.distance - travelled, v1, s.lead_speed) < 1.0
        return Decision(unsafe, unsafe.astype(np.int8), safe)


def test_the_core_supervisor_keeps_a_random_follower_behind_its_lead():
    rng = np.random.default_rng(0)
    n, ticks = 2000, 600
    state = Gap(rng.uniform(5, 60, n), rng.uniform(0, 25, n), rng.uniform(0, 25, n))
    ok = margin(state.distance, state.speed, state.lead_speed) >= 1.0  # start from safe states
    state = Gap(state.distance[ok], state.speed[ok], state.lead_speed[ok])
    n = int(ok.sum())
    logic = BrakingEnvelope()
    keeper = PIDGains(kp=0.5, ki=0.0, kd=0.0, out_min=-MAX_BRAKE, out_max=MAX_ACCEL)
    memory = PIDState.zeros((n,))
    switched = np.zeros(n, dtype=bool)
    for _ in range(ticks):
        learned = rng.uniform(-MAX_BRAKE, MAX_ACCEL, (n, 1))  # a random learned controller
        learned[rng.random(n) < 0.05] = np.nan
        # The Safety controller: a PID that drives the speed to zero, saturating at full brake.
        brake, memory = pid_step(keeper, memory, -state.speed * 100.0, DT)
        safe = brake[:, None]
        sup = supervise(logic, state, learned, safe, -MAX_BRAKE, MAX_ACCEL)
        assert np.isfinite(sup.executed).all()
        switched |= sup.safety_active
        accel = sup.executed[:, 0]
        lead_accel = rng.uniform(-MAX_BRAKE, MAX_ACCEL, n)
        new_speed = np.maximum(state.speed + accel * DT, 0.0)
        new_lead = np.maximum(state.lead_speed + lead_accel * DT, 0.0)
        state = Gap(
            state.distance
            + 0.5 * (state.lead_speed + new_lead) * DT
            - 0.5 * (state.speed + new_speed) * DT,
            new_speed,
            new_lead,
        )
        assert (state.distance > 0).all()
    assert switched.mean() > 0.5  # the rule really had to work
    assert reason_names(logic) == ("learned", "too_close", "invalid_learned_action")
