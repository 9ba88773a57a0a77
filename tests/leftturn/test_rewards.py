from dataclasses import replace

import numpy as np
import pytest

from safeswitch.leftturn.config import LeftTurnConfig, RewardConfig
from safeswitch.leftturn.rewards import (
    accel_lat_reward,
    accel_lon_reward,
    adas_reward,
    lane_keeping_reward,
    speed_reward,
)
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.task import LeftTurnTask

from .conftest import cruise_action

R = RewardConfig()


@pytest.mark.parametrize(
    ("kmh", "expected"),
    [
        (0, -1),
        (2.5, -0.5),
        (5, 0),
        (15, 0.5),
        (25, 1),
        (28, 1),
        (30, 1),
        (32.5, 0.5),
        (35, 0),
        (40, -0.5),
        (45, -1),
        (80, -1),
    ],
)
def test_speed_reward_breakpoints(kmh, expected):
    assert speed_reward(R, np.array(kmh / 3.6)) == pytest.approx(expected)


@pytest.mark.parametrize(("x", "expected"), [(0, 1), (0.75, 0.5), (1.5, 0), (3, -1), (9, -1)])
def test_lane_keeping_reward_is_symmetric_with_zero_at_the_tolerance(x, expected):
    assert lane_keeping_reward(R, np.array([x, -x])) == pytest.approx([expected, expected])


@pytest.mark.parametrize(
    ("a", "lon", "lat"),
    [(0, 1, 1), (3, 0.4, 0), (3.75, 0.25, -1), (5, 0, -2), (5.75, -1, -2), (10, -2, -2)],
)
def test_acceleration_rewards_are_zero_at_their_comfort_limits(a, lon, lat):
    for sign in (1, -1):
        assert accel_lon_reward(R, np.array(sign * a)) == pytest.approx(lon)
        assert accel_lat_reward(R, np.array(sign * a)) == pytest.approx(lat)


def test_adas_reward_is_eq4_and_can_be_switched_off():
    active = np.array([True, False])
    np.testing.assert_array_equal(adas_reward(R, active), [-25.0, 0.0])
    np.testing.assert_array_equal(adas_reward(R, active, enabled=False), [0.0, 0.0])


def test_a_fast_safe_crossing_earns_more_than_a_slow_one():
    """No reward for dawdling (SPEC §2): the fixed horizon makes speed pay."""
    config = LeftTurnConfig(switching="none")
    config = replace(config, episode=replace(config.episode, learned_scope="episode"))
    task = LeftTurnTask(config)
    # North car far away: both crossings are safe.
    scenarios = Scenarios(
        *(np.array([v, v]) for v in (36.0, 25 / 3.6, 8.0)), arrival_offset=np.array([8.0, 8.0])
    )
    state = task.initial(scenarios)
    targets = np.array([25.0, 12.0]) / 3.6  # fast, slow
    returns, cleared = np.zeros(2), np.full(2, np.nan)
    for tick in range(config.episode.horizon_ticks):
        state, record = task.step(state, cruise_action(record_speed(state), targets))
        assert not record.collision.any()
        returns += record.reward
        cleared = np.where(np.isnan(cleared) & record.ego_cleared, tick, cleared)
    assert cleared[0] < cleared[1]  # the fast one really crosses sooner
    assert returns[0] > returns[1] + 100


def record_speed(state):
    return state.world.vehicles.speed[:, 0]


def test_the_compiled_interpolation_is_np_interp_bit_for_bit():
    config = RewardConfig()
    rng = np.random.default_rng(2)
    speed = np.concatenate([rng.uniform(-1, 17, 100_000), np.array(config.speed_points_kmh) / 3.6])
    expected = np.interp(speed * 3.6, config.speed_points_kmh, config.speed_values)
    np.testing.assert_array_equal(speed_reward(config, speed), expected)
    lateral = np.concatenate([rng.uniform(-4, 4, 100_000), config.lateral_points_m])
    expected = np.interp(np.abs(lateral), config.lateral_points_m, config.lateral_values)
    np.testing.assert_array_equal(lane_keeping_reward(config, lateral), expected)
