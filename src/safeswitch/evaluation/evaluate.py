"""Evaluation building blocks: scenario sets, the rule-based baselines and the oracle, one
episode per scenario, summaries against the oracle and the per-episode CSV.

``safeswitch evaluate`` (:mod:`safeswitch.app.evaluate`) puts them together with trained
policies.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from safeswitch.core.arrays import concat_rows
from safeswitch.evaluation.metrics import summarize
from safeswitch.evaluation.oracle import Oracle, OraclePlan
from safeswitch.evaluation.planner import Planner
from safeswitch.evaluation.rollout import Policy, RolloutResult, rollout
from safeswitch.evaluation.traffic_planner import UnboundGapPlanner
from safeswitch.leftturn.config import SCENARIO_NAMES, LearnedScope, LeftTurnConfig
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.task import LeftTurnTask, StepRecord, TaskState
from safeswitch.sim.geometry import FloatArray

#: Scenarios simulated at once by a streaming evaluation (memory stays bounded whatever the
#: number of episodes).
CHUNK = 4096

#: The rule-based controllers and the oracle (``safeswitch evaluate --controller``).
BASELINES: tuple[str, ...] = ("rule", "planner", "gap_planner", "oracle")


def _rule_policy(obs: Any, state: Any, tick: int) -> Any:
    return np.zeros(obs.shape[0])  # ignored: learned_scope="never" lets PID_th drive


def scenario_set(
    task: LeftTurnTask, which: str, episodes: int, seed: int
) -> tuple[Scenarios, list[str]]:
    """The paper's three scenarios, or ``episodes`` random ones drawn with ``seed``."""
    if which == "paper":
        # in traffic: the paper's cars among others, drawn with ``seed``
        parts = [task.named(name, 1, seed) for name in SCENARIO_NAMES]
        return concat_rows(parts), list(SCENARIO_NAMES)
    if which != "random":
        raise ValueError(f"--scenarios must be 'paper' or 'random', got {which!r}")
    if episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {episodes}")
    scenarios = task.scenario_set(seed, episodes)
    return scenarios, [f"random-{i}" for i in range(episodes)]


def baseline_setup(
    controller: str, switching: str | None = None
) -> tuple[LeftTurnConfig, Policy | None]:
    """The task configuration and policy of a rule-based controller: ``rule`` (``PID_th``
    proposes throughout), ``planner`` (drives with the learned controller's throttle
    throughout), ``gap_planner`` (the same, in traffic; unbound until its task is built:
    :func:`~safeswitch.app.evaluate.fit_observations` binds it) or ``oracle`` (plans instead of
    acting: the policy is ``None``), under the ``paper`` logic (``certified`` for the gap
    planner) unless ``switching`` names another."""
    if controller not in BASELINES:
        raise ValueError(f"controller {controller!r} is not one of {', '.join(BASELINES)}")
    scope: LearnedScope = "episode" if controller in ("planner", "gap_planner") else "never"
    default = "certified" if controller == "gap_planner" else "paper"
    env_config = replace(LeftTurnConfig(), switching=switching or default)
    env_config = replace(env_config, episode=replace(env_config.episode, learned_scope=scope))
    policy: Policy | None = None
    if controller == "planner":
        policy = Planner(LeftTurnTask(env_config))
    elif controller == "gap_planner":
        policy = UnboundGapPlanner()
    elif controller == "rule":
        policy = _rule_policy
    return replace(env_config, scenario=None), policy


def run_controller(
    task: LeftTurnTask,
    policy: Policy | None,
    batch: Scenarios,
    on_tick: Callable[[TaskState, StepRecord, int], None] | None = None,
    plan: OraclePlan | None = None,
    trace: bool = True,
) -> tuple[RolloutResult, OraclePlan]:
    """One episode per scenario (the oracle's plan when ``policy`` is None), and the oracle's
    plan of the same scenarios (``plan``, if already made for this road and these scenarios).
    The oracle reuses the rollout's north car (it never reacts to the ego) instead of
    simulating it again; ``trace=False`` keeps only its times to clear and outcomes (no
    per-tick arrays: what an evaluation's summary needs)."""
    oracle = Oracle(task) if plan is None or policy is None else None
    if policy is None:
        assert oracle is not None
        if plan is None or plan.progress.shape[1] == 0:  # the rollout needs every tick
            plan = oracle.plan(batch)
        return oracle.as_rollout(plan), plan
    north: list[FloatArray] = [task.initial(batch).world.progress[:, 1].copy()]

    def record(state: TaskState, step: StepRecord, tick: int) -> None:
        north.append(state.world.progress[:, 1].copy())
        if on_tick is not None:
            on_tick(state, step, tick)

    result = rollout(task, batch, policy, record)
    if plan is None:
        assert oracle is not None
        complete = len(north) == task.config.episode.horizon_ticks + 1
        plan = oracle.plan(batch, np.stack(north, axis=1) if complete else None, full=trace)
    return result, plan


