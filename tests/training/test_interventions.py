"""Learning from the Safety controller's interventions (issue #39, item 4): the executed safety
action is a demonstration on the states where the switch overruled the policy."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from safeswitch.core.config import ConfigError, from_dict
from safeswitch.core.wrappers import SafeSwitch
from safeswitch.leftturn.vec_env import LeftTurnVecEnv
from safeswitch.training.config import EnvTrainConfig, TrainConfig
from safeswitch.training.interventions import (
    LEFT_TURN_SAFE_ACTION,
    InterventionRecorder,
    interventions,
    recorder_of,
)
from safeswitch.training.ppo import SwitchPPO
from safeswitch.training.run import build_model
from tests.core import user_plant


def wall_env(logic, n=2, seed=0):
    def make():
        env = gym.make(user_plant.ENV_ID)
        return SafeSwitch(env, user_plant.full_brake, logic, penalty=-1.0)

    vec = DummyVecEnv([make] * n)
    vec.seed(seed)
    return InterventionRecorder(VecNormalize(vec, norm_reward=False))


def model_on(env, coef, seed=0, learning_rate=3e-4):  # SB3's default rate
    return SwitchPPO("MlpPolicy", env, n_steps=32, batch_size=32, n_epochs=2, seed=seed,
                     device="cpu", intervention_imitation=coef, learning_rate=learning_rate,
                     policy_kwargs={"net_arch": [16, 16]})  # fmt: skip


def test_the_safety_action_is_read_from_any_plant_and_from_the_left_turn():
    infos = [{"safety_active": False}, {"safety_active": True, "executed_action": [-3.0]}]
    mask, targets = interventions(infos, 1)
    assert mask.tolist() == [False, True] and targets[1].tolist() == [-3.0]
    vec = LeftTurnVecEnv(8, switching="paper", seed=0)
    vec.reset()
    seen = np.zeros(8, dtype=bool)
    for _ in range(400):  # full throttle: the paper logic brakes some of them
        _, _, _, infos = vec.step(np.ones((8, 1), dtype=np.float32))
        mask, targets = interventions(infos, 1)
        assert (mask == infos.record.safety_active).all()
        assert (targets[mask] == LEFT_TURN_SAFE_ACTION).all() and (targets[~mask] == 0).all()
        seen |= mask
    assert seen.any()


def test_the_recorder_keeps_the_state_the_overruled_action_was_taken_in():
    env = wall_env("stopping-distance")
    observation = env.reset()
    for _ in range(200):
        before = observation
        observation, _, _, infos = env.step(np.full((2, 1), 2.0, dtype=np.float32))
        mask, _ = interventions(infos, 1)
        if mask.any():
            states, targets = env.batch()
            assert np.array_equal(states[-mask.sum() :], before[mask])
            assert (targets == -user_plant.MAX_BRAKE).all()
            break
    else:
        pytest.fail("full acceleration toward the wall was never overruled")
    env.clear()
    assert env.batch() is None and recorder_of(env) is env


def _parameters(model):
    return [p.detach().clone() for p in model.policy.parameters()]


def test_imitation_changes_the_update_only_on_intervention_states():
    # No intervention in the rollouts (no logic): the update is PPO's, to the last bit.
    plain = model_on(wall_env("none"), 0.0)
    plain.learn(64)  # each built and trained in turn: both draw from the same seeded RNGs
    imitating = model_on(wall_env("none"), 5.0)
    imitating.learn(64)
    assert recorder_of(imitating.env).batch() is None
    for a, b in zip(_parameters(plain), _parameters(imitating), strict=True):
        assert torch.equal(a, b)
    # With interventions: the mean action on those states moves toward the safety action,
    # and the value network is not touched by the fit.
    model = model_on(wall_env("stopping-distance"), 5.0)
    model.learn(64)
    recorder = recorder_of(model.env)
    states, targets = recorder.batch()
    value_before = [p.detach().clone() for p in model.policy.mlp_extractor.value_net.parameters()]
    observation = torch.as_tensor(states, dtype=torch.float32)

    def gap():
        with torch.no_grad():
            mean = model.policy.get_distribution(observation).distribution.mean
        return float((mean.clamp(-3, 2) - torch.as_tensor(targets)).pow(2).mean())

    before = gap()
    model.imitate_interventions()
    assert gap() < before
    after = list(model.policy.mlp_extractor.value_net.parameters())
    assert all(torch.equal(a, b) for a, b in zip(value_before, after, strict=True))


def _mean_action(policy, states):
    with torch.no_grad():
        return policy.get_distribution(torch.as_tensor(states)).distribution.mean.numpy()


def test_an_anchored_actor_stays_near_its_reference_only_where_anchored():
    """``anchor_to`` (``safeswitch adapt``'s guard against forgetting) fits the actor toward a
    reference policy on the anchored environments' states after each update: there it moves
    toward the reference; with nothing anchored the update is PPO's to the last bit."""
    import copy

    def run(anchored):
        model = model_on(wall_env("none", n=4), 0.0, learning_rate=0.01)
        reference = copy.deepcopy(model.policy)
        with torch.no_grad():
            reference.action_net.bias.add_(0.5)  # the reference asks for 0.5 more everywhere
        model.anchor_to(reference, np.array(anchored), weight=1.0)
        states = np.random.default_rng(0).normal(size=(64, 2)).astype(np.float32)
        start = np.abs(_mean_action(model.policy, states) - _mean_action(reference, states))
        model.learn(1024)
        end = np.abs(_mean_action(model.policy, states) - _mean_action(reference, states))
        return model, start.mean(), end.mean()

    plain, start, end_plain = run([False] * 4)
    anchored, _, end_anchored = run([False, False, True, True])
    assert start == pytest.approx(0.5, abs=1e-5)
    assert end_anchored < 0.5 * start and end_anchored < 0.5 * end_plain
    unanchored = model_on(wall_env("none", n=4), 0.0, learning_rate=0.01)
    unanchored.learn(1024)
    for a, b in zip(_parameters(plain), _parameters(unanchored), strict=True):
        assert torch.equal(a, b)
    with pytest.raises(ValueError, match=r"one flag per environment \(4\)"):
        anchored.anchor_to(anchored.policy, np.array([True]))
    assert "_anchor" in anchored._excluded_save_params()


def _model_with_bound_loss(weight, bias, margin=0.0, log_std=-3.0):
    """A fresh model on the wall plant (no logic) whose mean starts at ``bias`` everywhere."""
    model = SwitchPPO("MlpPolicy", wall_env("none", n=4), n_steps=32, batch_size=32, n_epochs=2,
                      seed=0, device="cpu", action_bound_loss=weight, action_bound_margin=margin,
                      learning_rate=0.01, learn_log_std=False,
                      policy_kwargs={"net_arch": [16, 16], "log_std_init": log_std})  # fmt: skip
    with torch.no_grad():
        model.policy.action_net.weight.zero_()
        model.policy.action_net.bias.fill_(bias)
    return model


def test_the_bound_loss_pulls_a_mean_beyond_the_action_bounds_back_and_leaves_one_within():
    """``action_bound_loss`` (``policy.action_bound_loss``): a mean far beyond the action bounds
    (the wall plant's acceleration, up to ``MAX_ACCEL``) makes every sample of a small noise the
    same clipped action, so PPO's own update cannot move it; the fit after the update pulls it
    back toward the bound. Within the bounds it changes nothing, to the last bit."""
    high = float(wall_env("none").action_space.high[0])
    states = np.random.default_rng(0).normal(size=(64, 2)).astype(np.float32)
    far = 4.0 * high
    plain, pulled = _model_with_bound_loss(0.0, far), _model_with_bound_loss(1.0, far)
    plain.learn(1024)
    pulled.learn(128)  # one rollout: every state's mean lies beyond the bound
    assert pulled.logger.name_to_value["train/means_out_of_bounds"] == 1.0
    pulled.learn(896, reset_num_timesteps=False)
    assert _mean_action(plain.policy, states).mean() > 3.5 * high  # PPO alone: stuck out there
    assert _mean_action(pulled.policy, states).max() < 1.1 * high
    inside = _model_with_bound_loss(1.0, 0.0)
    inside.learn(256)
    reference = _model_with_bound_loss(0.0, 0.0)
    reference.learn(256)
    assert np.abs(_mean_action(inside.policy, states)).max() < high
    for a, b in zip(_parameters(inside), _parameters(reference), strict=True):
        assert torch.equal(a, b)


def test_the_bound_loss_leaves_a_mean_within_its_margin_and_pulls_one_beyond_it():
    """``action_bound_margin``: a mean may lie that many noise standard deviations beyond a
    bound, so that some samples still fall within; only beyond that is it pulled."""
    high = float(wall_env("none").action_space.high[0])
    sigma = 1.0  # log_std 0
    states = np.random.default_rng(0).normal(size=(64, 2)).astype(np.float32)
    runs = {}
    for weight, margin in [(0.0, 0.0), (1.0, 1.0), (1.0, 0.25)]:
        model = _model_with_bound_loss(weight, high + 0.5 * sigma, margin, log_std=0.0)
        model.learn(128)  # one rollout, one update: where the fit does or does not act
        runs[weight, margin] = model
    within, beyond = runs[1.0, 1.0], runs[1.0, 0.25]
    assert within.logger.name_to_value["train/means_out_of_bounds"] == 0.0
    assert beyond.logger.name_to_value["train/means_out_of_bounds"] == 1.0
    for a, b in zip(_parameters(within), _parameters(runs[0.0, 0.0]), strict=True):
        assert torch.equal(a, b)
    moved = _mean_action(beyond.policy, states).mean()
    assert moved < _mean_action(within.policy, states).mean() - 0.05


def test_the_bound_loss_is_a_policy_setting_off_by_default_and_reaches_the_model():
    assert TrainConfig().policy.action_bound_loss == 0.0
    assert EnvTrainConfig(env_id=user_plant.ENV_ID).policy.action_bound_loss == 0.0
    config = from_dict(
        EnvTrainConfig, {"env_id": user_plant.ENV_ID, "policy": {"action_bound_loss": 0.5}}
    )
    assert build_model(config, wall_env("none"), None).action_bound_loss == 0.5
    with pytest.raises(ConfigError, match=r"action_bound_loss.*-1"):
        from_dict(TrainConfig, {"policy": {"action_bound_loss": -1}})
