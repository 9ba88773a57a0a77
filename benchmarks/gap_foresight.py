"""How often the gap planner's go check decides differently when it knows only what a car could
(``foresight: observed``: no vehicle still to come, every driver assumed never to yield) than
when it knows the simulation's future (``full``).

The full-foresight gap planner drives 200 scenes of the ``train`` traffic family under
``certified`` (seed 11, the warm start's family); every 25 ticks, in every scene still short of
its first crossing zone, both checks decide from the same state, and a third knows the drivers'
yielding but no vehicle still to come (which part of the hidden future makes a difference).

Run: ``python benchmarks/gap_foresight.py [--scenes N] [--json]`` (about a minute); writes
``benchmarks/results/gap_foresight.json``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import _common
from safeswitch.evaluation.traffic_planner import GapPlanner, GapPlannerConfig
from safeswitch.io import write_json
from safeswitch.leftturn.task import TaskState, build_task

RESULTS = Path(__file__).parent / "results" / "gap_foresight.json"
CERTIFIED = {"switching": "certified", "episode": {"learned_scope": "episode"}}


def without_arrivals(state: TaskState) -> TaskState:
    """A copy of ``state`` with no vehicle still to come (the drivers' yielding kept)."""
    copy = state.take(np.arange(state.batch_size))
    copy.traffic.schedule.time[:] = np.inf  # type: ignore[attr-defined]
    copy.traffic.next_arrival[:] = np.inf  # type: ignore[attr-defined]
    return copy


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=200)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    task = build_task(None, CERTIFIED, traffic={"preset": "train"})
    n = args.scenes
    state = task.initial(task.scenario_set(11, n))
    full = GapPlanner(task, GapPlannerConfig(foresight="full"))
    observed = GapPlanner(task, GapPlannerConfig(foresight="observed"))
    counts = dict.fromkeys(("decisions", "differ", "full_goes_observed_waits",
                            "observed_goes_full_waits", "differ_by_arrivals"), 0)  # fmt: skip
    for tick in range(task.config.episode.horizon_ticks):
        if tick % 25 == 0:
            live = state.world.progress[:, 0] <= full.first_entry
            a, b = full.goes(state), observed.goes(state)
            c = full.goes(without_arrivals(state))
            counts["decisions"] += int(live.sum())
            counts["differ"] += int((live & (a != b)).sum())
            counts["full_goes_observed_waits"] += int((live & a & ~b).sum())
            counts["observed_goes_full_waits"] += int((live & b & ~a).sum())
            counts["differ_by_arrivals"] += int((live & (a != c)).sum())
        state, _ = task.step(state, full(None, state, tick))
    result = {"benchmark": "gap_foresight", **_common.machine(), "scenes": n, "seed": 11,
              "every_ticks": 25, **counts}  # fmt: skip
    write_json(RESULTS, result)
    _common.emit(result, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
