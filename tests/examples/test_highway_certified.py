"""The ``certified`` logic on highway-env: its assumptions hold in highway-env's code, each rule
refuses what it should on hand-made states, and adversarial drivers under it never crash."""

import gymnasium as gym
import numpy as np
import pytest

import safeswitch
from safeswitch.core.registry import LogicContextError, make_logic
from safeswitch.examples.highway import (
    OTHER_MAX_BRAKE,
    STATE_COLUMNS,
    TRACKED,
    VEHICLE_COLUMNS,
    highway_state,
)
from safeswitch.examples.highway_certified import (
    CertifiedHighwayController,
    CertifiedHighwayLogic,
    CertifiedRules,
)
from safeswitch.examples.highway_drivers import Adversary, IDMDriver, drive

highway_env = pytest.importorskip("highway_env")

LANES = (0.0, 4.0, 8.0)


def state(speed=25.0, y=4.0, heading=0.0, others=()):
    """One hand-made state row: the ego at ``speed`` on a 3-lane road (centres 0, 4, 8) and
    ``others`` as dicts of :data:`VEHICLE_COLUMNS` (``y_low``/``y_high`` default to ``y``)."""
    centre = min(LANES, key=lambda c: abs(c - y))
    row = [speed, heading, y - centre, y, -1.0, 9.0, 1e3, 1e3]
    for c in LANES:
        row += [c, 1e3, speed]
    block = []
    for other in others:
        o = {"present": 1.0, "max_brake": OTHER_MAX_BRAKE, **other}
        o.setdefault("y_low", o["y"])
        o.setdefault("y_high", o["y"])
        block += [o[name] for name in VEHICLE_COLUMNS]
    block += [0.0] * (TRACKED * len(VEHICLE_COLUMNS) - len(block))
    return np.array([row + block])


def decide(s, action):
    logic = CertifiedHighwayLogic()
    safe = CertifiedHighwayController()(s)
    decision = logic.decide(s, np.array([action], dtype=float), safe)
    return logic.reasons[int(decision.reason[0])]


def test_a_free_road_lets_every_gentle_action_through():
    s = state()
    for action in ([1.0, 0.0], [-1.0, 0.0], [0.0, 0.05], [0.3, -0.05]):
        assert decide(s, action) == "learned"


def test_each_rule_refuses_the_action_that_breaks_it():
    # a slower leader 20 m ahead: full throttle leaves no stopping distance, braking does
    slow_leader = state(others=[{"dx": 25.0, "y": 4.0, "speed": 15.0}])
    assert decide(slow_leader, [1.0, 0.0]) == "leader"
    far_leader = state(others=[{"dx": 80.0, "y": 4.0, "speed": 15.0}])
    assert decide(far_leader, [1.0, 0.0]) == "learned"
    # a fast car 12 m behind in the next lane: steering into that lane is refused, holding
    # the lane is not
    fast_behind = state(others=[{"dx": -17.0, "y": 8.0, "speed": 32.0}])
    assert decide(fast_behind, [0.0, 0.0]) == "learned"
    assert decide(fast_behind, [0.0, 0.15]) == "follower"
    # a car alongside that signals a change into the ego's lane
    merging = state(others=[{"dx": 1.0, "y": 7.0, "speed": 25.0, "y_low": 4.0, "y_high": 8.0}])
    assert decide(merging, [0.0, 0.0]) == "alongside"
    not_merging = state(others=[{"dx": 1.0, "y": 8.0, "speed": 25.0}])
    assert decide(not_merging, [0.0, 0.0]) == "learned"
    # passing a car in the next lane 17 m/s faster (MOBIL may move it in right behind)
    passing = state(speed=31.0, others=[{"dx": 6.0, "y": 8.0, "speed": 14.0}])
    assert decide(passing, [0.5, 0.0]) == "passing"
    assert decide(state(speed=22.0, others=[{"dx": 6.0, "y": 8.0, "speed": 14.0}]), [0.5, 0.0]) == (
        "learned"
    )
    # the road's edge and a heading the lane keeper cannot take back
    assert decide(state(y=8.6, heading=0.1), [0.0, 0.3]) == "off_road"
    assert decide(state(speed=0.5), [-1.0, 0.0]) == "reversing"


def test_a_crashed_leader_counts_as_stopping_within_a_second():
    crashed = {"dx": 45.0, "y": 4.0, "speed": 25.0, "max_brake": 12.5}
    assert decide(state(others=[{**crashed, "max_brake": OTHER_MAX_BRAKE}]), [0.0, 0.0]) == (
        "learned"
    )
    assert decide(state(others=[crashed]), [0.0, 0.0]) == "leader"


