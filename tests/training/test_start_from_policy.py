"""``warm_start.policy``: a run starts from a trained policy's weights and observation
statistics (fine-tuning), and refuses one it cannot take."""

import numpy as np
import pytest

from safeswitch.core.config import ConfigError, from_dict
from safeswitch.leftturn.make import build_task
from safeswitch.training import train
from safeswitch.training.config import TrainConfig
from safeswitch.training.policies import load_policy

SMALL = {
    "timesteps": 2048,
    "n_envs": 8,
    "seed": 3,
    "eval_episodes": 0,
    "torch_threads": 1,
    "ppo": {"net_arch": [16, 16]},
    "env": {"episode": {"learned_scope": "episode", "horizon_s": 2.0}},
}


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    run = tmp_path_factory.mktemp("source") / "run"
    train(from_dict(TrainConfig, SMALL), run, progress_bar=False)
    return run


def actions(run, obs):
    return load_policy(run).act(obs)


def test_a_run_with_its_actor_frozen_keeps_the_policy_it_started_from(source, tmp_path):
    frozen = SMALL | {
        "seed": 4,
        "warm_start": {"policy": str(source)},
        "policy": {"actor_frozen_steps": 10_000, "learn_log_std": False},
    }
    run = tmp_path / "fine"
    train(from_dict(TrainConfig, frozen), run, progress_bar=False)
    task = build_task(None, from_dict(TrainConfig, SMALL).env)
    low, high = task.observation_bounds
    obs = np.random.default_rng(0).uniform(low, high, (64, *low.shape)).astype(np.float32)
    np.testing.assert_allclose(actions(run, obs), actions(source, obs), rtol=0, atol=1e-6)
    np.testing.assert_array_equal(
        load_policy(run).normalizer.obs_rms.mean, load_policy(source).normalizer.obs_rms.mean
    )
    # started elsewhere, the same run's actor is another one
    fresh = tmp_path / "fresh"
    train(from_dict(TrainConfig, frozen | {"warm_start": {}}), fresh, progress_bar=False)
    assert np.abs(actions(fresh, obs) - actions(source, obs)).max() > 1e-3


def test_a_policy_of_another_shape_is_refused_by_name(source, tmp_path):
    wider = SMALL | {"ppo": {"net_arch": [32, 32]}, "warm_start": {"policy": str(source)}}
    with pytest.raises(ConfigError, match=r"warm_start\.policy=.*not this run's.*\[16, 16\]"):
        train(from_dict(TrainConfig, wider), tmp_path / "run", progress_bar=False)
    assert not (tmp_path / "run").exists()  # refused before the run directory is written
    with pytest.raises(ConfigError, match=r"warm_start\.policy=.*no trained policy"):
        train(
            from_dict(TrainConfig, SMALL | {"warm_start": {"policy": str(tmp_path / "none")}}),
            tmp_path / "run2",
            progress_bar=False,
        )


def test_starting_from_a_policy_and_cloning_exclude_each_other():
    with pytest.raises(ConfigError, match=r"warm_start.*policy"):
        from_dict(TrainConfig, SMALL | {"warm_start": {"policy": "certified", "episodes": 10}})


def test_a_policy_that_observes_fewer_values_starts_a_wider_run_when_asked_for(source, tmp_path):
    """``warm_start.extend_inputs``: the source's six values are the first of this run's seven
    (the time left appended): its first layers read them as before and the new input with
    weights that start at zero; its statistics are re-estimated on the run's states. Without
    the option the source is refused by name."""
    clock = {"episode": {**SMALL["env"]["episode"], "observe_time_left": True}}
    wide = SMALL | {
        "seed": 4,
        "env": clock,
        "warm_start": {"policy": str(source), "extend_inputs": True, "freeze_obs_stats": False},
        "policy": {"actor_frozen_steps": 10_000, "learn_log_std": False},
    }
    run = tmp_path / "wide"
    train(from_dict(TrainConfig, wide), run, progress_bar=False)
    theirs, ours = load_policy(source), load_policy(run)
    first = [p.model.policy.mlp_extractor.policy_net[0].weight.detach() for p in (theirs, ours)]
    assert first[1].shape == (16, 7)
    np.testing.assert_array_equal(first[1][:, :6], first[0])
    np.testing.assert_array_equal(first[1][:, 6], 0.0)  # the actor was frozen: still zero
    critic = ours.model.policy.mlp_extractor.value_net[0].weight.detach()
    assert critic[:, 6].abs().max() > 0  # the critic learned to read the clock
    # the clock's statistics move from 0 toward the run's mean time left (about 1 s of 2)
    assert 0.3 < ours.normalizer.obs_rms.mean[6] < 1.5
    with pytest.raises(ConfigError, match=r"warm_start\.policy=.*\(6,\) there, \(7,\) here"):
        train(from_dict(TrainConfig, wide | {"warm_start": {"policy": str(source)}}),
              tmp_path / "narrow", progress_bar=False)  # fmt: skip
    with pytest.raises(ConfigError, match=r"warm_start\.extend_inputs .*freeze_obs_stats"):
        from_dict(TrainConfig, SMALL | {"warm_start": {"policy": "x", "extend_inputs": True}})
