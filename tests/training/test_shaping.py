"""Potential-based progress shaping: what PPO sees, and what it leaves alone."""

import numpy as np
import pytest

from safeswitch.core.config import ConfigError
from safeswitch.leftturn.vec_env import LeftTurnVecEnv
from safeswitch.training.config import EnvTrainConfig, PPOConfig
from safeswitch.training.shaping import ProgressShaping

GAMMA, K = 0.99, 2.0


def make(n=6):
    config = {"episode": {"horizon_s": 2.0, "decision_interval": 5, "learned_scope": "episode"}}
    base = LeftTurnVecEnv(n, config=config, seed=4)
    return base, ProgressShaping(base, K, GAMMA)


def test_the_shaping_telescopes_over_each_episode_and_the_paper_reward_is_untouched():
    """Per episode, the discounted sum of the shaping terms is ``γ^T·Φ(last) − Φ(first)``:
    the potential of the episode that ended, not of the one that follows; the environment's
    own reward and its episode return are the paper's."""
    base, env = make()
    env.reset()
    rng = np.random.default_rng(0)
    start = K * base.state.world.progress[:, 0].copy()
    discounted, paper, power = np.zeros(6), np.zeros(6), np.ones(6)
    checked = 0
    for _ in range(40):
        env.step_async(rng.uniform(-1, 1, (6, 1)))
        _, reward, done, infos = env.step_wait()
        paper += paper_reward(base)
        discounted += power * (reward - paper_reward(base))
        power *= GAMMA
        for i in np.flatnonzero(done):
            last = K * base.ego_progress_after_step[i]
            assert discounted[i] == pytest.approx(power[i] * last - start[i], abs=1e-3)
            assert infos[i]["episode"]["r"] == pytest.approx(paper[i], rel=1e-5)
            start[i] = K * base.state.world.progress[i, 0]
            discounted[i], paper[i], power[i] = 0.0, 0.0, 1.0
            checked += 1
    assert checked >= 12


def paper_reward(base):
    """The paper's reward of the last step, as the environment itself returns it."""
    return base.last_record.reward.astype(np.float32)


def test_the_ego_moving_on_pays_and_standing_still_costs_only_the_discount():
    base, env = make(2)
    env.reset()
    env.step_async(np.array([[1.0], [-1.0]]))  # full throttle; closed throttle from a roll
    before = K * base.state.world.progress[:, 0].copy()
    _, reward, _, _ = env.step_wait()
    shaped = reward - paper_reward(base)
    after = K * base.ego_progress_after_step
    np.testing.assert_allclose(shaped, GAMMA * after - before, atol=1e-4)
    assert shaped[0] > shaped[1]


def test_bad_shaping_settings_are_named():
    with pytest.raises(ConfigError, match="progress_shaping"):
        PPOConfig(progress_shaping=-1.0)
    with pytest.raises(ConfigError, match="progress_shaping"):
        EnvTrainConfig(env_id="CartPole-v1", ppo=PPOConfig(progress_shaping=1.0))
    with pytest.raises(TypeError, match="LeftTurnVecEnv"):
        ProgressShaping(object(), 1.0, 0.99)  # type: ignore[arg-type]
