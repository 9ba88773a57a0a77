"""The oracle: within its limits, and never slower than anything that keeps to the same limits."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from safeswitch.evaluation.evaluate import scenario_set
from safeswitch.evaluation.metrics import FASTER_MARGIN_S, summarize
from safeswitch.evaluation.oracle import Oracle, efficiency
from safeswitch.evaluation.planner import Planner
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.scenarios import named_scenarios
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.training.policies import load_policy
from tests.leftturn.conftest import cruise_action

EPISODES = 300


@pytest.fixture(scope="module")
def oracle():
    return Oracle(LeftTurnTask(LeftTurnConfig()))


@pytest.fixture(scope="module")
def random_plan(oracle):
    scenarios, _ = scenario_set(oracle.task, "random", EPISODES, 77)
    return scenarios, oracle.plan(scenarios)


def shares_zone(task, ego, north):
    a, b = task.conflict.zone_a, task.conflict.zone_b
    return np.any((ego >= a[0]) & (ego <= a[1]) & (north >= b[0]) & (north <= b[1]), axis=-1)


def assert_within_limits(oracle, plan):
    lim = oracle.limits
    assert np.all(plan.speed >= 0.0)
    assert plan.speed.max() <= lim.max_speed + 1e-9
    assert np.abs(plan.accel_lon).max() <= lim.accel_lon + 1e-9
    assert np.abs(plan.accel_lat).max() <= lim.accel_lat + 1e-6
    assert not shares_zone(oracle.task, plan.progress, plan.north_progress).any()
    assert plan.separation.min() > 0.0


def test_the_oracle_keeps_every_limit_on_random_scenarios(oracle, random_plan):
    _, plan = random_plan
    assert_within_limits(oracle, plan)
    assert np.isfinite(plan.time_to_clear).all()
    # Both ways of crossing occur, and the plan passes first exactly when it clears first.
    assert {1, 2} <= set(plan.outcome.tolist())


@settings(max_examples=10, deadline=None)
@given(
    offset=st.floats(-3.0, 5.0),
    north_kmh=st.floats(20.0, 32.0),
    ego_kmh=st.floats(10.0, 25.0),
    distance=st.floats(25.0, 45.0),
)
def test_the_oracle_keeps_every_limit_on_any_scenario(oracle, offset, north_kmh, ego_kmh, distance):
    scenarios = named_scenarios("cut", 1)
    scenarios = replace(
        scenarios,
        arrival_offset=np.array([offset]),
        north_speed=np.array([north_kmh / 3.6]),
        ego_speed=np.array([ego_kmh / 3.6]),
        ego_start_distance=np.array([distance]),
    )
    assert_within_limits(oracle, oracle.plan(scenarios))


@pytest.mark.slow
def test_no_acceleration_sequence_of_the_same_model_beats_the_oracle(oracle, random_plan):
    """Random piecewise-constant accelerations (0.4 s pieces) on the oracle's own point mass:
    every sequence that keeps the limits clears the zone no sooner than the oracle."""
    _, plan = random_plan
    task, lim = oracle.task, oracle.limits
    rng = np.random.default_rng(5)
    start = np.stack([plan.progress[:, 0], plan.speed[:, 0]], axis=1)
    compared = 0
    for _ in range(40):
        pieces = rng.uniform(-lim.max_decel, lim.accel_lon, (EPISODES, 31))
        # Bias half the tries towards the oracle's own shape: hard at the start, fast later.
        pieces[:, :5] *= rng.choice([0.0, 1.0], (EPISODES, 1))
        s, v = oracle.integrate(start, lambda k, s, v, pieces=pieces: pieces[:, k // 20])
        curvature = np.interp(s, oracle._grid, oracle._curvature)
        ok = (
            (v.max(axis=1) <= lim.max_speed)
            & ((v**2 * curvature).max(axis=1) <= lim.accel_lat)
            & ~shares_zone(task, s, plan.north_progress)
        )
        cleared = s > task.conflict.zone_a[1]
        time = np.where(cleared.any(axis=1), np.argmax(cleared, axis=1) * 0.02, np.inf)
        assert np.all(time[ok] >= plan.time_to_clear[ok] - 1e-9)
        compared += int((ok & np.isfinite(time)).sum())
    assert compared >= 500


def cruise(target_kmh):
    def policy(obs, state, tick):
        return cruise_action(obs[:, 2], target=target_kmh / 3.6)

    return policy


@pytest.mark.slow
def test_no_controller_that_keeps_the_limits_is_faster_than_the_oracle(oracle, random_plan):
    scenarios, plan = random_plan
    base = LeftTurnConfig()
    shipped = load_policy("shipped")
    controllers = {
        "rule": ({"switching": "paper", "learned_scope": "never"}, cruise(25)),
        "shipped": ({"switching": "paper", "learned_scope": "episode"}, shipped.as_policy()),
    }
    planner_config = replace(base, episode=replace(base.episode, learned_scope="episode"))
    controllers["planner"] = (
        {"switching": "paper", "learned_scope": "episode"},
        Planner(LeftTurnTask(planner_config)),
    )
    for target in (14, 18, 21):
        for switching in ("paper", "certified"):
            controllers[f"cruise{target}-{switching}"] = (
                {"switching": switching, "learned_scope": "episode"},
                cruise(target),
            )
    compared = 0
    for name, (settings_, policy) in controllers.items():
        config = replace(
            base,
            switching=settings_["switching"],
            episode=replace(base.episode, learned_scope=settings_["learned_scope"]),
        )
        task = LeftTurnTask(config)
        north, ego, top = [], [], np.zeros(EPISODES)

        def watch(state, record, tick, north=north, ego=ego, top=top):
            ego.append(state.world.progress[:, 0].copy())
            north.append(state.world.progress[:, 1].copy())
            np.maximum(top, record.ego_speed, out=top)

        result = rollout(task, scenarios, policy, on_tick=watch)
        kept = (
            ~result.collision
            & (result.comfort_violation_steps == 0)
            & (top <= oracle.limits.max_speed)
            & ~shares_zone(task, np.stack(ego, axis=1), np.stack(north, axis=1))
            & np.isfinite(result.time_to_clear)
        )
        slower = result.time_to_clear[kept] < plan.time_to_clear[kept] - 1e-9
        assert not slower.any(), f"{name} beat the oracle within its limits"
        compared += int(kept.sum())
    assert compared >= EPISODES  # a real comparison, not a vacuous one


def test_the_paper_scenarios_cut_and_yield_as_named(oracle):
    batch, names = scenario_set(oracle.task, "paper", 3, 0)
    plan = oracle.plan(batch)
    assert dict(zip(names, plan.outcome.tolist(), strict=True)) == {
        "cut": 1,
        "yield1": 2,
        "yield2": 2,
    }
    # Yielding costs time: the later the north car, the later the ego clears behind it.
    assert plan.time_to_clear[0] < plan.time_to_clear[1] < plan.time_to_clear[2]
    again = oracle.plan(batch)
    np.testing.assert_array_equal(again.progress, plan.progress)


def test_efficiency_counts_a_never_cleared_episode_as_the_whole_horizon():
    ratio = efficiency(np.array([6.0, 6.0, np.nan]), np.array([8.0, np.nan, 7.0]), 12.0)
    np.testing.assert_allclose(ratio[:2], [0.75, 0.5])
    assert np.isnan(ratio[2])


def test_the_summary_counts_speeding_and_every_episode_faster_than_the_oracle(oracle, random_plan):
    """A cruise to 40 km/h (without a switching logic) speeds in most episodes and beats the
    oracle where it cuts: the summary counts both as the ticks themselves show, and here each
    episode faster than the oracle broke its speed or comfort limits. The oracle itself never
    speeds."""
    scenarios, plan = random_plan
    base = LeftTurnConfig()
    config = replace(base, switching="none",
                     episode=replace(base.episode, learned_scope="episode"))  # fmt: skip
    tolerated = base.rewards.tolerated_speed
    assert tolerated == pytest.approx(30.0 / 3.6) == pytest.approx(oracle.limits.max_speed)
    top, fast_ticks = np.zeros(EPISODES), np.zeros(EPISODES, dtype=np.int64)

    def watch(state, record, tick):
        np.maximum(top, record.ego_speed, out=top)
        fast_ticks[:] += record.ego_speed > tolerated + 0.1 / 3.6  # by more than 0.1 km/h

    result = rollout(LeftTurnTask(config), scenarios, cruise(40), on_tick=watch)
    horizon = base.episode.horizon_s
    summary = summarize(result, plan.time_to_clear, horizon)
    whole = ~result.collision  # a collision ends the episode; the watch sees every tick
    assert whole.sum() >= EPISODES // 2
    np.testing.assert_array_equal(result.speeding_steps[whole], fast_ticks[whole])
    np.testing.assert_allclose(result.max_speed[whole], top[whole])
    assert summary["speeding_episodes"] == int((result.speeding_steps > 0).sum()) > EPISODES // 2
    assert summary["speeding_steps"] == int(result.speeding_steps.sum())
    assert summary["max_speed_kmh"] == pytest.approx(3.6 * result.max_speed.max())
    faster = result.time_to_clear < plan.time_to_clear - FASTER_MARGIN_S
    assert summary["faster_than_oracle_episodes"] == int(faster.sum()) > 0
    broke = (result.speeding_steps > 0) | (result.comfort_violation_steps > 0)
    assert broke[faster].all()
    own = summarize(oracle.as_rollout(plan), plan.time_to_clear, horizon)
    assert own["speeding_episodes"] == own["faster_than_oracle_episodes"] == 0
    assert own["max_speed_kmh"] <= 30.0 + 1e-6


def test_faster_than_the_oracle_means_by_more_than_two_ticks(oracle, random_plan):
    """Clearing times are read in whole ticks: the oracle's own episodes two ticks sooner are
    within the margin a controller keeping every limit can reach, three ticks sooner are not."""
    _, plan = random_plan
    own = oracle.as_rollout(plan)
    horizon = oracle.task.config.episode.horizon_s
    dt = oracle.task.config.episode.dt
    assert 2 * dt < FASTER_MARGIN_S < 3 * dt
    cleared = int(np.isfinite(plan.time_to_clear).sum())
    for ticks, counted in ((0, 0), (2, 0), (3, cleared)):
        sooner = replace(own, time_to_clear=plan.time_to_clear - ticks * dt)
        summary = summarize(sooner, plan.time_to_clear, horizon)
        assert summary["faster_than_oracle_episodes"] == counted, ticks
