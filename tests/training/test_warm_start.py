"""Warm start (behaviour cloning of the planner), the actor's own learning-rate schedule and the
annealed exploration noise (SwitchPPO's additions to PPO)."""

import json
import pickle
from dataclasses import replace

import numpy as np
import pytest
import torch
from stable_baselines3.common.vec_env import VecNormalize

from safeswitch.core.config import ConfigError, from_dict
from safeswitch.evaluation.evaluate import scenario_set
from safeswitch.evaluation.planner import Planner
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.leftturn.vec_env import LeftTurnVecEnv
from safeswitch.training import train
from safeswitch.training.callbacks import TrainingMonitor
from safeswitch.training.config import TrainConfig
from safeswitch.training.policies import load_policy
from safeswitch.training.ppo import SwitchPPO
from safeswitch.training.run import build_model, complete_checkpoints
from safeswitch.training.warm_start import FrozenRunningMeanStd

BASE = {
    "timesteps": 2048,
    "n_envs": 8,
    "seed": 5,
    "checkpoint_every": 1024,
    "eval_episodes": 0,
    "torch_threads": 1,
    "env": {"switching": "paper", "episode": {"learned_scope": "episode", "horizon_s": 4.0}},
}


def config(**sections):
    data = dict(BASE)
    for key, value in sections.items():
        data[key] = value
    return from_dict(TrainConfig, data)


def actor_state(model):
    return [p.detach().clone() for p in model.policy.mlp_extractor.policy_net.parameters()]


def imitation_error(policy, task, planner, seed):
    """Mean squared difference between the policy's and the planner's actions on the states
    the planner visits."""
    scenarios, _ = scenario_set(task, "random", 40, seed)
    errors = []

    def drive(obs, state, tick):
        expert = planner(obs, state, tick)
        errors.append(np.mean((policy.act(obs) - expert) ** 2))
        return expert

    rollout(task, scenarios, drive)
    return float(np.mean(errors))


@pytest.fixture(scope="module")
def cloned(tmp_path_factory):
    folder = tmp_path_factory.mktemp("runs")
    warm = config(
        warm_start={"episodes": 40, "rounds": 1, "epochs": 12},
        ppo={"actor_learning_rate": 1e-4, "actor_frozen_steps": 10**6, "learn_log_std": False},
    )
    cold = config()
    train(warm, folder / "warm", progress_bar=False)
    train(cold, folder / "cold", progress_bar=False)
    return warm, folder


@pytest.mark.slow
def test_the_warm_started_actor_imitates_the_planner_far_better_than_a_fresh_one(cloned):
    warm, folder = cloned
    task = LeftTurnTask(warm.env)
    planner = Planner(task)
    seed = 12345  # scenarios neither run trained on
    cloned_error = imitation_error(load_policy(folder / "warm"), task, planner, seed)
    fresh_error = imitation_error(load_policy(folder / "cold"), task, planner, seed)
    assert cloned_error < 0.25 * fresh_error
    record = json.loads((folder / "warm" / "warm_start.json").read_text())
    assert record["episodes"] == 80 and record["samples"] == 80 * 200
    assert record["collisions"] == 0  # the clone drove under the certified logic
    metrics = json.loads((folder / "warm" / "metrics.json").read_text())
    assert metrics["warm_start"] == record
    assert json.loads((folder / "cold" / "metrics.json").read_text())["warm_start"] is None


def checkpoints(run):
    kept = complete_checkpoints(run)
    assert len(kept) == 2
    return kept


def observation_statistics(path):
    with open(path, "rb") as handle:
        return pickle.load(handle).obs_rms


