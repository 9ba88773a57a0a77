"""SafeSwitch and SafeSwitchVecEnv around environments safeswitch did not write."""

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from safeswitch import Decision, SafeSwitch, SafeSwitchVecEnv, SwitchingError
from safeswitch.core.registry import UnknownLogicError

from .plants import MAX_ACCEL, MAX_BRAKE, BrakingEnvelope, Follow, full_brake

INFO_KEYS = ("safety_active", "reason", "cost", "learned_action", "executed_action")


def wild_actions(rng, n):
    """Random accelerations, with NaN, ±inf and far out-of-range values mixed in."""
    actions = rng.uniform(-12.0, 6.0, (n, 1))
    pick = rng.random(n)
    actions[pick < 0.05] = np.nan
    actions[(pick >= 0.05) & (pick < 0.08)] = np.inf
    actions[(pick >= 0.08) & (pick < 0.10)] = -np.inf
    actions[(pick >= 0.10) & (pick < 0.15)] = 1e6
    return actions.astype(np.float32)


def test_no_invalid_or_out_of_range_action_reaches_the_env_and_nothing_crashes():
    inner = Follow()
    env = SafeSwitch(inner, full_brake, BrakingEnvelope())
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    reasons, crashes = set(), 0
    for action in wild_actions(rng, 3000):
        _, _, terminated, truncated, info = env.step(action)
        reasons.add(info["reason"])
        crashes += info["crashed"]
        if terminated or truncated:
            env.reset()
    received = np.array(inner.received)
    assert np.isfinite(received).all()
    assert received.min() >= -MAX_BRAKE and received.max() <= MAX_ACCEL
    assert crashes == 0
    assert reasons == {"learned", "too_close", "invalid_learned_action"}


def test_penalty_and_cost_appear_exactly_on_safety_steps():
    rng = np.random.default_rng(1)
    plain, wrapped = Follow(), SafeSwitch(Follow(), full_brake, BrakingEnvelope(), penalty=-7.0)
    plain.reset(seed=3)
    wrapped.reset(seed=3)
    safety_steps = 0
    for action in wild_actions(rng, 400):
        _, reward, terminated, truncated, info = wrapped.step(action)
        # the plain env replays exactly what ran (same seed, same executed action)
        _, plain_reward, *_ = plain.step(info["executed_action"].astype(np.float32))
        for key in INFO_KEYS:
            assert key in info
        assert info["cost"] == (1.0 if info["safety_active"] else 0.0)
        assert reward == pytest.approx(plain_reward + (-7.0 if info["safety_active"] else 0.0))
        safety_steps += info["safety_active"]
        if info["reason"] == "invalid_learned_action":
            assert info["safety_active"] and not np.isfinite(info["learned_action"]).all()
        if terminated or truncated:
            break
    assert 0 < safety_steps < 400


def test_out_of_range_learned_actions_are_clipped_and_say_so():
    env = SafeSwitch(Follow(), full_brake, "none")
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([50.0], dtype=np.float32))
    assert info["action_clipped"] and info["executed_action"][0] == MAX_ACCEL
    assert info["learned_action"][0] == 50.0 and not info["safety_active"]


def test_vec_wrapper_decides_as_the_single_env_wrapper_per_environment():
    n, steps = 4, 300
    rng = np.random.default_rng(2)
    actions = wild_actions(rng, steps * n).reshape(steps, n, 1)
    vec = SafeSwitchVecEnv(
        DummyVecEnv([lambda: Follow()] * n), full_brake, BrakingEnvelope(), penalty=-3.0
    )
    vec.seed(10)
    vec.reset()
    singles = [SafeSwitch(Follow(), full_brake, BrakingEnvelope(), penalty=-3.0) for _ in range(n)]
    for i, env in enumerate(singles):
        env.reset(seed=10 + i)
    for t in range(steps):
        _, rewards, dones, infos = vec.step(actions[t])
        for i, env in enumerate(singles):
            _, reward, terminated, truncated, info = env.step(actions[t, i])
            assert infos[i]["reason"] == info["reason"]
            np.testing.assert_array_equal(infos[i]["executed_action"], info["executed_action"])
            assert rewards[i] == pytest.approx(reward)
            assert dones[i] == (terminated or truncated)
            if terminated or truncated:
                env.reset()


