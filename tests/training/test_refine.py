"""The pipeline's search-guided refinement (``refine:``, :mod:`safeswitch.training.refine`):
it fits the actor toward the search's labels, keeps the iteration its criterion ranks first,
makes that the run's policy with PPO's kept beside it, leaves PPO's policy in place when
interrupted, and is refused where its search cannot run."""

import csv
import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3.common.callbacks import BaseCallback

from safeswitch.core.config import ConfigError, from_dict, to_dict
from safeswitch.evaluation.search import SEGMENT_S, family_of_drivers
from safeswitch.io import write_policy_files
from safeswitch.leftturn.traffic import LeftTurnTrafficTask
from safeswitch.training import refine as refine_module
from safeswitch.training import train
from safeswitch.training.config import (
    RefineConfig,
    TrainConfig,
    dump_config,
    load_config,
    write_config_with_files,
)
from safeswitch.training.policies import load_policy, resolve_model_dir, run_config_path
from safeswitch.training.refine import refine_run, search_task
from safeswitch.training.run import evaluate_trained
from safeswitch.training.validation import ValidationSet
from safeswitch.training.warm_start import action_error

SMALL_REFINE = RefineConfig(
    iterations=2, scenes=60, population=16, rounds=3, speed_scenes=40, speed_population=8,
    speed_rounds=3,
)  # fmt: skip


def shipped_run(folder, policy="certified"):
    """The shipped policy ``policy`` as a finished run in ``folder``."""
    folder.mkdir(parents=True)
    source = resolve_model_dir(policy)
    for name in ("model.zip", "vecnormalize.pkl"):
        shutil.copyfile(source / name, folder / name)
    # its config.yaml with the file it names (its go predictor)
    write_config_with_files(folder, dump_config(load_config(run_config_path(source))))
    return folder


def slowed_run(folder, by=0.3):
    """The shipped `certified` policy as a run, its action lowered by ``by`` wherever it is not
    clipped (the action head's bias): a policy the small searches below can beat, so that the
    fine-tune phase, which starts from the search's best iteration, has one to start from (the
    shipped policy itself is faster than what those searches find)."""
    run = shipped_run(folder)
    policy = load_policy(run)
    with torch.no_grad():
        policy.model.policy.action_net.bias.sub_(by)
    write_policy_files(run, policy.model, policy.normalizer)
    return run


def small_config(**refine):
    config = load_config("certified")
    return replace(
        config,
        refine=replace(SMALL_REFINE, **refine),
        validation=replace(config.validation, episodes=200),
    )


def full_key(config, row):
    """The run's criterion on a ``refine.csv`` row: no collision, the least excess over the
    comfort and safety budgets (the recipe limits no speeding), then efficiency."""
    comfort = config.constraints.comfort.selection_budget
    safety = config.constraints.safety.selection_budget
    episodes = config.validation.episodes
    excess = max(0.0, float(row["comfort_violation_fraction"]) / comfort - 1.0)
    excess += max(0.0, int(row["safety_activation_episodes"]) / episodes / safety - 1.0)
    return (-int(row["collisions"]), -excess, float(row["mean_efficiency"]))


