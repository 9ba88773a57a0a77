"""Simulator throughput: steps per second of the embedded plant, and highway-env for scale.

One simulation step of one scene = the ego (lane keeping PID + pedals) and the north car
(autopilot) advanced by one 20 ms tick, both projected onto their routes, plus the ego–north
collision check. Reported per scene-step and per vehicle-step (2 vehicles per scene).

If highway-env is installed (``pip install -e .[bench]``), its ``intersection-v0`` is stepped in
the same run with rendering off, and its simulation frames per second are reported with the
ratio. Run: ``python benchmarks/bench_sim.py [--json]``.
"""

from __future__ import annotations

import argparse
import sys
import time

import _common
from safeswitch.bench import sim_stepper, time_per_call

BATCHES = (1, 64, 1024, 8192)


def bench_highway_env(seconds: float = 3.0) -> dict[str, float] | None:
    try:
        import gymnasium as gym
        import highway_env  # noqa: F401
    except ImportError:
        return None
    env = gym.make("intersection-v0", render_mode=None)
    env.reset(seed=0)
    cfg = env.unwrapped.config
    frames_per_step = cfg["simulation_frequency"] // cfg["policy_frequency"]
    steps = frames = vehicle_frames = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        steps += 1
        frames += frames_per_step
        vehicle_frames += frames_per_step * len(env.unwrapped.road.vehicles)
        if terminated or truncated:
            env.reset()
    elapsed = time.perf_counter() - start
    env.close()
    return {
        "frames_per_s": frames / elapsed,
        "vehicle_frames_per_s": vehicle_frames / elapsed,
        "decisions_per_s": steps / elapsed,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--seconds", type=float, default=1.5, help="timing per batch size")
    args = parser.parse_args(argv)

    rows = []
    for batch in BATCHES:
        per_call = time_per_call(sim_stepper(batch), args.seconds)
        rows.append(
            {
                "batch": batch,
                "step_ms": per_call * 1e3,
                "scene_steps_per_s": batch / per_call,
                "vehicle_steps_per_s": 2 * batch / per_call,
            }
        )
    highway = bench_highway_env()
    result: dict[str, object] = {
        "benchmark": "sim",
        **_common.machine(),
        "rows": rows,
        "highway_env": highway,
    }
    if highway:
        result["ratio_vehicle_steps_vs_highway_env_at_8192"] = (
            rows[-1]["vehicle_steps_per_s"] / highway["vehicle_frames_per_s"]
        )
        result["ratio_scene_steps_vs_highway_env_frames_at_8192"] = (
            rows[-1]["scene_steps_per_s"] / highway["frames_per_s"]
        )
    if args.json:
        _common.emit(result, True)
        return 0
    print("safeswitch simulator, one core (numpy single-threaded), 20 ms ticks")
    print(f"{'batch':>6} {'step [ms]':>10} {'scene-steps/s':>15} {'vehicle-steps/s':>16}")
    for r in rows:
        print(
            f"{r['batch']:>6} {r['step_ms']:>10.3f} {r['scene_steps_per_s']:>15,.0f} "
            f"{r['vehicle_steps_per_s']:>16,.0f}"
        )
    if highway:
        print(
            f"highway-env intersection-v0: {highway['frames_per_s']:,.0f} frames/s, "
            f"{highway['vehicle_frames_per_s']:,.0f} vehicle-frames/s"
        )
        print(
            "ratio at batch 8192: "
            f"{result['ratio_vehicle_steps_vs_highway_env_at_8192']:,.0f}x vehicle-steps, "
            f"{result['ratio_scene_steps_vs_highway_env_frames_at_8192']:,.0f}x scene-steps"
        )
    else:
        print("highway-env not installed: pip install -e .[bench]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
