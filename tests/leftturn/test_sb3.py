"""The VecEnv inside Stable-Baselines3's PPO loop, with VecNormalize."""

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

from safeswitch.leftturn import make_vec_env


def test_ppo_collects_our_episode_summaries_through_vec_normalize():
    torch.set_num_threads(1)
    env = VecNormalize(make_vec_env(8, seed=0, config={"episode": {"horizon_s": 1.0}}))
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=128, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=2 * 64 * 8)
    episodes = list(model.ep_info_buffer)
    # 128 ticks per environment with 50-tick episodes: two finished episodes each.
    assert len(episodes) == 16
    assert all(e["l"] == 50 for e in episodes)
    assert all("safety_steps" in e and "collision" in e for e in episodes)
    # VecNormalize saw real observations: its running mean tracks the ego's coordinates.
    assert env.obs_rms.count > 1000
    assert np.all(np.isfinite(env.obs_rms.mean))
    assert env.obs_rms.mean[2] > 3.0  # ego speed, m/s