def rows_of(run):
    with open(run / "refine.csv", newline="", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


@pytest.fixture(scope="module")
def refined(tmp_path_factory):
    run = shipped_run(tmp_path_factory.mktemp("refine") / "run")
    original = (run / "model.zip").read_bytes()
    config = small_config()
    return run, config, refine_run(run, config), original


@pytest.mark.slow
def test_an_iteration_fits_the_actor_toward_the_searchs_labels(refined):
    run = refined[0]
    rows = rows_of(run)
    first = rows[1]
    assert int(first["fixed"]) + int(first["sped_up"]) > 0  # the search improved some scenes
    assert float(first["mse"]) < float(first["mse_before"])


@pytest.mark.slow
def test_the_stage_keeps_the_iteration_its_criterion_ranks_first(refined):
    run, config, record, _ = refined
    rows = rows_of(run)
    assert [int(r["iteration"]) for r in rows] == [0, 1, 2]
    assert [int(r["selected"]) for r in rows].count(1) == 1
    chosen = next(int(r["iteration"]) for r in rows if r["selected"] == "1")
    assert record["selected_iteration"] == chosen
    assert full_key(config, rows[chosen]) == max(full_key(config, r) for r in rows)


@pytest.mark.slow
def test_the_selected_iteration_is_the_runs_policy_and_ppos_is_kept(refined):
    run, config, record, original = refined
    chosen = record["selected_iteration"]
    if chosen == 0:
        assert (run / "model.zip").read_bytes() == original
        assert not (run / "ppo").exists()
    else:
        assert (run / "ppo" / "model.zip").read_bytes() == original
        assert (run / "model.zip").read_bytes() != original
    # what the stage reports is what the run's policy now does
    summary = ValidationSet(config).summary(load_policy(run))
    assert summary["mean_efficiency"] == pytest.approx(record["validation"]["mean_efficiency"])
    assert summary["cleared_episodes"] == record["validation"]["cleared_episodes"]


@pytest.mark.slow
def test_an_interrupted_stage_leaves_ppos_policy(tmp_path, monkeypatch):
    run = shipped_run(tmp_path / "run")
    original = (run / "model.zip").read_bytes()
    real = refine_module.refine_iteration

    def interrupted(task, policy, config, seed, iteration):
        if iteration == 2:
            raise KeyboardInterrupt
        return real(task, policy, config, seed, iteration)

    monkeypatch.setattr(refine_module, "refine_iteration", interrupted)
    with pytest.raises(KeyboardInterrupt):
        refine_run(run, small_config())
    assert (run / "model.zip").read_bytes() == original
    assert not (run / "refine.csv").exists() and not (run / "ppo").exists()


@pytest.mark.slow
def test_the_pipeline_evaluates_the_refined_policy(tmp_path):
    config = load_config("certified")
    small = replace(
        config, timesteps=4096, n_envs=16, eval_episodes=100, torch_threads=1,
        validation=replace(config.validation, start=2048, every=2048, episodes=100),
        refine=replace(SMALL_REFINE, iterations=1, scenes=20, speed_scenes=10),
    )  # fmt: skip
    run = tmp_path / "run"
    metrics = train(small, run, progress_bar=False)
    assert metrics["refined"]["iterations"] == 1
    chosen = metrics["refined"]["selected_iteration"]
    assert rows_of(run)[chosen]["selected"] == "1"
    again = evaluate_trained(load_policy(run), small, small.eval_episodes, small.eval_seed)
    assert metrics["evaluation"]["mean_efficiency"] == pytest.approx(again["mean_efficiency"])


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"env": {"switching": "paper"}}, "env has 'paper'"),
        ({"deploy_switching": "paper"}, "deploy_switching has 'paper'"),
        ({"env": {"scenario": "cut"}}, "needs random scenarios"),
        ({"refine": {"iterations": 1, "env": {"switching": "paper"}}}, "refine.env has 'paper'"),
    ],
)
def test_refinement_is_refused_where_its_search_cannot_run(change, message):
    base = to_dict(load_config("certified"))
    base["refine"] = {"iterations": 1}
    for key, value in change.items():
        if isinstance(value, dict):
            base[key] = {**base[key], **value}
        else:
            base[key] = value
    with pytest.raises(ConfigError, match=rf"refine\.iterations .*{message}.*got 1"):
        from_dict(TrainConfig, base)


