"""Would knowing when a drive begun later gets through help the single-car scene clear 99 %?
(issue #39; docs/learning_experiments.md, "A go predictor for the left turn").

A one-off probe with exact, simulated checks (no learning): the `certified` recipe's scene (no
predictor in the observation) on the 1,000 unseen scenarios of seed 1000003, driven by

1. the throttle planner alone;
2. the planner, overruled by the go check the recipe's predictor learns: drive the planners'
   fast drive wherever it gets past the ego's certified zone, with no collision, without the
   filter acting and within the episode's time;
3. 2, and where that fails, coast (throttle closed) wherever the fast drive begun after one of
   ``DELAYS`` seconds of coasting gets through — the "coast, then go" drives that lift the
   ceiling (benchmarks/certified_ceiling.py) above the full-throttle driver and the planner.

4. 3, and the fast drive also wherever driving it for one more decision still leaves one of
   those coast-then-go drives that gets through (drive, coast, then go: what the ceiling's
   search does before it coasts).

If 3 and 4 clear no more than the trained policies (983-985), a predictor of delayed drives in
the observation is not the missing information. Run: ``python
experiments/probe_certified_delays.py [DELAY ...]`` (default every 0.25 s from 0.25 to 7 s; one
thread, about 3 min for 1-3 and 6 more for 4).
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
from probe_go_rule import score_rules

from safeswitch.evaluation.evaluate import scenario_chunks
from safeswitch.evaluation.planner import FastDrive, Planner, throttle_scene
from safeswitch.evaluation.traffic_planner import GapPlannerConfig
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.task import LeftTurnTask, TaskState
from safeswitch.training.config import load_config

config = load_config("certified")
ENV = dataclasses.replace(
    config.env, episode=dataclasses.replace(config.env.episode, go_model=None)
)
TASK = build_task(None, ENV)
G = GapPlannerConfig()
DRIVE = FastDrive(TASK, G.top_speed_kmh, G.accel_lat, G.curve_decel, G.preview_s, G.speed_gain)
CHECK = LeftTurnTask(dataclasses.replace(throttle_scene(TASK.config), switching="certified"))
ENTRY, EXIT = TASK.north_conflict.ego_cert_zone
HORIZON = TASK.config.episode.horizon_ticks
INTERVAL = TASK.config.episode.decision_interval
DT = TASK.config.episode.dt


def passes(state: TaskState, rows: np.ndarray, delay: int, now: int, lead: int = 0) -> np.ndarray:
    """Whether the fast drive begun after ``delay`` ticks of a closed throttle takes the ego of
    ``rows`` past its certified zone with no collision, no safety action and before the
    episode's end (tick ``now`` of ``HORIZON``); other rows get True. With ``lead``, the fast
    drive first drives ``lead`` ticks before the throttle closes (drive, coast, then go). Each
    action is held from one decision to the next, as the scene holds the learned one."""

    def act(current: TaskState, tick: int) -> np.ndarray:
        closed = np.full(current.batch_size, -1.0)
        driving = tick < lead or tick >= lead + delay
        return DRIVE.action(current, tick) if driving else closed

    ok = np.ones(state.batch_size, dtype=bool)
    reached = np.zeros(state.batch_size, dtype=bool)
    reached[np.setdiff1d(np.arange(state.batch_size), rows)] = True
    sim, index = state.take(rows), rows.copy()
    held = act(sim, 0)
    for tick in range(HORIZON - now):
        if index.size == 0:
            break
        if (now + tick) % INTERVAL == 0:
            held = act(sim, tick)
        inside = sim.world.progress[:, 0] <= EXIT
        sim, record = CHECK.step(sim, held, observe=False)
        ok[index[inside & (record.safety_active | record.collision)]] = False
        past = sim.world.progress[:, 0] > EXIT
        reached[index[past]] = True
        keep = np.flatnonzero(ok[index] & ~past)
        index, sim, held = index[keep], sim.take(keep), held[keep]
    return ok & reached


class Rule:
    """The planner, overruled by the exact go check and (``delays``) the coast-then-go one;
    with ``keep_going``, the fast drive also wherever driving it for one more decision still
    leaves a coast-then-go drive that gets through (drive, coast, then go)."""

    def __init__(self, delays: list[float], keep_going: bool = False) -> None:
        self.delays, self.base, self.keep_going = delays, Planner(TASK), keep_going
        self.go: np.ndarray | None = None
        self.coast: np.ndarray | None = None

    def __call__(self, obs: np.ndarray, state: TaskState, tick: int) -> np.ndarray:
        base = self.base(obs, state, tick)
        size = state.batch_size
        if tick % INTERVAL == 0 or self.go is None or self.go.shape[0] != size:
            rows = np.flatnonzero(state.world.progress[:, 0] <= ENTRY)
            self.go, self.coast = np.zeros(size, bool), np.zeros(size, bool)
            if rows.size:
                now = passes(state, rows, 0, tick)
                self.go[rows] = now[rows]
                left = rows[~now[rows]]
                for delay in self.delays if self.keep_going else ():
                    if left.size == 0:
                        break
                    later = passes(state, left, round(delay / DT), tick, lead=INTERVAL)
                    self.go[left[later[left]]] = True
                    left = left[~later[left]]
                for delay in self.delays:
                    if left.size == 0:
                        break
                    later = passes(state, left, round(delay / DT), tick)
                    self.coast[left[later[left]]] = True
                    left = left[~later[left]]
        fast = DRIVE.to_scene(DRIVE.action(state, tick))
        closed = DRIVE.to_scene(np.full(size, -1.0))
        assert self.coast is not None
        return np.where(self.go, fast, np.where(self.coast, closed, base))


def main() -> None:
    delays = [float(a) for a in sys.argv[1:]] or list(np.arange(1, 29) * 0.25)
    ((_, scenes),) = scenario_chunks(TASK, "random", 1000, 1_000_003)
    rules = [("planner", Planner(TASK)), ("planner + exact go check", Rule([])),
             ("planner + exact go check + coast-then-go checks", Rule(delays)),
             ("… + drive while a drive-coast-go check passes",
              Rule(delays, keep_going=True))]  # fmt: skip
    score_rules(TASK, rules, scenes)


if __name__ == "__main__":
    main()
