"""A plant nobody in safeswitch wrote for: a car following a lead car in one dimension, as a
Gymnasium env, with a Safety controller and a switching logic of its own.

The lead car accelerates at random within ``[-MAX_BRAKE, MAX_ACCEL]``. The follower's action
is its acceleration. ``BrakingEnvelope`` accepts an acceleration only if, after one tick of it,
full braking still stops the follower at least ``MIN_GAP`` behind wherever the lead car can stop
(a responsibility-sensitive distance); else the Safety controller brakes fully.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from safeswitch import Decision, register_logic
from safeswitch.core.registry import register_safety_controller

DT = 0.1  # [s]
MAX_BRAKE = 8.0  # [m/s²]
MAX_ACCEL = 3.0  # [m/s²]
MIN_GAP = 1.0  # [m]


def margin(gap, speed, lead_speed):
    """Gap left if both brake fully from now on [m]."""
    return gap + lead_speed**2 / (2 * MAX_BRAKE) - speed**2 / (2 * MAX_BRAKE)


class Follow(gym.Env):
    """Observation (gap [m], speed [m/s], lead speed [m/s]); action: acceleration [m/s²].

    ``received`` keeps every action the environment was stepped with, ``crashes`` counts the
    episodes that ended with the follower in the lead car."""

    observation_space = gym.spaces.Box(0.0, np.inf, (3,), np.float64)
    action_space = gym.spaces.Box(-MAX_BRAKE, MAX_ACCEL, (1,), np.float32)

    def __init__(self, horizon: int = 200):
        self.horizon = horizon
        self.received: list[np.ndarray] = []
        self.crashes = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        while True:
            self.state = self.np_random.uniform([5, 0, 0], [60, 25, 25])
            if margin(*self.state) >= 3 * MIN_GAP:
                break
        self.t = 0
        return self.state.copy(), {}

    def step(self, action):
        self.received.append(np.array(action, copy=True))
        gap, speed, lead = self.state
        accel = float(np.asarray(action).reshape(-1)[0])
        lead_accel = self.np_random.uniform(-MAX_BRAKE, MAX_ACCEL)
        new_speed, new_lead = max(speed + accel * DT, 0.0), max(lead + lead_accel * DT, 0.0)
        gap += 0.5 * (lead + new_lead) * DT - 0.5 * (speed + new_speed) * DT
        self.state = np.array([gap, new_speed, new_lead])
        self.t += 1
        crashed = gap <= 0
        self.crashes += int(crashed)
        reward = -100.0 if crashed else new_speed / 25.0
        return (
            self.state.copy(),
            reward,
            bool(crashed),
            self.t >= self.horizon,
            {"crashed": crashed},
        )


def full_brake(state: np.ndarray) -> np.ndarray:
    """The Safety controller: brake fully, ``[B, 1]``."""
    return np.full((np.asarray(state).shape[0], 1), -MAX_BRAKE)


class BrakingEnvelope:
    """Learned acceleration if full braking after one tick of it keeps ``MIN_GAP``."""

    reasons = ("learned", "too_close")

    def decide(self, state, learned, safe):
        gap, speed, lead = state[:, 0], state[:, 1], state[:, 2]
        v1 = np.maximum(speed + learned[:, 0] * DT, 0.0)
        travelled = 0.5 * (speed + v1) * DT
        lead_moved = np.maximum(lead - MAX_BRAKE * DT, 0.0)
        lead_travelled = 0.5 * (lead + lead_moved) * DT
        unsafe = margin(gap - travelled + lead_travelled, v1, lead_moved) < MIN_GAP
        return Decision(unsafe, unsafe.astype(np.int8), safe)


def register_plant(env_id, entry_point, safety, failure, logic, make_logic):
    """Register a plant as a user does: its Gymnasium id, its Safety controller ``safety``
    with what counts as its ``failure``, and its switching logic ``logic`` (``make_logic()``
    builds it)."""
    if env_id not in gym.registry:
        gym.register(env_id, entry_point=entry_point)
    register_safety_controller(env_id, lambda env: safety, failure=failure)
    register_logic(logic, lambda context: make_logic(), replace=True)