@pytest.mark.slow
def test_the_observation_statistics_stay_those_of_the_demonstrations(cloned, tmp_path):
    """Between the two checkpoints a run keeps (1,024 PPO steps apart) the statistics do not
    move after a warm start; left running (the control) they do."""
    _, folder = cloned
    frozen = [observation_statistics(p / "vecnormalize.pkl") for p in checkpoints(folder / "warm")]
    assert all(isinstance(s, FrozenRunningMeanStd) for s in frozen)
    np.testing.assert_array_equal(frozen[0].mean, frozen[1].mean)
    np.testing.assert_array_equal(frozen[0].var, frozen[1].var)
    thawed = config(warm_start={"episodes": 8, "rounds": 0, "epochs": 1, "freeze_obs_stats": False})
    train(thawed, tmp_path / "thawed", progress_bar=False)
    running = [
        observation_statistics(p / "vecnormalize.pkl") for p in checkpoints(tmp_path / "thawed")
    ]
    assert not isinstance(running[1], FrozenRunningMeanStd)
    assert np.abs(running[1].mean - running[0].mean).max() > 1e-3


def test_a_frozen_actor_does_not_move_while_the_value_function_learns(tmp_path, monkeypatch):
    frozen = config(
        ppo={"actor_learning_rate": 1e-3, "actor_frozen_steps": 10**6, "learn_log_std": False}
    )
    snapshots = {}
    original = TrainingMonitor._on_training_start

    def remember(self):
        original(self)
        snapshots["actor"] = actor_state(self.model)
        snapshots["critic"] = [p.detach().clone() for p in self.model.policy.value_net.parameters()]
        snapshots["log_std"] = self.model.policy.log_std.detach().clone()

    monkeypatch.setattr(TrainingMonitor, "_on_training_start", remember)
    train(frozen, tmp_path / "run", progress_bar=False)
    model = load_policy(tmp_path / "run").model
    for before, after in zip(snapshots["actor"], actor_state(model), strict=True):
        assert torch.equal(before, after)
    assert torch.equal(snapshots["log_std"], model.policy.log_std)
    moved = [
        not torch.equal(b, a)
        for b, a in zip(snapshots["critic"], model.policy.value_net.parameters(), strict=True)
    ]
    assert all(moved)


def test_the_actor_rate_is_zero_then_ramps_then_holds(tmp_path):
    c = config(
        ppo={"actor_learning_rate": 1e-4, "actor_frozen_steps": 1000, "actor_ramp_steps": 2000}
    )
    model = build_model(c, VecNormalize(LeftTurnVecEnv(2, config=c.env, seed=0)), None)
    assert len(model.policy.optimizer.param_groups) == 2
    assert model.actor_rate(0) == 0.0 and model.actor_rate(999) == 0.0
    assert model.actor_rate(2000) == pytest.approx(0.5e-4)
    assert model.actor_rate(3000) == model.actor_rate(10**7) == pytest.approx(1e-4)
    plain = build_model(config(), VecNormalize(LeftTurnVecEnv(2, config=c.env, seed=0)), None)
    assert len(plain.policy.optimizer.param_groups) == 1  # Table II: one rate for everything


def test_a_frozen_actor_without_its_own_rate_thaws_to_the_configured_one():
    """Value-function pre-training from a random start: ``actor_frozen_steps`` alone (it once
    did nothing without ``actor_learning_rate``)."""
    c = config(ppo={"actor_frozen_steps": 1000, "learning_rate": 3e-4})
    model = build_model(c, VecNormalize(LeftTurnVecEnv(2, config=c.env, seed=0)), None)
    assert len(model.policy.optimizer.param_groups) == 2
    assert model.actor_rate(999) == 0.0
    assert model.actor_rate(1000) == pytest.approx(3e-4)


@pytest.mark.slow
def test_an_interrupted_warm_started_run_resumes_with_its_parameter_groups(
    tmp_path, interrupted_training
):
    c = replace(
        config(
            warm_start={"episodes": 16, "rounds": 0, "epochs": 1},
            ppo={"actor_learning_rate": 1e-4, "actor_ramp_steps": 1000},
        ),
        timesteps=4096,
    )
    interrupted_training(c, tmp_path / "run", at=2048)
    metrics = train(c, tmp_path / "run", resume=True, progress_bar=False)
    assert metrics["timesteps"] >= 4096
    assert metrics["warm_start"]["episodes"] == 16
    model = load_policy(tmp_path / "run").model
    assert len(model.policy.optimizer.param_groups) == 2


