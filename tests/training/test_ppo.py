"""SwitchPPO's bookkeeping: the left turn's batched infos are read only where episodes ended,
with the same episode buffers as SB3's loop over every environment."""

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm

from safeswitch.leftturn.vec_env import LeftTurnVecEnv
from safeswitch.training.ppo import SwitchPPO


def test_episode_buffers_are_sb3s_from_the_ended_infos_alone():
    vec = LeftTurnVecEnv(16, switching="certified", seed=3)
    fast = SwitchPPO("MlpPolicy", vec, n_steps=8, batch_size=8, device="cpu", seed=0)
    every = SwitchPPO("MlpPolicy", vec, n_steps=8, batch_size=8, device="cpu", seed=0)
    fast._setup_learn(1)  # the buffers
    every._setup_learn(1)
    rng = np.random.default_rng(0)
    vec.reset()
    ended = 0
    for _ in range(1500):
        _, _, dones, infos = vec.step(rng.uniform(-1, 1, (16, 1)).astype(np.float32))
        fast._update_info_buffer(infos, dones)
        assert len(infos._cache) == dones.sum()  # only the ended environments' infos built
        BaseAlgorithm._update_info_buffer(every, list(infos), dones)  # SB3's loop, every info
        ended += int(dones.sum())
    assert ended > 16  # episodes ended and were counted
    assert fast.ep_info_buffer == every.ep_info_buffer
    assert len(fast.ep_info_buffer) == min(ended, fast.ep_info_buffer.maxlen)
    assert fast.ep_success_buffer == every.ep_success_buffer