@pytest.mark.slow
def test_in_traffic_the_stage_searches_the_traffic_scene_and_fits_its_labels(tmp_path):
    # the scene with traffic from every leg is deterministic given its start too: the search
    # runs there, and the fitted policy is validated on the run's traffic scenes
    run = shipped_run(tmp_path / "run", "traffic-certified")
    config = load_config("traffic_certified")
    config = replace(
        config,
        refine=replace(SMALL_REFINE, iterations=1, scenes=30, speed_scenes=10),
        validation=replace(config.validation, episodes=60),
    )
    task = search_task(config)
    assert isinstance(task, LeftTurnTrafficTask)
    assert task.traffic == ValidationSet(config).task.traffic
    record = refine_run(run, config)
    first = rows_of(run)[1]
    assert int(first["failing"]) > 0 and int(first["fixed"]) + int(first["sped_up"]) > 0
    assert float(first["mse"]) < float(first["mse_before"])
    chosen = record["selected_iteration"]
    summary = ValidationSet(config).summary(load_policy(run))
    assert summary["cleared_episodes"] == record["validation"]["cleared_episodes"]
    assert (chosen == 0) == (not (run / "ppo").exists())


@pytest.mark.parametrize("interval", [5, 15])
def test_the_structured_drivers_seed_the_search_at_any_decision_interval(interval):
    # each decision takes the driver's action of the half-second segment it starts in: at 0.1 s
    # five decisions per segment, at 0.3 s (traffic's hold) the segments do not divide
    episode = replace(load_config("certified").env.episode, decision_interval=interval)
    decisions = episode.horizon_ticks // interval
    drivers = refine_module._drivers(episode)
    family = family_of_drivers(round(episode.horizon_s / SEGMENT_S))
    assert drivers.shape == (len(family), decisions)
    starts = np.arange(decisions) * interval * episode.dt  # [s]
    np.testing.assert_array_equal(drivers, family[:, (starts / SEGMENT_S + 1e-9).astype(int)])


def test_on_a_two_pedal_scene_the_structured_drivers_seed_the_search_as_throttles(monkeypatch):
    # the drivers' closed throttle (-1) is a coast, not the full brake: mapped to (a + 1) / 2
    base = small_config(speed_scenes=0, scenes=40)
    env = replace(base.env, controllers=replace(base.env.controllers, learned_brake=True))
    config = replace(base, env=env)
    seeded = []

    def recording(task, scenarios, start, **kwargs):
        seeded.append(kwargs["seeds"])
        return np.full(len(start), np.nan), np.zeros(len(start), np.int64), start

    monkeypatch.setattr(refine_module, "search_sequences", recording)
    monkeypatch.setattr(refine_module, "fit_actor", lambda *args, **kwargs: None)
    task = search_task(config)
    refine_module.refine_iteration(task, load_policy("certified"), config.refine, 4, 1)
    throttles = refine_module._drivers(task.config.episode)
    np.testing.assert_array_equal(seeded[0], (throttles + 1.0) / 2.0)
    assert seeded[0].min() == 0.0 and throttles.min() == -1.0


def test_refinement_settings_are_checked_by_name():
    with pytest.raises(ConfigError, match=r"refine\.scenes.*got 0"):
        RefineConfig(scenes=0)
    with pytest.raises(ConfigError, match=r"refine\.knot.*got 0"):
        RefineConfig(knot=0)
    with pytest.raises(ConfigError, match=r"refine\.lock_s.*got -1"):
        RefineConfig(lock_s=-1.0)


@pytest.mark.parametrize("allowed", [0, 3])
def test_a_dirty_clear_is_a_label_only_where_the_policy_never_clears(monkeypatch, allowed):
    config = small_config(uncleared_dirty_ticks=allowed, speed_scenes=0, scenes=200)
    task, policy = search_task(config), load_policy("certified")

    def stub(task, scenarios, start, **kwargs):  # every failing scene cleared at 5 s, 3 dirty ticks
        return np.full(len(start), 5.0), np.full(len(start), 3), start.copy()

    monkeypatch.setattr(refine_module, "search_sequences", stub)
    monkeypatch.setattr(refine_module, "fit_actor", lambda *args, **kwargs: None)
    done = refine_module.refine_iteration(task, policy, config.refine, seed=7, iteration=1)
    n = config.refine.scenes
    ids = refine_module.REFINE_ENV_OFFSET + np.arange(n)
    scenes = task.draw_scenarios(7, ids, np.zeros(n, dtype=np.int64))
    _, clear, _, _ = refine_module.policy_actions(task, scenes, policy.as_policy())
    never = int(np.isnan(clear).sum())
    assert never > 0 and done["failing"] > never  # some never clear, some clear dirty
    assert done["fixed"] == (never if allowed >= 3 else 0)


