"""Where a trained policy needs the filter, and where its mean action lies beyond the bounds
(issue #39; docs/learning_experiments.md, "Seed 1's basin in traffic").

A one-off probe on a kept run (or a shipped policy's name): its deterministic policy drives
``EPISODES`` random scenes of a traffic family (seed 1000003, the README's) under the logic it
was trained with, and the probe reports

- in how many episodes each of the switching logic's reasons ran the safety action, and on
  how many ticks;
- the policy's Gaussian mean (before the environment clips it to [-1, 1]) at its decisions,
  by where the ego is on its route: percentiles, and the share beyond ±1.3 — a mean there
  makes every sample of a small exploration noise the same clipped action, so PPO cannot
  learn from those states;
- on the ticks the filter's clear backup ran: what the policy asked for, the ego's speed and
  its lateral acceleration.

Run: ``python experiments/probe_saturation.py RUN [FAMILY] [EPISODES]`` (default ``light``,
1,000; ``none`` for the single-car scene; about 20 s per 1,000 scenes, one thread).
"""

from __future__ import annotations

import sys
from collections import Counter
from typing import Any

import numpy as np
import torch

from safeswitch.app.evaluate import controller_setup, traffic_setup
from safeswitch.app.reproduce import EVAL_SEED
from safeswitch.evaluation.evaluate import run_controller, scenario_chunks
from safeswitch.leftturn.make import build_task
from safeswitch.training.policies import load_policy

#: Sections of the ego's route [m from its start]: the approach, the last metres before the
#: turn, the turn (the route's curve runs from 120 to 138.5 m).
SECTIONS = ((0.0, 100.0), (100.0, 118.0), (118.0, 140.0))


def main() -> None:
    model = sys.argv[1]
    family = sys.argv[2] if len(sys.argv) > 2 else "light"
    episodes = int(sys.argv[3]) if len(sys.argv) > 3 else 1000
    config, _ = controller_setup("learned", model, None, ())
    traffic, _ = traffic_setup("learned", model, family)
    task = build_task(None, config, traffic=traffic)
    trained = load_policy(model)
    reasons = task.reasons
    clear = reasons.index("backup_clear")
    means: list[np.ndarray] = []
    clear_ticks: list[np.ndarray] = []
    ticks: Counter[str] = Counter()
    episodes_with: Counter[str] = Counter()

    def policy(obs: np.ndarray, state: Any, tick: int) -> np.ndarray:
        mean = trained.raw_mean(trained.normalise(obs))[:, 0].astype(np.float64)
        means.append(np.stack([mean, state.world.progress[:, 0]], axis=1))
        return np.clip(mean, -1.0, 1.0)

    for names, batch in scenario_chunks(task, "random", episodes, EVAL_SEED):
        live = np.ones(len(names), dtype=bool)
        seen = np.zeros((len(names), len(reasons)), dtype=bool)

        def on_tick(state: Any, record: Any, tick: int, seen: np.ndarray = seen) -> None:
            nonlocal live
            for k in range(1, len(reasons)):
                hit = live & (record.reason == k)
                ticks[reasons[k]] += int(hit.sum())
                seen[:, k] |= hit
            hit = live & (record.reason == clear)
            clear_ticks.append(np.stack([
                record.learned_throttle[hit], record.throttle[hit], record.ego_speed[hit] * 3.6,
                np.abs(record.accel_lat[hit]),
            ], axis=1))  # fmt: skip
            live = live & ~(record.terminated | record.truncated)

        run_controller(task, policy, batch, on_tick, trace=False)
        for k in range(1, len(reasons)):
            episodes_with[reasons[k]] += int(seen[:, k].sum())

    print(f"{model} in {family}, {episodes} scenes (seed {EVAL_SEED})")
    print("the safety action, by reason (episodes; ticks):")
    for name in reasons[1:]:
        if ticks[name]:
            print(f"  {name}: {episodes_with[name]}; {ticks[name]}")
    log_std = getattr(trained.model.policy, "log_std", None)
    if log_std is not None:
        std = float(torch.exp(log_std.detach()).mean())
        print(f"exploration noise of the kept policy: std {std:.3f}")
    rows = np.concatenate(means)
    print("the policy's mean action by route section (percentiles 5/25/50/75/95; beyond ±1.3):")
    for low, high in SECTIONS:
        mean = rows[(rows[:, 1] >= low) & (rows[:, 1] < high), 0]
        if not len(mean):
            continue
        pct = " / ".join(f"{v:.2f}" for v in np.percentile(mean, [5, 25, 50, 75, 95]))
        over, under = np.mean(mean > 1.3), np.mean(mean < -1.3)
        print(f"  {low:.0f}-{high:.0f} m ({len(mean)} decisions): {pct}; "
              f"> 1.3 in {over:.1%}, < -1.3 in {under:.1%}")  # fmt: skip
    taken = np.concatenate(clear_ticks)
    if len(taken):
        med = np.median(taken, axis=0)
        print(f"clear backup ({len(taken)} ticks), medians: learned throttle {med[0]:.2f}, "
              f"executed {med[1]:.2f}, {med[2]:.1f} km/h, {med[3]:.2f} m/s² sideways")  # fmt: skip


if __name__ == "__main__":
    main()
