"""Throughput measurements shared by ``safeswitch bench`` and the scripts in ``benchmarks/``.

Timings are medians over repeated blocks on one core (set ``OMP_NUM_THREADS=1`` and friends
before numpy is imported to be sure; the scripts in ``benchmarks/`` do).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from safeswitch.core.pid import PIDState, pid_step
from safeswitch.core.pid_gains import PIDGains


def time_per_call(fn: Callable[[], object], min_seconds: float = 1.0, warmup: int = 3) -> float:
    """Median wall time of one call of ``fn`` [s], over at least ``min_seconds``."""
    for _ in range(warmup):
        fn()
    blocks = []
    start = time.perf_counter()
    while True:
        t0 = time.perf_counter()
        fn()
        blocks.append(time.perf_counter() - t0)
        if time.perf_counter() - start > min_seconds and len(blocks) >= 5:
            break
    blocks.sort()
    return blocks[len(blocks) // 2]


def sim_stepper(batch: int) -> Callable[[], None]:
    """One simulator step of ``batch`` scenes per call: ego (lane keeping, fixed throttle) and
    north car (autopilot) advanced 20 ms, route tracking and the collision check."""
    from safeswitch.sim import (
        AutopilotParams,
        Intersection,
        World,
        autopilot_pedals,
        preview_offsets,
    )

    intersection = Intersection()
    world = World([intersection.route("south", "west"), intersection.route("north", "south")])
    rng = np.random.default_rng(0)
    progress = np.stack([rng.uniform(60, 110, batch), rng.uniform(60, 110, batch)], 1)
    state = world.place(progress, rng.uniform(4, 9, (batch, 2)))
    lka_state, speed_state = PIDState.zeros((batch, 2)), PIDState.zeros((batch,))
    lka = PIDGains(0.2, 0.01, 0.02, -1.0, 1.0)
    autopilot = AutopilotParams()
    target, ego_throttle = np.full(batch, 8.0), np.full(batch, 0.35)

    def step() -> None:
        nonlocal state, lka_state, speed_state
        steer, lka_state = pid_step(lka, lka_state, preview_offsets(world, state, 5.0), world.dt)
        throttle_n, brake_n, speed_state = autopilot_pedals(
            autopilot, world.params, state.vehicles.speed[:, 1], target, speed_state, world.dt
        )
        throttle = np.stack([ego_throttle, throttle_n], 1)
        brake = np.stack([np.zeros(batch), brake_n], 1)
        state, _, _ = world.step(state, throttle, brake, steer)

    return step


def sim_steps_per_s(batch: int, seconds: float = 1.0) -> float:
    """Scene-steps per second of the simulator at ``batch`` scenes (2 vehicles each)."""
    return batch / time_per_call(sim_stepper(batch), seconds)


def vec_env_steps_per_s(
    num_envs: int, switching: str = "paper", seconds: float = 1.0, **env_kwargs: Any
) -> float:
    """Environment steps per second of the batched VecEnv (random actions); ``env_kwargs`` as
    for :func:`~safeswitch.leftturn.make_vec_env` (e.g. ``perception``)."""
    from safeswitch.leftturn import make_vec_env

    env = make_vec_env(num_envs, switching=switching, seed=0, **env_kwargs)
    env.reset()
    actions = np.random.default_rng(0).uniform(-1, 1, (16, num_envs, 1))
    counter = {"k": 0}

    def one_step() -> None:
        env.step(actions[counter["k"] % 16])
        counter["k"] += 1

    return num_envs / time_per_call(one_step, seconds)


def env_steps_per_s(switching: str = "paper", seconds: float = 1.0) -> float:
    """Steps per second of the Gymnasium Env (a batch of one), resets included."""
    from safeswitch.leftturn import LeftTurnEnv

    env = LeftTurnEnv(switching=switching)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (1000, 1)).astype(np.float32)
    counter = {"k": 0}

    def hundred_steps() -> None:
        for _ in range(100):
            _, _, terminated, truncated, _ = env.step(actions[counter["k"] % 1000])
            counter["k"] += 1
            if terminated or truncated:
                env.reset()

    return 100 / time_per_call(hundred_steps, seconds)


def quick_bench(seconds: float = 0.5) -> dict[str, float]:
    """The headline throughput figures, in a few seconds (the simulator's scene- and
    vehicle-steps come from one measurement: two vehicles per scene)."""
    scenes = sim_steps_per_s(8192, seconds)
    return {
        "sim_scene_steps_per_s_batch_8192": scenes,
        "sim_vehicle_steps_per_s_batch_8192": 2 * scenes,
        "vec_env_steps_per_s_4096": vec_env_steps_per_s(4096, "paper", seconds),
        "vec_env_certified_steps_per_s_4096": vec_env_steps_per_s(4096, "certified", seconds),
        "env_steps_per_s": env_steps_per_s("paper", seconds),
    }
