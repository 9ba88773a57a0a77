"""The logic-aware limit: a lower bound on the time to clear of every controller that never
triggers the paper switching logic."""

import numpy as np
import pytest

from safeswitch.app.evaluate import controller_setup
from safeswitch.core.config import ConfigError
from safeswitch.evaluation.evaluate import scenario_set
from safeswitch.evaluation.logic_limit import PaperLogicLimit
from safeswitch.evaluation.oracle import Oracle
from safeswitch.evaluation.planner import Planner, PlannerConfig
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.spaces import speed_tracking_action
from safeswitch.leftturn.task import LeftTurnTask

EPISODES = 40


@pytest.fixture(scope="module")
def setup():
    config, _ = controller_setup("planner", None, None)  # the paper logic, learned throughout
    task = LeftTurnTask(config)
    scenarios, _ = scenario_set(task, "random", EPISODES, 57)
    return task, scenarios, Oracle(task).plan(scenarios).time_to_clear


@pytest.fixture(scope="module")
def bounds(setup):
    task, scenarios, _ = setup
    return {
        (braking, logic): PaperLogicLimit(task, braking=braking, logic=logic).times(scenarios)
        for braking, logic in (("comfort", False), ("comfort", True), ("throttle", True))
    }


@pytest.mark.slow
def test_without_the_logic_it_is_the_oracle_up_to_the_grid(setup, bounds):
    _, _, oracle = setup
    free = bounds["comfort", False]
    assert np.isfinite(free).all()
    assert np.all(free <= oracle + 1e-9)  # a relaxation: never slower than the exact plan
    assert np.mean(oracle - free) < 0.05  # and a tight one


@pytest.mark.slow
def test_the_logic_costs_time_and_a_closed_throttle_more(setup, bounds):
    _, _, oracle = setup
    free, paper, throttle = (
        bounds["comfort", False],
        bounds["comfort", True],
        bounds["throttle", True],
    )
    assert np.all(paper >= free) and np.all(throttle >= paper)
    # the logic fires on most of the oracle's plans (benchmarks/planner_gap.py): it must bite
    assert np.mean(paper - oracle) > 0.3
    assert np.sum(paper > oracle + 0.5) > EPISODES // 4


@pytest.mark.slow
def test_no_controller_that_never_triggers_the_logic_clears_sooner(setup, bounds):
    """Three planners and speed trackers (targets below the turn's comfort speed) on the same
    scenarios: every episode without a safety action, comfort violation or speeding clears no
    sooner than the bound — and some come close to it, so the bound is not vacuous."""
    task, scenarios, _ = setup
    limit = PaperLogicLimit(task, braking="throttle")
    v_max = limit.oracle.limits.max_speed
    assert v_max <= limit.top_speed < v_max + 0.01
    planners = [
        PlannerConfig(),
        PlannerConfig(top_speed_kmh=27.0, curve_decel=1.5),
        PlannerConfig(top_speed_kmh=25.0, accel_lat=2.5, yield_speed=5.5),
    ]
    rng = np.random.default_rng(3)
    targets = rng.uniform(1.5, 5.7, 2 * EPISODES)
    vehicle = task.config.vehicle
    drivers = [Planner(task, c) for c in planners]
    drivers.append(
        lambda obs, state, tick: speed_tracking_action(
            vehicle, targets, state.world.vehicles.speed[:, 0], 1.0
        )
    )
    times, clean, bound = [], [], []
    for driver in drivers:
        rows = np.arange(EPISODES) if driver is not drivers[-1] else np.tile(np.arange(EPISODES), 2)
        top = np.zeros(rows.size)

        def watch(state, record, tick, top=top):
            np.maximum(top, state.world.vehicles.speed[:, 0], out=top)

        result = rollout(task, scenarios.take(rows), driver, on_tick=watch)
        times.append(result.time_to_clear)
        bound.append(bounds["throttle", True][rows])
        clean.append(
            (result.safety_steps == 0)
            & (result.comfort_violation_steps == 0)
            & (top <= limit.top_speed)
            & np.isfinite(result.time_to_clear)
        )
    assert clean[0].all()  # the default planner never needs the Safety controller
    time, ok, low = np.concatenate(times), np.concatenate(clean), np.concatenate(bound)
    assert ok.sum() > 3 * EPISODES
    assert np.all(time[ok] >= low[ok] - 1e-9)
    assert np.min(time[ok] - low[ok]) < 0.3


# -- in traffic: every conflict at once ----------------------------------------------------


@pytest.fixture(scope="module")
def traffic():
    """Light traffic whose drivers never give way to the ego, so the others' world does not
    depend on what the ego does and the bound holds episode by episode."""
    task = build_task(
        None,
        {"episode": {"learned_scope": "episode"}},
        traffic={"preset": "light", "horizon_s": 20.0, "non_yielding_share": (1.0, 1.0)},
        switching="paper",
    )
    scenarios = task.draw_scenarios(5, np.arange(EPISODES), np.zeros(EPISODES, dtype=np.int64))
    timeline = task.conflict_timeline(scenarios)
    free = PaperLogicLimit(task, logic=False)
    return {
        "task": task,
        "scenarios": scenarios,
        "timeline": timeline,
        "oracle": Oracle(task).plan(scenarios, full=False).time_to_clear,
        "free": free.bound(timeline),
        "paper": PaperLogicLimit(task).bound(timeline),
        "throttle": PaperLogicLimit(task, braking="throttle").bound(timeline),
    }