@pytest.mark.slow
def test_sb3_ppo_and_sac_train_through_both_wrappers_without_a_crash():
    from stable_baselines3 import PPO, SAC

    plants = [Follow(horizon=100) for _ in range(3)]
    single = Monitor(SafeSwitch(plants[0], full_brake, BrakingEnvelope()))
    vec = SafeSwitchVecEnv(
        DummyVecEnv([lambda p=p: p for p in plants[1:]]), full_brake, BrakingEnvelope()
    )
    for algorithm, env in ((PPO, single), (SAC, single), (PPO, vec), (SAC, vec)):
        kwargs = {"n_steps": 64, "batch_size": 64} if algorithm is PPO else {"learning_starts": 50}
        model = algorithm("MlpPolicy", env, seed=0, device="cpu", **kwargs)
        model.learn(400)
        assert model.num_timesteps >= 400
    # untrained policies explore wildly, yet no plant ever saw a crash
    assert sum(len(p.received) for p in plants) >= 1600
    assert [p.crashes for p in plants] == [0, 0, 0]
    # the Monitor outside the wrapper logged returns that include the penalty
    episodes = single.get_episode_rewards()
    assert episodes and min(episodes) < -25


class WrongReasons:
    reasons = ("safe", "learned")

    def decide(self, state, learned, safe):
        raise AssertionError("never called")


class WrongShapes:
    reasons = ("learned", "x")

    def __init__(self, field):
        self.field = field

    def decide(self, state, learned, safe):
        b = learned.shape[0]
        d = {
            "use_safety": np.zeros(b, bool),
            "reason": np.zeros(b, np.int8),
            "safe_action": safe,
        }
        d[self.field] = {"use_safety": np.zeros(b + 1, bool), "reason": np.zeros(b, float),
                         "safe_action": safe[:, :0]}[self.field]  # fmt: skip
        return Decision(**d)


def test_bad_inputs_are_named():
    with pytest.raises(SwitchingError, match="start with 'learned'"):
        SafeSwitch(Follow(), full_brake, WrongReasons())
    with pytest.raises(UnknownLogicError, match=r"no-such-logic.*known logics: .*paper"):
        SafeSwitch(Follow(), full_brake, "no-such-logic")
    with pytest.raises(SwitchingError, match="Box action space"):
        SafeSwitch(gym.make("CartPole-v1"), full_brake, "none")
    with pytest.raises(SwitchingError, match="penalty"):
        SafeSwitch(Follow(), full_brake, "none", penalty=float("nan"))
    for field in ("use_safety", "reason", "safe_action"):
        env = SafeSwitch(Follow(), full_brake, WrongShapes(field))
        env.reset(seed=0)
        with pytest.raises(SwitchingError, match=f"WrongShapes.decide returned Decision.{field}"):
            env.step(np.zeros(1, np.float32))
    env = SafeSwitch(Follow(), lambda s: np.full((1, 1), np.nan), "none")
    env.reset(seed=0)
    with pytest.raises(SwitchingError, match="Safety controller returned a NaN"):
        env.step(np.zeros(1, np.float32))
    env = SafeSwitch(Follow(), lambda s: np.zeros(1), "none")
    env.reset(seed=0)
    with pytest.raises(SwitchingError, match=r"Safety controller returned shape \(1,\)"):
        env.step(np.zeros(1, np.float32))
    env = SafeSwitch(Follow(), full_brake, "none")
    env.reset(seed=0)
    with pytest.raises(SwitchingError, match="learned action is None"):
        env.step(None)
