"""Latency of one decision of the exported controller (``safeswitch.runtime``): the ONNX
policy's inference and the switch (controllers, switching logic, supervision), one vehicle,
one core.

Each shipped left-turn policy is exported (``safeswitch export``, parity checked) under the
logic named, then driven through ``Controller.decide`` on random unseen scenarios (seed
1,000,003) while the embedded simulator plays the plant; every ``decide`` call is timed with
``perf_counter`` after a warm-up (compilation). The process is pinned to one CPU; onnxruntime
and numba run one thread. Reported: percentiles over all ticks, and over the ticks on which
the policy ran (every ``decision_interval`` ticks; the others reuse the held action).

Target (issue #42): p99 ≤ 0.5 ms for one decision (policy + logic).

Run: ``python benchmarks/runtime_latency.py [--episodes 200] [--out results/runtime_latency.json]``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import _common

CASES = (("paper", "paper"), ("certified", "certified"))


def drive(folder: Path, episodes: int) -> dict[str, object]:
    """Time every ``decide`` of ``episodes`` episodes through the runtime."""
    import numpy as np  # after _common's thread pins

    from safeswitch.runtime import Controller, measurement_of

    controller = Controller(folder)
    task = controller.task
    scenarios = task.scenario_set(1_000_003, episodes)
    interval = task.config.episode.decision_interval
    all_ticks: list[float] = []
    policy_ticks: list[float] = []
    for warm in (True, False):
        for i in range(3 if warm else episodes):
            state = task.initial(scenarios.take(np.array([i])))
            controller.reset()
            observation = task.observe(state)
            for tick in range(task.config.episode.horizon_ticks):
                measurement = measurement_of(state)
                start = time.perf_counter()
                _, decision = controller.decide(observation[0], measurement)
                elapsed = time.perf_counter() - start
                if not warm:
                    all_ticks.append(elapsed)
                    if tick % interval == 0:
                        policy_ticks.append(elapsed)
                state, record = task.step(state, np.array([decision.learned_action]))
                observation = record.observation
                if record.terminated[0] or record.truncated[0]:
                    break

    def stats(values: list[float]) -> dict[str, float]:
        ms = 1e3 * np.asarray(values)
        return {
            "count": int(ms.size),
            "p50_ms": float(np.percentile(ms, 50)),
            "p99_ms": float(np.percentile(ms, 99)),
            "max_ms": float(ms.max()),
        }

    return {"all_ticks": stats(all_ticks), "policy_ticks": stats(policy_ticks)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    from safeswitch.deploy.export import export

    result: dict[str, object] = {"machine": _common.machine(), "target_p99_ms": 0.5}
    with tempfile.TemporaryDirectory() as tmp:
        for model, switching in CASES:
            folder = Path(tmp) / model
            export(model, folder, switching=switching, observations=10_000)
            measured = drive(folder, args.episodes)
            result[f"{model} under {switching}"] = measured
            if not args.json:
                a, p = measured["all_ticks"], measured["policy_ticks"]
                assert isinstance(a, dict) and isinstance(p, dict)
                print(
                    f"{model:>9} under {switching:<9}  all ticks: p50 {a['p50_ms']:.3f} ms, "
                    f"p99 {a['p99_ms']:.3f} ms, max {a['max_ms']:.2f} ms ({a['count']:,})   "
                    f"policy ticks: p50 {p['p50_ms']:.3f}, p99 {p['p99_ms']:.3f} ms "
                    f"({p['count']:,})"
                )
    _common.publish(result, args.out, args.json)


if __name__ == "__main__":
    main()