def test_bad_warm_start_and_actor_settings_are_named():
    with pytest.raises(ConfigError, match="episodes"):
        config(warm_start={"episodes": -1})
    with pytest.raises(ConfigError, match="actor_learning_rate"):
        config(ppo={"actor_learning_rate": 0.0})
    with pytest.raises(ConfigError, match="actor_frozen_steps"):
        config(ppo={"actor_frozen_steps": -5})
    with pytest.raises(ConfigError, match="warm_start"):
        config(warm_start={"episode": 3})
    with pytest.raises(ConfigError, match=r"warm_start\.planner"):
        config(warm_start={"planner": {"lateral": 2.5}})
    with pytest.raises(ConfigError, match="accel_lat"):
        config(warm_start={"planner": {"accel_lat": -1.0}})


def test_the_warm_start_demonstrates_with_its_configured_planner(tmp_path, monkeypatch):
    import safeswitch.training.warm_start as ws

    seen = []

    class Recording(Planner):
        def __init__(self, task, planner_config=None):
            seen.append(planner_config)
            super().__init__(task, planner_config)

    monkeypatch.setattr(ws, "Planner", Recording)
    run = config(
        warm_start={"episodes": 4, "rounds": 0, "epochs": 1, "planner": {"accel_lat": 2.6}}
    )
    assert run.warm_start.planner.accel_lat == 2.6
    train(replace(run, timesteps=1024), tmp_path / "run", progress_bar=False)
    assert [c.accel_lat for c in seen] == [2.6]
    saved = (tmp_path / "run" / "config.yaml").read_text()
    assert "accel_lat: 2.6" in saved


@pytest.mark.slow
def test_the_warm_start_clones_in_traffic_with_the_traffic_observation(tmp_path):
    """In traffic the demonstrations are driven in the training task, so the clone learns on
    the observation it will see (the paper's six values and the nearest vehicles), and the
    observation statistics it keeps are those of that observation."""
    run = config(
        traffic={"preset": "light", "horizon_s": 4.0, "observed": 2},
        warm_start={"episodes": 8, "rounds": 1, "epochs": 2},
    )
    train(replace(run, timesteps=1024), tmp_path / "run", progress_bar=False)
    report = json.loads((tmp_path / "run" / "warm_start.json").read_text())
    assert report["episodes"] == 16 and report["samples"] == 16 * 200
    with open(tmp_path / "run" / "vecnormalize.pkl", "rb") as handle:
        stats = pickle.load(handle).obs_rms
    assert stats.mean.shape == (6 + 2 * 6,)
    assert np.all(stats.var[6:] > 0)  # the vehicles' features vary across the demonstrations


def test_annealed_exploration_noise_follows_its_schedule_and_is_the_rollouts(tmp_path, monkeypatch):
    """``log_std_final``: the fixed noise falls linearly over the run, one value per rollout,
    and the update after a rollout sees the noise its actions were drawn with."""
    annealed = config(ppo={"learn_log_std": False, "log_std_init": 0.0, "log_std_final": -2.0})
    seen = []
    original = SwitchPPO.train

    def record(self):
        seen.append(float(self.policy.log_std.detach().mean()))
        original(self)

    monkeypatch.setattr(SwitchPPO, "train", record)
    train(annealed, tmp_path / "run", progress_bar=False)
    # 2,048 steps in rollouts of 1,024: the first at the start, the second half-way
    assert seen == pytest.approx([0.0, -1.0])
    model = load_policy(tmp_path / "run").model
    assert float(model.policy.log_std.detach().mean()) == pytest.approx(-1.0)


