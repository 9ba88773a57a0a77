"""One training pipeline for every plant (issue #39, item 1): the left turn and any Gymnasium
plant go through ``safeswitch.training.train``; validation and best-policy selection, resume
and the configuration checks hold for a plant of the user's as for the left turn."""

import csv
import json

import gymnasium as gym
import pytest

from safeswitch.core.config import ConfigError
from safeswitch.core.wrappers import SafeSwitch
from safeswitch.training import train
from safeswitch.training.config import EnvTrainConfig, TrainConfig, ValidationConfig
from safeswitch.training.pipeline import plant_for
from tests.core import user_plant


@pytest.fixture
def wall():
    user_plant.register()  # another test may have made the module forgotten
    return user_plant


def wall_config(**changes):
    base = dict(env_id=user_plant.ENV_ID, switching=user_plant.LOGIC, timesteps=2048, n_envs=2,
                checkpoint_every=1024, eval_episodes=4)  # fmt: skip
    return EnvTrainConfig(**{**base, **changes})


def test_a_plant_is_validated_and_its_best_policy_becomes_the_runs(wall, tmp_path):
    config = wall_config(
        validation=ValidationConfig(every=512, episodes=3, seed=77,
                                    criterion="collisions_then_return"),
    )  # fmt: skip
    run = tmp_path / "run"
    metrics = train(config, run, progress_bar=False)
    with open(run / "validation.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 4  # after the rollouts reaching 512, 1024, 1536 and 2048 steps
    assert set(rows[0]) >= {"timesteps", "mean_return", "failures", "safety_share", "best"}
    best = [r for r in rows if r["best"] == "1"][-1]
    selected = metrics["selected"]
    assert selected["best_timesteps"] == int(best["timesteps"])
    assert selected["best_key"] == [-float(best["failures"]), float(best["mean_return"])]
    # the best validated policy is the run's policy; the last one is kept beside it
    assert (run / "model.zip").read_bytes() == (run / "best" / "model.zip").read_bytes()
    assert (run / "last" / "model.zip").is_file()
    assert metrics["evaluation"]["episodes"] == 4 and "failures" in metrics["evaluation"]
    assert json.loads((run / "metrics.json").read_text()) == metrics


def test_make_env_trains_the_plant_the_caller_builds(wall, tmp_path):
    built = []

    def make_env():
        built.append(1)
        env = gym.make(wall.ENV_ID)
        return SafeSwitch(env, wall.full_brake, wall.LOGIC, penalty=-1.0)

    metrics = train(wall_config(timesteps=512, eval_episodes=2), tmp_path / "run",
                    progress_bar=False, make_env=make_env)  # fmt: skip
    assert len(built) == 2 + 1  # the two training environments and the evaluation's
    assert metrics["training"]["episodes"] > 0 and metrics["evaluation"]["episodes"] == 2


def test_what_only_the_left_turn_has_is_refused_on_a_plant(wall):
    for validation, needle in (
        (ValidationConfig(every=512, switching="none"), "validation.switching"),
        (ValidationConfig(every=512, criterion="constraints_then_return"),
         "validation.criterion"),
    ):  # fmt: skip
        with pytest.raises(ConfigError, match=needle):
            wall_config(validation=validation)
    with pytest.raises(ValueError, match="make_env builds a Gymnasium plant"):
        plant_for(TrainConfig(), make_env=lambda: gym.make(wall.ENV_ID))


def test_an_interrupted_validated_run_resumes_with_its_best_policy(
    wall, tmp_path, interrupted_training
):
    config = wall_config(validation=ValidationConfig(every=512, episodes=2, seed=5),
                         checkpoint_every=512)  # fmt: skip
    run = tmp_path / "run"
    interrupted_training(config, run, at=1024)
    best_before = json.loads((run / "best" / "state.json").read_text())
    metrics = train(config, run, resume=True, progress_bar=False)
    assert metrics["timesteps"] == 2048
    assert metrics["selected"]["best_key"] >= best_before["best_key"]
    with open(run / "validation.csv", newline="") as handle:
        assert [int(r["timesteps"]) for r in csv.DictReader(handle)][-1] == 2048


def test_an_evaluation_counts_why_the_safety_controller_acted_and_each_named_cost(wall):
    from safeswitch.training.generic import make_supervised_env, run_episodes

    def throttle(obs):  # full throttle: fast enough to speed, then meets the wall's logic
        return [user_plant.MAX_ACCEL]

    env = make_supervised_env(wall.ENV_ID, wall.LOGIC, -1.0)
    summary = run_episodes(env, throttle, 3, seed=5)
    # the same episodes counted here, step by step
    speeding = speeding_braked = too_close = 0
    for k in range(3):
        env.reset(seed=5 + k)
        done = False
        while not done:
            *_, terminated, truncated, info = env.step(throttle(None))
            speeding += info["costs"]["speeding"] > 0
            speeding_braked += info["costs"]["speeding"] > 0 and info["safety_active"]
            too_close += info["reason"] == "too_close"
            done = terminated or truncated
    env.close()
    assert speeding > speeding_braked > 0 and too_close > 0
    assert summary["cost_steps"] == {"speeding": speeding}
    assert summary["safety_cost_steps"] == {"speeding": speeding_braked}
    assert summary["safety_reasons"] == {"too_close": too_close}
    assert sum(summary["safety_reasons"].values()) == summary["safety_activation_steps"]