@pytest.mark.slow
def test_in_traffic_the_bound_without_the_logic_is_below_the_multi_conflict_oracle(traffic):
    """The oracle is one feasible plan (brake, then drive) around every occupied zone; the
    reachable set knows every plan, so it is never slower, and mostly within the grid."""
    oracle, free = traffic["oracle"], traffic["free"]
    assert np.isfinite(oracle).mean() > 0.9
    assert np.isfinite(free[np.isfinite(oracle)]).all()
    both = np.isfinite(oracle)
    assert np.all(free[both] <= oracle[both] + 1e-9)
    assert np.median(oracle[both] - free[both]) < 0.05


@pytest.mark.slow
def test_in_traffic_every_conflicting_vehicle_counts(traffic):
    """Against the north car alone the bound is never later, and in some scenes it is
    earlier: the other vehicles' zones and their Algorithm 1 are in the bound."""
    task, timeline = traffic["task"], traffic["timeline"]
    north = np.zeros(timeline.present.shape[-1], dtype=bool)
    north[0] = True
    alone = PaperLogicLimit(task).bound(timeline._replace(present=timeline.present & north))
    full = traffic["paper"]
    fin = np.isfinite(full)
    assert np.all(alone[fin] <= full[fin] + 1e-9)
    assert np.sum(alone[fin] < full[fin] - 0.1) >= 2
    assert np.all(full[fin] >= traffic["free"][fin])
    assert np.all(traffic["throttle"][fin] >= full[fin] - 1e-9)


@pytest.mark.slow
def test_in_traffic_no_controller_that_never_triggers_the_logic_clears_sooner(traffic):
    """Speed trackers and the planner in the same scenes: every episode without a safety
    action, comfort violation, speeding or collision clears no sooner than the bound."""
    task, scenarios, bound = traffic["task"], traffic["scenarios"], traffic["throttle"]
    top_speed = PaperLogicLimit(task, braking="throttle").top_speed
    rows = np.tile(np.arange(EPISODES), 4)
    targets = np.random.default_rng(3).uniform(1.5, 5.7, rows.size)
    vehicle = task.config.vehicle
    drivers = [
        (np.arange(EPISODES), Planner(task, PlannerConfig())),
        (
            rows,
            lambda obs, state, tick: speed_tracking_action(
                vehicle, targets, state.world.vehicles.speed[:, 0], 1.0
            ),
        ),
    ]
    margins = []
    for picked, driver in drivers:
        top = np.zeros(picked.size)

        def watch(state, record, tick, top=top):
            np.maximum(top, state.world.vehicles.speed[:, 0], out=top)

        result = rollout(task, scenarios.take(picked), driver, on_tick=watch)
        clean = (
            (result.safety_steps == 0)
            & (result.comfort_violation_steps == 0)
            & (result.collision == 0)
            & (top <= top_speed)
            & np.isfinite(result.time_to_clear)
        )
        assert clean.sum() >= 10
        margins.append(result.time_to_clear[clean] - bound[picked][clean])
    margin = np.concatenate(margins)
    assert np.all(margin >= -1e-9)
    assert margin.min() < 0.3


@pytest.mark.slow
def test_bad_settings_are_named(setup):
    task, _, _ = setup
    with pytest.raises(ConfigError, match="braking"):
        PaperLogicLimit(task, braking="hard")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="speed_step"):
        PaperLogicLimit(task, speed_step=0.0)


@pytest.mark.slow
def test_clearing_into_a_zone_about_to_be_occupied_does_not_count(setup):
    """A second conflict zone just past the north car's, occupied from shortly after the ego
    could first clear: clearing then would leave the ego inside it, so the bound moves later.
    Occupied only long after the ego is through, it changes nothing."""
    task, scenarios, _ = setup
    limit = PaperLogicLimit(task, logic=False)
    base = task.conflict_timeline(scenarios)
    free = limit.bound(base)
    clear_at = task.conflict.zone_a[1]
    dt = task.config.episode.dt
    batch, ticks, _ = base.present.shape

    def with_zone(start_after: int):
        inside = np.zeros((batch, ticks, 1), dtype=bool)
        for b in range(batch):
            first = round(free[b] / dt) + start_after
            inside[b, first : first + 150] = True
        extra = {
            "present": np.ones((batch, ticks, 1), dtype=bool),
            "ego_entry": np.full((batch, ticks, 1), clear_at + 0.5),
            "ego_exit": np.full((batch, ticks, 1), clear_at + 8.0),
            "ego_point": np.full((batch, ticks, 1), clear_at + 4.0),
            "other_distance": np.full((batch, ticks, 1), 100.0),
            "other_inside": inside,
            "other_window": np.zeros((batch, ticks, 1), dtype=bool),
            "other_speed": np.zeros((batch, ticks, 1)),
        }
        fields = {k: np.concatenate([getattr(base, k), v], axis=2) for k, v in extra.items()}
        return limit.bound(base._replace(**fields))

    soon, late = with_zone(10), with_zone(400)
    assert np.all(soon > free + 0.1)
    assert np.array_equal(late, free)