def test_an_annealed_learning_rate_falls_linearly_over_the_run_and_is_saved(tmp_path, monkeypatch):
    """``learning_rate_final``: each update's Adam step size is on the line from
    ``learning_rate`` to it, and a loaded (or resumed) model keeps the schedule."""
    annealed = config(ppo={"learning_rate": 1e-3, "learning_rate_final": 2e-4})
    seen = []
    original = SwitchPPO.train

    def record(self):
        original(self)
        seen.append([group["lr"] for group in self.policy.optimizer.param_groups])

    monkeypatch.setattr(SwitchPPO, "train", record)
    train(annealed, tmp_path / "run", progress_bar=False)
    # 2,048 steps in rollouts of 1,024: updated half-way through the run, then at its end
    assert seen == [pytest.approx([6e-4]), pytest.approx([2e-4])]
    model = load_policy(tmp_path / "run").model
    assert model.lr_schedule(0.25) == pytest.approx(4e-4)
    with pytest.raises(ConfigError, match=r"learning_rate_final .*-0\.1"):
        config(ppo={"learning_rate_final": -0.1})


def test_an_annealed_noise_that_would_also_be_learned_is_refused():
    with pytest.raises(ConfigError, match="log_std_final"):
        config(ppo={"learn_log_std": True, "log_std_final": -2.0})


def sampled(model, observations):
    """Exploring actions of ``model`` for ``observations`` (no new noise weights drawn)."""
    with torch.no_grad():
        actions, _, _ = model.policy(torch.as_tensor(observations))
    return actions.numpy()


def test_gsde_explores_consistently_until_its_noise_is_drawn_again():
    """``use_sde``: the same observation gets the same exploring action until the noise weights
    are drawn again (a Gaussian's draws differ every step), and the deterministic policy is
    the mean either way."""
    c = config(policy={"use_sde": True, "log_std_init": -1.0})
    env = VecNormalize(LeftTurnVecEnv(4, config=c.env, seed=0))
    model = build_model(c, env, None)
    assert model.use_sde and model.sde_sample_freq == -1
    observations = np.random.default_rng(0).normal(size=(4, 6)).astype(np.float32)
    model.policy.reset_noise(4)
    first, again = sampled(model, observations), sampled(model, observations)
    np.testing.assert_array_equal(first, again)
    with torch.no_grad():
        mean = model.policy.get_distribution(torch.as_tensor(observations)).mode().numpy()
    assert np.all(np.abs(first - mean) > 1e-6)
    model.policy.reset_noise(4)
    assert np.all(np.abs(sampled(model, observations) - first) > 1e-6)
    plain = build_model(config(), env, None)
    assert not np.allclose(sampled(plain, observations), sampled(plain, observations))


def test_an_annealed_noise_scales_gsde_and_its_resampling_is_checked(tmp_path, monkeypatch):
    """The annealed noise sets gSDE's log std (the matrix the noise weights are drawn with)
    before each rollout; a resampling interval without gSDE, or of 0, is refused."""
    annealed = config(
        policy={"use_sde": True, "learn_log_std": False, "log_std_init": -1.0,
                "log_std_final": -3.0, "sde_sample_freq": 16}
    )  # fmt: skip
    seen = []
    original = SwitchPPO.train

    def record(self):
        log_std = self.policy.log_std.detach()
        seen.append((tuple(log_std.shape), float(log_std.min()), float(log_std.max())))
        original(self)

    monkeypatch.setattr(SwitchPPO, "train", record)
    train(annealed, tmp_path / "run", progress_bar=False)
    assert seen == [((128, 1), -1.0, -1.0), ((128, 1), -2.0, -2.0)]
    model = load_policy(tmp_path / "run").model
    assert model.use_sde and model.sde_sample_freq == 16
    with pytest.raises(ConfigError, match=r"sde_sample_freq.*use_sde.*16"):
        config(policy={"sde_sample_freq": 16})
    with pytest.raises(ConfigError, match=r"sde_sample_freq.*\b0\b"):
        config(policy={"use_sde": True, "sde_sample_freq": 0})
