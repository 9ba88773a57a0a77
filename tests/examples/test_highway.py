"""The framework on highway-env (a plant nobody here wrote): SafeSwitch with the ``ttc`` logic,
and ``train``/``evaluate --env`` for any registered environment."""

import json

import gymnasium as gym
import numpy as np
import pytest

import safeswitch
from safeswitch.cli import main
from safeswitch.core.registry import register_safety_controller, unregister_logic

pytest.importorskip("highway_env")


def run_random(switching, episodes, seed=0):
    env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching=switching)
    rng = np.random.default_rng(seed)
    crashes = off_road = steps = safety = 0
    reasons = set()
    for k in range(episodes):
        env.reset(seed=seed + k)
        done = False
        while not done:
            *_, terminated, truncated, info = env.step(rng.uniform(-1, 1, 2))
            steps += 1
            safety += info["safety_active"]
            reasons.add(info["reason"])
            done = terminated or truncated
        crashes += info["crashed"]
        off_road += info["rewards"]["on_road_reward"] == 0
    env.close()
    return crashes, off_road, steps, safety, reasons


@pytest.mark.slow
def test_ttc_keeps_a_random_driver_on_the_road_and_out_of_other_cars():
    crashes, off_road, steps, safety, reasons = run_random("ttc", 5)
    assert crashes == 0 and off_road == 0
    assert steps >= 5 * 150  # every episode ran its whole 30 s
    assert safety > 0.2 * steps and {"learned", "off_road"} <= reasons
    # without the switch the same random driver leaves the road in nearly every episode
    crashes, off_road, steps, safety, _ = run_random("none", 5)
    assert crashes + off_road >= 4 and safety == 0


def test_the_wrapper_records_and_penalises_every_safety_step():
    env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching="ttc", penalty=-2.0)
    env.reset(seed=3)
    for _ in range(40):
        _, reward, _, _, info = env.step(np.array([1.0, 1.0], dtype=np.float32))  # hard left
        assert info["cost"] == float(info["safety_active"])
        if info["safety_active"]:
            assert reward < 0  # the penalty outweighs highway-env's [0, 1] reward
            assert not np.array_equal(info["executed_action"], info["learned_action"])
    assert env.unwrapped.vehicle.on_road


@pytest.mark.slow
def test_train_and_evaluate_any_registered_env(tmp_path, capsys):
    run = tmp_path / "run"
    args = ["train", "--env", safeswitch.HIGHWAY_ENV_ID, "--switching", "ttc", "--timesteps",
            "256", "--n-envs", "1", "--out", str(run), "--no-progress"]  # fmt: skip
    assert main(args) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["env_id"] == safeswitch.HIGHWAY_ENV_ID and metrics["timesteps"] >= 256
    assert metrics["training"]["failures"] == 0
    capsys.readouterr()
    args = ["evaluate", "--env", safeswitch.HIGHWAY_ENV_ID, "--model", str(run), "--episodes",
            "2", "--json"]  # fmt: skip
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["episodes"] == 2 and summary["switching"] == "ttc"
    assert summary["failures"] == 0


def test_an_env_with_a_registered_safety_controller_trains_through_safeswitch(tmp_path):
    from tests.core.plants import BrakingEnvelope, Follow, full_brake

    env_id = "tests/Follow-v0"
    if env_id not in gym.registry:
        gym.register(env_id, entry_point=Follow, kwargs={"horizon": 50})
    register_safety_controller(env_id, lambda env: full_brake)
    safeswitch.register_logic("braking-envelope", lambda env: BrakingEnvelope(), replace=True)
    run = tmp_path / "run"
    args = ["train", "--env", env_id, "--switching", "braking-envelope", "--timesteps", "512",
            "--n-envs", "2", "--out", str(run), "--no-progress"]  # fmt: skip
    try:
        assert main(args) == 0
    finally:  # other tests list the known logics
        unregister_logic("braking-envelope")
    metrics = json.loads((run / "metrics.json").read_text())
    training = metrics["training"]
    assert training["failures"] == 0 and training["safety_activation_steps"] > 0


def test_the_ttc_thresholds_are_configured_from_a_training_file():
    from safeswitch.core.config import ConfigError, from_dict
    from safeswitch.training.config import EnvTrainConfig

    config = from_dict(EnvTrainConfig, {"env_id": safeswitch.HIGHWAY_ENV_ID, "switching": "ttc",
                                        "logic_params": {"min_ttc": 2.5}})  # fmt: skip
    env = gym.make(config.env_id, switching=config.switching, logic_params=config.logic_params)
    assert env.unwrapped is not env and env.get_wrapper_attr("logic").rules.min_ttc == 2.5
    assert env.get_wrapper_attr("logic").rules.decision_period == 0.2  # from the environment
    env.close()
    with pytest.raises(ConfigError, match=r"ttc\.min_ttc must be > 0, got -1"):
        from_dict(EnvTrainConfig, {"env_id": safeswitch.HIGHWAY_ENV_ID, "switching": "ttc",
                                   "logic_params": {"min_ttc": -1}})  # fmt: skip
    with pytest.raises(ConfigError, match="logic_params need switching"):
        from_dict(EnvTrainConfig, {"env_id": safeswitch.HIGHWAY_ENV_ID,
                                   "logic_params": {"min_ttc": 2}})  # fmt: skip