def test_a_lock_keeps_the_policys_own_decisions_before_its_first_dirty_tick(monkeypatch):
    # 200 scenes: enough failing ones for one whose first dirty tick comes after the lock
    config = small_config(lock_s=1.0, scenes=200)
    task, policy = search_task(config), load_policy("certified")
    episode = task.config.episode
    searched, real = [], refine_module.search_sequences

    def recording(task, scenarios, start, **kwargs):
        result = real(task, scenarios, start, **kwargs)
        if kwargs.get("frozen") is not None:
            searched.append((scenarios, start, kwargs["frozen"], result[2]))
        return result

    monkeypatch.setattr(refine_module, "search_sequences", recording)
    monkeypatch.setattr(refine_module, "fit_actor", lambda *args, **kwargs: None)
    done = refine_module.refine_iteration(task, policy, config.refine, seed=4, iteration=1)
    assert len(searched) == 1 and done["failing"] > 0  # the failing scenes', not the speed-ups'
    scenarios, start, frozen, labels = searched[0]
    _, _, _, first = refine_module.policy_actions(task, scenarios, policy.as_policy())
    lock = round(1.0 / episode.dt)
    expected = np.where(first >= 0, np.maximum(0, (first - lock) // episode.decision_interval), 0)
    np.testing.assert_array_equal(frozen, expected)
    assert (frozen > 0).any()
    for i, held in enumerate(frozen):
        np.testing.assert_array_equal(labels[i, :held], start[i, :held])


def test_a_mean_beyond_the_bound_its_label_sits_on_is_no_error():
    mean = torch.tensor([[1.8], [0.5], [1.8], [-1.4], [-1.4]])
    label = torch.tensor([[1.0], [1.0], [0.3], [-1.0], [0.0]])
    clipped = action_error(mean, label, clipped=True)
    np.testing.assert_allclose(clipped.numpy()[:, 0], [0.0, -0.5, 1.5, 0.0, -1.4], atol=1e-6)
    np.testing.assert_allclose(action_error(mean, label, clipped=False), mean - label)


def test_the_search_may_run_under_a_stricter_filter_than_the_deployed_one():
    config = small_config(
        env={
            "certified": {"time_margin_s": 0.3, "progress_factor": 1.15},
            "rewards": {"comfort_accel_lat": 2.7},
        }
    )
    searched = search_task(config).config.certified
    assert (searched.time_margin_s, searched.progress_factor) == (0.3, 1.15)
    assert searched.zone_margin_m == 0.9  # the recipe's, unchanged
    deployed = ValidationSet(config).task.config.certified
    assert (deployed.time_margin_s, deployed.progress_factor) == (0.1, 1.05)
    assert search_task(config).config.rewards.comfort_accel_lat == 2.7
    assert ValidationSet(config).task.config.rewards.comfort_accel_lat == 3.0
    assert search_task(small_config()).config.certified == deployed


def test_a_bad_setting_of_the_searchs_filter_is_refused_by_name():
    base = to_dict(load_config("certified"))
    base["refine"] = {"iterations": 1, "env": {"certified": {"time_margin": 0.4}}}
    with pytest.raises(ConfigError, match="time_margin"):
        from_dict(TrainConfig, base)
    base["refine"] = {"iterations": 1, "env": {"certified": {"progress_factor": 3.0}}}
    with pytest.raises(ConfigError, match=r"progress_factor.*3\.0"):
        from_dict(TrainConfig, base)


FINETUNE = {
    "timesteps": 4096, "n_envs": 16,
    "policy": {"learn_log_std": False, "log_std_init": -2.0, "log_std_final": -2.0,
               "actor_learning_rate": 1e-4},
    "constraints": {"comfort": {"start": 0}, "safety": {"start": 0}, "uncleared": {"start": 0}},
    "validation": {"start": 2048, "every": 2048},
}  # fmt: skip


@pytest.fixture(scope="module")
def finetuned(tmp_path_factory):
    run = slowed_run(tmp_path_factory.mktemp("finetune") / "run")
    original = (run / "model.zip").read_bytes()
    config = small_config(iterations=2, finetune=FINETUNE)
    return run, config, refine_run(run, config, train), original


@pytest.mark.slow
def test_the_fine_tune_phase_trains_the_fastest_searched_iteration_under_the_constraints(
    finetuned,
):
    run, config, record, _ = finetuned
    rows = rows_of(run)
    assert [r["stage"] for r in rows] == ["ppo", "search", "search", "finetune"]
    searched = [r for r in rows if r["stage"] == "search" and r["collisions"] == "0"]
    fastest = max(searched, key=lambda r: float(r["mean_efficiency"]))
    assert record["selected_iteration"] == int(fastest["iteration"])  # budgets aside
    phase = run / "refine" / "finetune"
    started = json.loads((phase / "warm_start.json").read_text(encoding="utf-8"))
    assert Path(started["policy"]) == run / "refine" / "searched"
    tuned = load_config(phase / "config.yaml")
    assert tuned.timesteps == 4096 and tuned.policy.log_std_init == -2.0
    assert tuned.constraints.safety.start == 0 and tuned.constraints.safety.budget == 0.02
    assert tuned.refine.iterations == 0 and tuned.eval_episodes == 0
    assert tuned.seed == config.seed and tuned.validation.episodes == 200
    assert record["finetune"]["timesteps"] == 4096


@pytest.mark.slow
def test_the_run_keeps_the_fine_tuned_policy_only_if_it_ranks_at_least_as_high_as_ppos(
    finetuned,
):
    run, config, record, original = finetuned
    rows = rows_of(run)
    ppo, tuned = rows[0], rows[-1]
    kept = "finetune" if full_key(config, tuned) >= full_key(config, ppo) else "ppo"
    assert record["kept"] == kept
    assert [r["stage"] for r in rows if r["selected"] == "1"] == [kept]
    if kept == "finetune":
        phase = run / "refine" / "finetune"
        assert (run / "model.zip").read_bytes() == (phase / "model.zip").read_bytes()
        assert (run / "ppo" / "model.zip").read_bytes() == original
    else:
        assert (run / "model.zip").read_bytes() == original
    summary = ValidationSet(config).summary(load_policy(run))
    assert summary["mean_efficiency"] == pytest.approx(record["validation"]["mean_efficiency"])


class InterruptAt(BaseCallback):
    """Ctrl-C once PPO has made ``steps`` steps."""

    def __init__(self, steps):
        super().__init__()
        self.steps = steps

    def _on_step(self):
        if self.num_timesteps >= self.steps:
            raise KeyboardInterrupt
        return True


@pytest.mark.slow
def test_an_interrupted_fine_tune_phase_continues_from_its_checkpoint(tmp_path, capsys):
    run = slowed_run(tmp_path / "run")
    original = (run / "model.zip").read_bytes()
    config = small_config(iterations=1, finetune=FINETUNE)
    with pytest.raises(KeyboardInterrupt):
        refine_run(run, config, lambda *a, **k: train(*a, **k, callbacks=[InterruptAt(2048)]))
    assert f"safeswitch train --resume --out {run}" in capsys.readouterr().err
    assert (run / "model.zip").read_bytes() == original  # PPO's still the run's
    phase = run / "refine" / "finetune"
    interrupted = list((phase / "checkpoints").iterdir())
    assert interrupted
    searched = load_policy(run / "refine" / "searched").model.policy.state_dict()
    record = refine_run(run, config, train)
    again = load_policy(run / "refine" / "searched").model.policy.state_dict()
    assert all(torch.equal(searched[k], again[k]) for k in searched)  # the seeded search
    assert record["finetune"]["timesteps"] == 4096
    with open(phase / "progress.csv", newline="", encoding="utf-8") as handle:
        steps = [int(row["timesteps"]) for row in csv.DictReader(handle)]
    assert steps == sorted(steps) and steps[0] <= 2048 and steps[-1] == 4096  # not from 0 again
    # interrupted after the phase finished: --resume puts PPO's policy back and runs the
    # stage again; the phase is not trained again
    for name in ("model.zip", "vecnormalize.pkl"):
        if (run / "ppo").is_dir():
            shutil.copyfile(run / "ppo" / name, run / name)
    assert (run / "model.zip").read_bytes() == original
    progress = (phase / "progress.csv").read_bytes()
    assert refine_run(run, config, train)["finetune"] == record["finetune"]
    assert (phase / "progress.csv").read_bytes() == progress


def test_the_fine_tune_phase_needs_the_pipelines_train(tmp_path):
    with pytest.raises(ValueError, match="needs the pipeline's train"):
        refine_run(tmp_path, small_config(iterations=1, finetune=FINETUNE))


def test_fine_tune_settings_are_checked_by_name():
    base = to_dict(load_config("certified"))
    cases = [
        ({"iterations": 0, "finetune": {"timesteps": 10}}, r"refine\.finetune.*needs iterations"),
        ({"iterations": 1, "finetune": {"policy": {}}}, r"refine\.finetune.*names timesteps"),
        ({"iterations": 1, "finetune": {"timesteps": 10, "warm_start": {"policy": "x"}}},
         r"refine\.finetune\.warm_start.*set by the stage"),
        ({"iterations": 1, "finetune": {"timesteps": 10, "polcy": {}}}, r"refine\.finetune.*polcy"),
        ({"iterations": 1, "finetune": {"timesteps": -5}}, r"refine\.finetune.*timesteps.*-5"),
    ]  # fmt: skip
    for refine, message in cases:
        base["refine"] = refine
        with pytest.raises(ConfigError, match=message):
            from_dict(TrainConfig, base)


@pytest.mark.slow
def test_safeswitch_train_runs_the_phase_and_says_which_policy_it_kept(tmp_path, capsys):
    from safeswitch.cli import main

    run = tmp_path / "run"
    start = slowed_run(tmp_path / "slowed")
    settings = [
        "timesteps=2048", "n_envs=16", "eval_episodes=50", f"warm_start.policy={start}",
        "validation={start: 1024, every: 1024, episodes: 200}",
        "refine={iterations: 2, scenes: 60, population: 16, rounds: 3, speed_scenes: 40, "
        "speed_population: 8, speed_rounds: 3, finetune: {timesteps: 2048, n_envs: 16, "
        "validation: {start: 1024, every: 1024}}}",
    ]  # fmt: skip
    args = ["train", "--config", "certified", "--out", str(run), "--no-progress"]
    assert main([*args, *(x for s in settings for x in ("--set", s))]) == 0
    out = capsys.readouterr().out
    refined = json.loads((run / "metrics.json").read_text(encoding="utf-8"))["refined"]
    assert refined["selected_iteration"] > 0  # the search beat PPO's policy: the phase ran
    assert (run / "refine" / "finetune" / "metrics.json").is_file()
    tuned = refined["finetune"]["selected_timesteps"]
    kept = "kept" if refined["kept"] == "finetune" else "not better than PPO's"
    line = (
        f"iteration {refined['selected_iteration']} of 2 fine-tuned by PPO (selected at "
        f"{tuned:,} steps), {kept} (refine.csv)"
    )
    assert line in out