def test_the_safety_controller_brakes_for_a_short_envelope_and_before_a_fast_pass():
    controller = CertifiedHighwayController()
    assert controller(state())[0, 0] == 0.0  # holds its speed on a free road
    assert controller(state(others=[{"dx": 20.0, "y": 4.0, "speed": 10.0}]))[0, 0] == -1.0
    assert controller(state(speed=31.0, others=[{"dx": 12.0, "y": 8.0, "speed": 14.0}]))[0, 0] < 0
    assert controller(state(speed=0.0))[0, 0] == 0.0  # never reverses
    # and steers back to the centre of its lane
    assert controller(state(y=5.0))[0, 1] < 0 < controller(state(y=3.0))[0, 1]


def test_the_assumptions_hold_in_highway_envs_code():
    from highway_env.road.lane import AbstractLane
    from highway_env.vehicle.behavior import IDMVehicle

    rules = CertifiedRules()
    assert IDMVehicle.ACC_MAX == OTHER_MAX_BRAKE  # every IDM acceleration is clipped at ±6
    assert rules.follower_max_accel >= IDMVehicle.COMFORT_ACC_MAX  # IDM's free-road term
    assert rules.lane_width == AbstractLane.DEFAULT_WIDTH
    env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching="certified")
    env.reset(seed=0)
    ego, other = env.unwrapped.vehicle, env.unwrapped.road.vehicles[1]
    # MOBIL reads the ego's target speed as 0: the braking it predicts for the ego as a new
    # follower is far beyond what it imposes, so no vehicle changes in front of a moving ego
    assert not hasattr(ego, "target_speed")
    predicted = other.acceleration(ego_vehicle=ego, front_vehicle=other)
    assert predicted < -other.LANE_CHANGE_MAX_BRAKING_IMPOSED
    env.close()


def test_the_state_tracks_every_vehicle_and_its_intent():
    env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching="certified")
    env.reset(seed=0)
    s = highway_state(env)
    assert s.shape == (1, len(STATE_COLUMNS) + 3 * 3 + len(VEHICLE_COLUMNS) * TRACKED)
    road = env.unwrapped.road
    changer = road.vehicles[1]
    lane = changer.lane_index
    changer.target_lane_index = (lane[0], lane[1], 2 - lane[2] if lane[2] != 1 else 0)
    target_y = road.network.get_lane(changer.target_lane_index).start[1]
    block = highway_state(env)[0, -TRACKED * len(VEHICLE_COLUMNS) :].reshape(TRACKED, -1)
    row = block[
        np.argmin(np.abs(block[:, 1] - (changer.position[0] - env.unwrapped.vehicle.position[0])))
    ]
    assert row[4] <= min(target_y, changer.position[1]) and row[5] >= max(
        target_y, changer.position[1]
    )
    assert int(block[:, 0].sum()) == len(road.vehicles) - 1  # 15 others, all tracked
    env.close()


def test_certified_is_one_name_for_the_left_turn_and_highway_env():
    env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching="certified")
    assert isinstance(env.get_wrapper_attr("logic"), CertifiedHighwayLogic)
    assert isinstance(
        env.get_wrapper_attr("supervisor").safety_controller, CertifiedHighwayController
    )
    env.close()
    left = gym.make(safeswitch.ENV_ID, switching="certified")
    assert type(left.unwrapped.task.switching).__name__ == "CertifiedSwitching"
    left.close()
    with pytest.raises(LogicContextError, match="left turn and highway-env, not CartPole-v1"):
        make_logic("certified", gym.make("CartPole-v1"))


@pytest.mark.slow
@pytest.mark.parametrize("kind", Adversary.KINDS)
def test_adversarial_drivers_never_crash_under_certified(kind):
    env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching="certified")
    row = drive(env, Adversary(kind, seed=5), 3, seed=5000)
    assert row["crashes"] == 0 and row["off_road"] == 0
    # whole episodes, and the switch had work to do
    assert row["steps"] == 3 * 151 and row["safety_activation_steps"] > 0


@pytest.mark.slow
@pytest.mark.parametrize("kind", Adversary.KINDS)
def test_adversarial_drivers_never_crash_under_certified_at_length(kind):
    env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching="certified")
    row = drive(env, Adversary(kind, seed=7), 40, seed=7000)
    assert row["crashes"] == 0 and row["off_road"] == 0 and row["steps"] == 40 * 151


@pytest.mark.slow
def test_the_idm_driver_in_the_egos_seat_drives_like_highway_envs_own_vehicles():
    env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching="none")
    row = drive(env, IDMDriver(), 2, seed=1_000_003)
    assert row["crashes"] == 0 and row["off_road"] == 0 and row["steps"] == 2 * 151
    assert row["mean_return"] > 100  # it keeps up its speed: 0.66 of the best reward a step
    with pytest.raises(ValueError, match="adversary kind 'reckless' is not one of"):
        Adversary("reckless")