def test_the_plant_publishes_speeding_and_comfort_from_the_bicycle_it_drives():
    """``accel_lat`` is ``v·ψ̇`` of highway-env's kinematic bicycle: checked against the heading
    the plant actually turned through; ``comfort`` flags a lateral acceleration above 3 m/s²;
    ``speeding`` a speed above the lane's 30 m/s."""
    env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching="none")
    env.reset(seed=3)
    ego = env.unwrapped.vehicle
    dt = 1 / env.unwrapped.config["policy_frequency"]
    for steer, uncomfortable in ((0.01, False), (-0.01, False), (0.05, True)):
        speed, heading = ego.speed, ego.heading
        *_, info = env.step(np.array([0.0, steer], dtype=np.float32))
        assert info["accel_lat"] == pytest.approx(speed * (ego.heading - heading) / dt, rel=1e-6)
        assert info["costs"]["comfort"] == float(uncomfortable)
        assert info["costs"]["speeding"] == 0.0
    ego.speed = 35.0  # above highway-env's 30 m/s limit
    *_, info = env.step(np.array([0.0, 0.0], dtype=np.float32))
    assert info["costs"]["speeding"] == 1.0
    env.close()


def test_the_plant_publishes_a_following_gap_under_one_second():
    """``time_gap`` is bumper to bumper at the ego's speed to the vehicle ahead in the ego's
    lane — a nearer one in another lane does not count —; ``following`` flags a gap under 1 s."""
    from safeswitch.examples.highway_plant import FOLLOWING_GAP_S, time_gap

    env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching="none")
    env.reset(seed=0)
    road, ego = env.unwrapped.road, env.unwrapped.vehicle
    lanes = len(road.network.lanes_list())
    own = ego.lane_index
    other = (own[0], own[1], (own[2] + 1) % lanes)
    s_ego, _ = road.network.get_lane(own).local_coordinates(ego.position)

    def place(vehicle, index, ahead_by):
        vehicle.lane_index, vehicle.lane = index, road.network.get_lane(index)
        vehicle.position = vehicle.lane.position(s_ego + ahead_by, 0.0)

    others = [v for v in road.vehicles if v is not ego]
    leader, beside = others[0], others[1]
    for k, v in enumerate(others[2:]):  # every other vehicle far behind
        place(v, own, -400.0 - 10.0 * k)
    place(beside, other, ego.LENGTH + 5.0)  # 5 m ahead, one lane over: not followed
    ego.speed = leader.speed = 25.0
    for gap in (30.0, 20.0):
        place(leader, own, gap + ego.LENGTH)
        assert time_gap(env.unwrapped) == pytest.approx(gap / 25.0)
    assert FOLLOWING_GAP_S == 1.0
    *_, info = env.step(np.array([0.0, 0.0], dtype=np.float32))  # 0.8 s: following
    assert info["time_gap"] < 1.0 and info["costs"]["following"] == 1.0
    place(leader, own, 40.0 + ego.LENGTH)
    *_, info = env.step(np.array([0.0, 0.0], dtype=np.float32))  # 1.6 s: not
    assert info["time_gap"] > 1.0 and info["costs"]["following"] == 0.0
    place(leader, other, 10.0 + ego.LENGTH)  # nobody ahead in the ego's lane
    assert time_gap(env.unwrapped) == float("inf")
    env.close()


def test_the_learned_steering_limit_binds_the_policy_not_the_safety_controller():
    from safeswitch.examples.highway_plant import LearnedSteering

    env = gym.make(safeswitch.HIGHWAY_ENV_ID, switching="certified", steering_limit=0.02)
    env.reset(seed=0)
    ego = env.unwrapped.vehicle
    *_, info = env.step(np.array([0.0, 1.0], dtype=np.float32))
    assert info["reason"] == "learned" and ego.action["steering"] == pytest.approx(0.02)
    np.testing.assert_allclose(info["executed_action"], [0.0, 1.0], atol=1e-6)
    # drive off the road's edge: the Safety controller steers back with more than the limit
    steering = []
    for _ in range(40):
        *_, info = env.step(np.array([0.0, -1.0], dtype=np.float32))
        if info["safety_active"]:
            steering.append(abs(ego.action["steering"]))
    assert steering and max(steering) > 0.02
    assert info["rewards"]["on_road_reward"] == 1 and not info["crashed"]
    env.close()
    bad = r"steering_limit must lie in \(0, 0\.7854\] rad, got 2\.0"
    with pytest.raises(ValueError, match=bad):
        LearnedSteering(gym.make(safeswitch.HIGHWAY_ENV_ID, switching="none"), 2.0)
