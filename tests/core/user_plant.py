"""A user's plant, registered when imported (``--import tests.core.user_plant``): a cart that
must stop before a wall. Its failure is its own ``info["hit_wall"]`` — neither ``crashed``
nor ``collision`` — declared with its Safety controller; its switching logic is its own too;
it publishes one named cost, ``info["costs"]["speeding"]`` (faster than ``SPEED_LIMIT``).

``HITS`` counts every episode that ended at the wall, so a test can check what the pipeline
counted against what the plant did.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from safeswitch import Decision
from tests.core.plants import register_plant

ENV_ID = "UserWall-v0"
LOGIC = "stopping-distance"
DT = 0.1  # [s]
MAX_BRAKE = 3.0  # [m/s²]
MAX_ACCEL = 2.0  # [m/s²]
MARGIN = 0.5  # [m]
SPEED_LIMIT = 5.0  # [m/s]: faster is the plant's named cost ``speeding``

HITS: list[int] = []


class Wall(gym.Env):
    """Observation (distance to the wall [m], speed [m/s]); action: acceleration [m/s²]. The
    reward pays speed, so a policy left alone learns to drive into the wall."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
    action_space = gym.spaces.Box(-MAX_BRAKE, MAX_ACCEL, (1,), np.float32)

    def __init__(self, horizon: int = 60):
        self.horizon = horizon

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.state = self.np_random.uniform([12.0, 2.0], [30.0, 6.0])
        self.t = 0
        return self.state.copy(), {}

    def step(self, action):
        distance, speed = self.state
        accel = float(np.clip(np.asarray(action, dtype=np.float64).reshape(-1)[0], -3, 2))
        new_speed = max(speed + accel * DT, 0.0)
        distance -= 0.5 * (speed + new_speed) * DT
        self.state = np.array([distance, new_speed])
        self.t += 1
        hit = distance <= 0.0
        if hit:
            HITS.append(1)
        reward = -10.0 if hit else new_speed / 10.0
        info = {"hit_wall": hit, "costs": {"speeding": float(new_speed > SPEED_LIMIT)}}
        return self.state.copy(), reward, bool(hit), self.t >= self.horizon, info


def full_brake(state: np.ndarray) -> np.ndarray:
    """The Safety controller: brake fully, ``[B, 1]``."""
    return np.full((np.asarray(state).shape[0], 1), -MAX_BRAKE)


class StoppingDistance:
    """The learned acceleration if, one tick of it later, full braking still stops the cart
    ``MARGIN`` before the wall; else the Safety controller's."""

    reasons = ("learned", "too_close")

    def decide(self, state, learned, safe):
        distance, speed = state[:, 0], state[:, 1]
        v1 = np.maximum(speed + np.clip(learned[:, 0], -MAX_BRAKE, MAX_ACCEL) * DT, 0.0)
        left = distance - 0.5 * (speed + v1) * DT
        unsafe = left - v1**2 / (2 * MAX_BRAKE) < MARGIN
        return Decision(unsafe, unsafe.astype(np.int8), safe)


def register() -> None:
    """Register the plant, its Safety controller (with its failure) and its logic."""
    register_plant(ENV_ID, Wall, full_brake, "hit_wall", LOGIC, StoppingDistance)


register()
