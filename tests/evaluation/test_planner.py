"""The planner: a throttle-only controller that never needs the paper logic's Safety controller."""

from dataclasses import replace

import numpy as np
import pytest

from safeswitch.core.config import ConfigError
from safeswitch.evaluation.evaluate import controller_setup, run_controller, scenario_set
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


def test_a_bad_planner_setting_is_named():
    with pytest.raises(ConfigError, match="accel_lat"):
        PlannerConfig(accel_lat=-1.0)
    with pytest.raises(ConfigError, match="recheck_ticks"):
        replace(PlannerConfig(), recheck_ticks=0)
