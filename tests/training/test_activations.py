"""``policy.fast_tanh``: numpy's tanh in the forward pass is the same function, and its gradient
is tanh's."""

import numpy as np
import torch

from safeswitch.training.activations import NumpyTanh
from safeswitch.training.config import PolicyConfig
from safeswitch.training.run import _activation


def test_numpy_tanh_matches_torch_tanh_in_value_and_gradient():
    x = torch.linspace(-12, 12, 4001, dtype=torch.float32).reshape(-1, 1).repeat(1, 3)
    x = x.clone().requires_grad_(True)
    ours = NumpyTanh()(x)
    theirs = torch.tanh(x)
    np.testing.assert_allclose(ours.detach().numpy(), theirs.detach().numpy(), atol=2e-7)
    weights = torch.randn(3)
    (g_ours,) = torch.autograd.grad((ours * weights).sum(), x)
    (g_theirs,) = torch.autograd.grad((theirs * weights).sum(), x)
    np.testing.assert_allclose(g_ours.numpy(), g_theirs.numpy(), atol=1e-6)
    assert isinstance(NumpyTanh(), torch.nn.Tanh)  # found wherever Tanh layers are looked for


def test_fast_tanh_is_opt_in():
    assert _activation("tanh") is torch.nn.Tanh
    assert _activation("tanh", fast_tanh=True) is NumpyTanh
    assert _activation("relu", fast_tanh=True) is torch.nn.ReLU
    assert PolicyConfig().fast_tanh is False


def test_a_run_with_fast_tanh_saves_loads_and_acts_as_it_predicts(tmp_path):
    from safeswitch.core.config import from_dict
    from safeswitch.training import train
    from safeswitch.training.config import TrainConfig
    from safeswitch.training.policies import load_policy

    config = from_dict(TrainConfig, {
        "timesteps": 1024, "n_envs": 8, "seed": 3, "eval_episodes": 5, "torch_threads": 1,
        "ppo": {"fast_tanh": True},
        "env": {"episode": {"learned_scope": "episode", "horizon_s": 2.0}},
    })  # fmt: skip
    train(config, tmp_path / "run", progress_bar=False)
    policy = load_policy(tmp_path / "run")
    layers = list(policy.model.policy.mlp_extractor.policy_net)
    assert any(isinstance(m, NumpyTanh) for m in layers)
    obs = np.random.default_rng(0).normal(size=(16, 6)).astype(np.float32) * 10
    predicted, _ = policy.model.predict(policy.normalise(obs), deterministic=True)
    np.testing.assert_allclose(policy.act(obs), predicted.reshape(-1), atol=1e-6)
