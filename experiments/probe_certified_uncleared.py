"""Where a driver under `certified` (the narrower zones) fails to clear the left turn in 12 s.

A one-off probe for docs/learning_experiments.md ("Where the never-cleared episodes are"): a
full-throttle learned controller behind the 29.9 km/h limiter under `certified` with
ego_max_lateral_m 0.45 and zone_margin_m 0.9, on the 1,000 unseen scenarios of seed 1000003;
prints the summary, the never-cleared scenarios' parameters and, for a few, when the filter
stopped the ego and when it let it go. Run: ``python experiments/probe_certified_uncleared.py``.
"""

from dataclasses import replace

import numpy as np

from safeswitch.evaluation.evaluate import run_controller, scenario_set, summary_against_oracle
from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.task import LeftTurnTask


def main() -> None:
    base = LeftTurnConfig()
    config = replace(
        base,
        switching="certified",
        certified=replace(base.certified, ego_max_lateral_m=0.45, zone_margin_m=0.9),
        controllers=replace(base.controllers, learned_speed_limiter_kmh=29.9),
        episode=replace(base.episode, learned_scope="episode"),
    )
    task = LeftTurnTask(config)
    scenarios, _ = scenario_set(task, "random", 1000, 1_000_003)
    speed: list[np.ndarray] = []
    result, plan = run_controller(
        task,
        lambda obs, state, tick: np.ones(obs.shape[0]),
        scenarios,
        on_tick=lambda state, record, tick: speed.append(state.world.vehicles.speed[:, 0].copy()),
    )
    summary = summary_against_oracle(result, plan, config.episode.horizon_s)
    keys = ("collisions", "cleared_episodes", "never_cleared_episodes", "cut_episodes",
            "mean_efficiency")  # fmt: skip
    print({k: summary[k] for k in keys})
    never = np.flatnonzero(np.isnan(np.asarray(result.time_to_clear, dtype=float)))
    v = np.array(speed)  # [ticks, B]
    dt = config.episode.dt
    print(
        "scenario  north behind [s]  north [km/h]  oracle clears [s]  stopped [s]  goes again [s]"
    )
    for i in never:
        still = np.flatnonzero(v[:, i] < 0.1)
        still = still[still > 50]
        stop, go = (still[0] * dt, (still[-1] + 1) * dt) if still.size else (np.nan, np.nan)
        print(f"{i:8d}  {scenarios.arrival_offset[i]:16.2f}  {3.6 * scenarios.north_speed[i]:12.1f}"
              f"  {plan.time_to_clear[i]:17.2f}  {stop:11.2f}  {go:14.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
