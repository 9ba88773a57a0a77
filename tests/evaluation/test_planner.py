"""The planner: a throttle-only controller that never needs the paper logic's Safety controller."""

from dataclasses import replace

import numpy as np
import pytest

from safeswitch.app.evaluate import controller_setup
from safeswitch.core.config import ConfigError
from safeswitch.evaluation.evaluate import run_controller, scenario_set
from safeswitch.evaluation.planner import Planner, PlannerConfig
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.task import OUTCOMES, LeftTurnTask

EPISODES = 200


@pytest.fixture(scope="module")
def setup():
    config, planner = controller_setup("planner", None, None)
    return LeftTurnTask(config), planner


@pytest.fixture(scope="module")
def random_run(setup):
    task, planner = setup
    scenarios, _ = scenario_set(task, "random", EPISODES, 31)
    actions = []

    def record(obs, state, tick):
        a = planner(obs, state, tick)
        actions.append(a)
        return a

    return rollout(task, scenarios, record), np.concatenate(actions)


def test_it_drives_with_the_learned_controller_under_the_paper_logic(setup):
    task, _ = setup
    assert task.config.switching == "paper"
    assert task.config.episode.learned_scope == "episode"


def test_it_never_needs_the_safety_controller_and_keeps_the_comfort_limits(random_run):
    result, actions = random_run
    assert not result.collision.any()
    assert result.safety_steps.sum() == 0
    assert result.comfort_violation_steps.sum() == 0
    assert np.all(np.abs(actions) <= 1.0) and np.all(np.isfinite(actions))
    # not by standing still: it crosses in every scenario, both first and second
    assert np.isfinite(result.time_to_clear).all()
    assert (result.outcome == OUTCOMES.index("cut")).sum() > 0.1 * EPISODES
    assert (result.outcome == OUTCOMES.index("yield")).sum() > 0.1 * EPISODES


def test_it_is_faster_than_the_rule_based_system_when_it_yields_without_stopping(setup, random_run):
    task, _ = setup
    result, _ = random_run
    assert result.min_speed.min() > 0.1  # no full stop anywhere
    rule_config, rule = controller_setup("rule", None, None)
    scenarios, _ = scenario_set(task, "random", EPISODES, 31)
    rule_result, _ = run_controller(LeftTurnTask(rule_config), rule, scenarios)
    both_yield = (result.outcome == OUTCOMES.index("yield")) & (
        rule_result.outcome == OUTCOMES.index("yield")
    )
    assert both_yield.sum() > 20
    horizon = task.config.episode.horizon_s  # an episode that never clears counts whole
    rule_time = np.where(np.isfinite(rule_result.time_to_clear), rule_result.time_to_clear, horizon)
    assert result.time_to_clear[both_yield].mean() < rule_time[both_yield].mean()


@pytest.mark.slow
def test_the_paper_scenarios(setup):
    task, planner = setup
    scenarios, names = scenario_set(task, "paper", 3, 0)
    result = rollout(task, scenarios, planner)
    outcome = dict(zip(names, (OUTCOMES[int(o)] for o in result.outcome), strict=True))
    assert outcome == {"cut": "cut", "yield1": "yield", "yield2": "yield"}
    assert result.safety_steps.sum() == 0


def test_without_its_pass_first_margin_the_check_is_what_keeps_it_safe(setup):
    """The pass-first check matters: a planner that always passes first (check disabled by an
    impossible margin the other way round — it never yields) needs the Safety controller."""
    task, _ = setup
    scenarios, _ = scenario_set(task, "random", EPISODES, 31)

    class AlwaysFirst(Planner):
        def passes_first(self, state):
            return np.ones(state.batch_size, dtype=bool)

    reckless = rollout(task, scenarios, AlwaysFirst(task))
    assert (reckless.safety_steps > 0).sum() > 0.1 * EPISODES


@pytest.mark.slow
def test_arriving_slowly_at_the_firing_point_clears_sooner(setup):
    """The firing distance grows with v²: a yield that reaches it at 4 m/s waits closer to the
    zone than one arriving at the turn's speed (~6.8 m/s) and clears it sooner."""
    task, planner = setup
    scenarios, _ = scenario_set(task, "random", EPISODES, 31)
    slow = rollout(task, scenarios, planner)
    fast = rollout(task, scenarios, Planner(task, replace(planner.config, yield_speed=6.8)))
    yields = OUTCOMES.index("yield")
    both = (slow.outcome == yields) & (fast.outcome == yields)
    assert both.sum() > 0.3 * EPISODES
    assert fast.safety_steps.sum() == 0
    gain = fast.time_to_clear[both] - slow.time_to_clear[both]
    assert gain.mean() > 0.1
    assert np.mean(gain > 0) > 0.9


def test_once_in_its_conflict_zone_it_drives_on(setup):
    """A yield can only be planned before the zone: a car that is already in it (a cloned
    policy after a hesitation) is told to leave it at speed, not to brake there."""
    task, planner = setup
    scenarios, _ = scenario_set(task, "random", 50, 31)

    class NeverFirst(Planner):
        def passes_first(self, state):
            return np.zeros(state.batch_size, dtype=bool)

    never = NeverFirst(task, planner.config)
    entry, north_exit = task.conflict.zone_a[0], task.conflict.zone_b[1]
    inside, before = [], []

    def full_throttle(obs, state, tick):
        w = state.world
        s, s_n, v = w.progress[:, 0], w.progress[:, 1], w.vehicles.speed[:, 0]
        target, fast = never.target_speed(state, tick), never._fast(s, v)
        waiting = s_n <= north_exit
        inside.append((target - fast)[waiting & (s > entry)])
        before.append((target - fast)[waiting & (s < entry - 5.0)])
        return np.ones(state.batch_size)

    rollout(task, scenarios, full_throttle)
    inside_gap, before_gap = np.concatenate(inside), np.concatenate(before)
    assert inside_gap.size > 100 and np.all(inside_gap == 0.0)
    assert np.mean(before_gap < -0.5) > 0.5  # before the zone it does yield


def test_a_bad_planner_setting_is_named():
    with pytest.raises(ConfigError, match="accel_lat"):
        PlannerConfig(accel_lat=-1.0)
    with pytest.raises(ConfigError, match="recheck_ticks"):
        replace(PlannerConfig(), recheck_ticks=0)
    with pytest.raises(ConfigError, match="yield_speed"):
        PlannerConfig(yield_speed=float("nan"))
