"""Drivers for the ego's seat of ``safeswitch/Highway-v0``, none of which knows the switch:
highway-env's own IDM/MOBIL driver (the floor a competent rule-based driver sets), and three
adversaries that try to crash (the benchmark ``benchmarks/highway_adversaries.py`` and
``tests/examples/test_highway_certified.py`` drive them under each logic).

Each is a policy: ``driver.reset(env)`` at the start of an episode, then ``driver(observation)
-> action`` in ``[-1, 1]²`` (acceleration, steering) every decision.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from safeswitch.core.tally import StepTally
from safeswitch.examples.highway import ACCEL_RANGE, STEER_RANGE


class IDMDriver:
    """highway-env's IDM (longitudinal) and MOBIL (lane changes) in the ego's seat: a shadow
    ``IDMVehicle`` (target speed ``target_speed``, the top of highway-env's rewarded speed
    range) takes the ego's place on the road for each decision, so that it sees the road as
    the ego would, and its command is scaled to the action."""

    def __init__(self, target_speed: float = 30.0) -> None:
        self.target_speed = target_speed
        self.env: Any = None
        self.shadow: Any = None

    def reset(self, env: Any) -> None:
        from highway_env.vehicle.behavior import IDMVehicle

        self.env = env.unwrapped
        ego = self.env.vehicle
        self.shadow = IDMVehicle(
            ego.road, ego.position.copy(), ego.heading, ego.speed, target_speed=self.target_speed
        )
        self.shadow.target_lane_index = ego.lane_index

    def __call__(self, _: Any) -> np.ndarray:
        ego, road, shadow = self.env.vehicle, self.env.road, self.shadow
        shadow.position, shadow.heading, shadow.speed = ego.position.copy(), ego.heading, ego.speed
        shadow.lane_index = road.network.get_closest_lane_index(shadow.position, shadow.heading)
        shadow.lane = road.network.get_lane(shadow.lane_index)
        seat = road.vehicles.index(ego)
        road.vehicles[seat] = shadow
        try:
            shadow.act()
        finally:
            road.vehicles[seat] = ego
        shadow.timer += 1.0 / self.env.config["policy_frequency"]
        command = shadow.action
        return np.clip(
            [command["acceleration"] / ACCEL_RANGE, command["steering"] / STEER_RANGE], -1.0, 1.0
        )


class Adversary:
    """A driver that draws an action and holds it for a few decisions, from its own random
    generator (seeded once: a run of episodes is reproducible).

    Args:
        kind: ``random`` (uniform actions held 1–7 decisions), ``weaving`` (full throttle and
            sudden lane changes, held 1–5: it passes whatever it can), or ``brake-checking``
            (bursts of full throttle, full braking or coasting with a slight wobble, held 1–9).
        seed: Its generator's seed.
    """

    KINDS = ("random", "weaving", "brake-checking")

    def __init__(self, kind: str, seed: int = 0) -> None:
        if kind not in self.KINDS:
            raise ValueError(f"adversary kind {kind!r} is not one of {', '.join(self.KINDS)}")
        self.kind, self.rng = kind, np.random.default_rng(seed)
        self.action, self.hold = np.zeros(2), 0

    def reset(self, env: Any) -> None:
        self.hold = 0

    def __call__(self, _: Any) -> np.ndarray:
        if self.hold == 0:
            self.action, self.hold = self._draw()
        self.hold -= 1
        return self.action

    def _draw(self) -> tuple[np.ndarray, int]:
        rng = self.rng
        if self.kind == "random":
            return rng.uniform(-1, 1, 2), int(rng.integers(1, 8))
        if self.kind == "weaving":
            steer = rng.choice([-1, 1]) * rng.uniform(0, 0.3) * (rng.random() < 0.5)
            return np.array([rng.uniform(0.2, 1.0), steer]), int(rng.integers(1, 6))
        throttle = rng.choice([1.0, -1.0, 0.0])
        return np.array([throttle, rng.uniform(-0.15, 0.15)]), int(rng.integers(1, 10))


def drive(env: Any, driver: Any, episodes: int, seed: int) -> dict[str, Any]:
    """``episodes`` episodes of ``driver`` on ``env`` (a ``safeswitch/Highway-v0``), reset with
    seeds ``seed``, ``seed + 1``, …: crashes, off-road episodes, steps, the steps on which the
    Safety controller acted (and why: the logic's reasons), the steps each of the plant's costs
    (``speeding``, ``comfort``, ``following``) was positive, and the mean return."""
    crashes = off_road = steps = 0
    returns = []
    tally = StepTally()
    for k in range(episodes):
        observation, _ = env.reset(seed=seed + k)
        driver.reset(env)
        total, done = 0.0, False
        info: dict[str, Any] = {}
        while not done:
            observation, reward, terminated, truncated, info = env.step(driver(observation))
            total += float(reward)
            steps += 1
            tally.add(info)
            done = terminated or truncated
        returns.append(total)
        crashes += bool(info["crashed"])
        off_road += info["rewards"]["on_road_reward"] == 0
    return {
        "episodes": episodes,
        "crashes": crashes,
        "off_road": off_road,
        "steps": steps,
        "safety_activation_steps": tally.safety_steps,
        "safety_share": tally.safety_steps / steps if steps else None,
        **tally.summary(),
        "mean_return": float(np.mean(returns)) if returns else None,
    }


__all__ = ["Adversary", "IDMDriver", "drive"]