def summary_against_oracle(
    result: RolloutResult, plan: OraclePlan, horizon_s: float
) -> dict[str, Any]:
    """:func:`~safeswitch.evaluation.metrics.summarize` with the oracle's plan of the same
    scenarios: its mean time to clear and ``mean_efficiency`` (the mean over scenarios of the
    oracle's time to clear divided by the controller's, see
    :func:`~safeswitch.evaluation.oracle.efficiency`)."""
    return summarize(result, plan.time_to_clear, horizon_s)


def scenario_chunks(
    task: LeftTurnTask, which: str, episodes: int, seed: int, chunk: int = CHUNK
) -> Iterator[tuple[list[str], Scenarios]]:
    """:func:`scenario_set` in chunks of at most ``chunk`` scenarios (the same scenarios in
    the same order: random scenario ``i`` is a pure function of ``(seed, i)``)."""
    if which == "paper":
        scenarios, names = scenario_set(task, which, episodes, seed)
        yield names, scenarios
        return
    if which != "random":
        raise ValueError(f"--scenarios must be 'paper' or 'random', got {which!r}")
    if episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {episodes}")
    for start in range(0, episodes, chunk):
        ids = np.arange(start, min(start + chunk, episodes))
        scenarios = task.draw_scenarios(seed, ids, np.zeros(ids.size, dtype=int))
        yield [f"random-{i}" for i in ids], scenarios


#: An episode's outcome in ``episodes.csv``, by the task's outcome code at its end: the ego
#: never cleared its conflict zone, cleared it before the north car left its own, or after.
EPISODE_OUTCOMES: tuple[str, ...] = ("never_cleared", "cut", "yield")

#: Columns of ``episodes.csv`` (a never-cleared episode has an empty ``time_to_clear_s``).
CSV_COLUMNS = (
    "episode",
    "ego_start_distance_m",
    "ego_speed_kmh",
    "north_speed_kmh",
    "arrival_offset_s",
    "collision",
    "lost_control",
    "safety_steps",
    "min_speed_kmh",
    "max_speed_kmh",
    "speeding_steps",
    "time_to_clear_s",
    "outcome",
    "comfort_violation_steps",
    "max_accel_lon",
    "max_accel_lat",
    "max_lateral_m",
    "return",
    "oracle_time_to_clear_s",
    "min_ttc_s",
    "min_pet_s",
)


def _number(value: float) -> str:
    return f"{value:.3f}" if np.isfinite(value) else ""


def episode_rows(
    names: list[str], scenarios: Scenarios, result: RolloutResult, oracle_time: FloatArray
) -> Iterator[list[Any]]:
    """One row of :data:`CSV_COLUMNS` per episode."""
    s, r = scenarios, result
    for i, name in enumerate(names):
        yield [
            name,
            _number(s.ego_start_distance[i]),
            _number(s.ego_speed[i] * 3.6),
            _number(s.north_speed[i] * 3.6),
            _number(s.arrival_offset[i]),
            int(r.collision[i]),
            int(r.lost_control[i]),
            int(r.safety_steps[i]),
            _number(r.min_speed[i] * 3.6),
            _number(r.max_speed[i] * 3.6),
            int(r.speeding_steps[i]),
            _number(r.time_to_clear[i]),
            EPISODE_OUTCOMES[int(r.outcome[i])],
            int(r.comfort_violation_steps[i]),
            _number(r.max_accel_lon[i]),
            _number(r.max_accel_lat[i]),
            _number(r.max_lateral[i]),
            _number(r.episode_return[i]),
            _number(oracle_time[i]),
            _number(r.min_ttc[i]),
            _number(r.min_pet[i]),
        ]


def episodes_csv(
    names: list[str], scenarios: Scenarios, result: RolloutResult, oracle_time: FloatArray
) -> str:
    """One row per episode: the scenario, what happened, and the oracle's time to clear."""
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(CSV_COLUMNS)
    writer.writerows(episode_rows(names, scenarios, result, oracle_time))
    return buffer.getvalue()


class EpisodeCSV:
    """``episodes.csv`` written chunk by chunk into a temporary file beside it, renamed into
    place on :meth:`close` (a reader never sees half a file; an interrupted evaluation leaves
    none)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._tmp = path.with_name(f".{path.name}.tmp")
        self._handle = open(self._tmp, "w", newline="", encoding="utf-8")  # noqa: SIM115
        self._writer = csv.writer(self._handle)
        self._writer.writerow(CSV_COLUMNS)

    def write(
        self, names: list[str], scenarios: Scenarios, result: RolloutResult, oracle: FloatArray
    ) -> None:
        self._writer.writerows(episode_rows(names, scenarios, result, oracle))

    def close(self) -> None:
        self._handle.close()
        os.replace(self._tmp, self.path)

    def abandon(self) -> None:
        """Drop the partial file (on an error or an interrupt)."""
        self._handle.close()
        self._tmp.unlink(missing_ok=True)
