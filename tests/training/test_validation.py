"""Model selection on a validation set: the run's policy is the best validated one."""

import csv
import json

import numpy as np
import pytest
import torch
from stable_baselines3.common.callbacks import BaseCallback

from safeswitch.cli import main
from safeswitch.core.config import ConfigError, from_dict
from safeswitch.evaluation.evaluate import run_controller
from safeswitch.io import complete_checkpoints
from safeswitch.leftturn.make import build_task
from safeswitch.training import train
from safeswitch.training.config import TrainConfig
from safeswitch.training.policies import load_policy
from safeswitch.training.validation import Validator, copied

SMALL = {
    "timesteps": 4096,
    "n_envs": 8,
    "seed": 3,
    "checkpoint_every": 2048,
    "eval_episodes": 20,
    "torch_threads": 1,
    "validation": {"every": 1024, "episodes": 30, "seed": 2_000_003},
    "env": {"episode": {"learned_scope": "episode", "horizon_s": 2.0}},
}


def rows(run):
    with open(run / "validation.csv", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


def validation_return(run, config):
    """The run's policy on the validation scenarios, evaluated afresh from its files."""
    task = build_task(None, config.env)
    v = config.validation
    scenarios = task.draw_scenarios(v.seed, np.arange(v.episodes), np.zeros(v.episodes, int))
    result, _ = run_controller(task, load_policy(run).as_policy(), scenarios, trace=False)
    return float(result.episode_return.mean())


def test_the_best_validated_policy_becomes_the_runs_policy(tmp_path):
    config = from_dict(TrainConfig, SMALL)
    run = tmp_path / "run"
    metrics = train(config, run, progress_bar=False)
    table = rows(run)
    assert [int(r["timesteps"]) for r in table] == [1024, 2048, 3072, 4096]
    returns = [float(r["mean_return"]) for r in table]
    # a row is flagged exactly when it beats every earlier one
    assert [r["best"] == "1" for r in table] == [
        k == 0 or returns[k] > max(returns[:k]) for k in range(len(returns))
    ]
    chosen = int(np.argmax(returns))
    assert metrics["selected"]["best_timesteps"] == int(table[chosen]["timesteps"])
    assert metrics["selected"]["best_return"] == pytest.approx(returns[chosen])
    assert (run / "model.zip").read_bytes() == (run / "best" / "model.zip").read_bytes()
    # the files that ship are the policy that was validated: same return on the same scenarios
    assert validation_return(run, config) == pytest.approx(returns[chosen], rel=1e-9)
    # the last policy stays usable beside it: its config is the run's, one level up
    assert load_policy(run / "last").config == load_policy(run).config
    assert main(["evaluate", "--model", str(run / "last"), "--episodes", "4", "--json"]) == 0


@pytest.mark.slow
def test_a_resumed_run_keeps_the_best_it_had(tmp_path, interrupted_training):
    config = from_dict(TrainConfig, SMALL | {"timesteps": 6144})
    run = tmp_path / "run"
    interrupted_training(config, run, at=3072)
    before = json.loads((run / "best" / "state.json").read_text())
    assert main(["train", "--resume", "--out", str(run), "--no-progress"]) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["selected"]["best_return"] >= before["best_return"]
    returns = [float(r["mean_return"]) for r in rows(run)]
    assert metrics["selected"]["best_return"] == pytest.approx(max(returns))


def test_the_validation_set_is_neither_trained_nor_tested_on():
    with pytest.raises(ConfigError, match=r"validation\.seed"):
        from_dict(TrainConfig, SMALL | {"validation": {"every": 1024, "seed": 1_000_003}})
    with pytest.raises(ConfigError, match=r"validation\.seed"):
        from_dict(TrainConfig, SMALL | {"validation": {"every": 1024, "seed": 3}})
    with pytest.raises(ConfigError, match="every"):
        from_dict(TrainConfig, SMALL | {"validation": {"every": -1}})


def test_a_policy_can_be_validated_under_the_logic_it_will_be_deployed_under(tmp_path):
    from safeswitch.training.validation import Validator

    trains_guarded = SMALL | {"env": {**SMALL["env"], "switching": "guarded"}}
    config = from_dict(TrainConfig, trains_guarded)
    assert Validator(config, tmp_path).task.config.switching == "guarded"  # default: its own
    deployed = from_dict(
        TrainConfig, trains_guarded | {"validation": {**SMALL["validation"], "switching": "paper"}}
    )
    validator = Validator(deployed, tmp_path)
    assert validator.task.config.switching == "paper"
    assert deployed.env.switching == "guarded"  # training itself keeps its logic
    with pytest.raises(ConfigError, match=r"validation\.switching .*'papr'"):
        from_dict(TrainConfig, SMALL | {"validation": {"every": 1024, "switching": "papr"}})


@pytest.mark.parametrize(("criterion", "chosen"), [("return", 2), ("collisions_then_return", 3)])
def test_the_selection_criterion_can_put_the_fewest_collisions_first(tmp_path, criterion, chosen):
    """The paper's reward has no collision term, so the highest return can come with a
    collision; ``collisions_then_return`` prefers the collision-free policies."""
    from types import SimpleNamespace

    from stable_baselines3.common.logger import configure

    from safeswitch.training.validation import Validator

    config = from_dict(
        TrainConfig, SMALL | {"validation": {**SMALL["validation"], "criterion": criterion}}
    )
    validator = Validator(config, tmp_path)
    validator.model = SimpleNamespace(logger=configure(None, []))  # type: ignore[assignment]
    scores = [(2, 100.0), (0, 90.0), (1, 120.0), (0, 95.0)]  # (collisions, mean return)
    saved = []
    validator._save_best = lambda: saved.append(validator.num_timesteps)  # type: ignore[method-assign]
    for k, (collisions, mean_return) in enumerate(scores):
        validator.validate = lambda c=collisions, r=mean_return: canned(  # type: ignore[method-assign]
            mean_return=r, collisions=c
        )
        validator.num_timesteps = 1024 * (k + 1)
        validator._on_rollout_end()
    assert validator.state["best_timesteps"] == 1024 * (chosen + 1)
    assert saved[-1] == 1024 * (chosen + 1)
    flagged = [int(r["timesteps"]) for r in rows(tmp_path) if r["best"] == "1"]
    assert flagged[-1] == 1024 * (chosen + 1)
    with pytest.raises(ConfigError, match="criterion"):
        from_dict(TrainConfig, SMALL | {"validation": {"every": 1024, "criterion": "fastest"}})


def canned(**given):
    """A validation summary with every field the validator reads (600-tick episodes)."""
    return {
        "episodes": 100, "ticks": 60_000, "mean_return": 0.0, "collisions": 0,
        "safety_activation_episodes": 0, "safety_activation_steps": 0,
        "comfort_violation_steps": 0, "comfort_violation_episodes": 0,
        "cleared_episodes": 100, "mean_time_to_clear_s": 8.0,
        "speeding_steps": 0, "speeding_episodes": 0,
    } | given  # fmt: skip


def test_constraints_then_return_puts_the_limits_first_then_the_time_then_the_return(tmp_path):
    """``constraints_then_return``: a policy within its comfort and safety budgets beats one
    outside them whatever its return; among those, one within (or nearer) the clear-time
    budget; then the higher return. The time to clear counts a never-cleared episode at the
    horizon (12 s)."""
    from types import SimpleNamespace

    from stable_baselines3.common.logger import configure

    from safeswitch.core.config import to_dict
    from safeswitch.training.validation import Validator, constraint_key

    config = from_dict(TrainConfig, SMALL | {
        "env": {"episode": {"learned_scope": "episode"}},
        "validation": {**SMALL["validation"], "criterion": "constraints_then_return"},
        "constraints": {"comfort": {"budget": 0.01}, "safety": {"budget": 0.015},
                        "clear_time": {"budget": 7.5}},
    })  # fmt: skip
    validator = Validator(config, tmp_path)
    validator.model = SimpleNamespace(logger=configure(None, []))  # type: ignore[assignment]
    validator._save_best = lambda: None  # type: ignore[method-assign]
    candidates = [
        canned(mean_return=2000.0, safety_activation_episodes=2),  # 2 % of episodes: over
        canned(mean_return=1900.0, comfort_violation_steps=300),  # 0.5 %: within
        canned(mean_return=1800.0, cleared_episodes=95, mean_time_to_clear_s=7.0),  # 7.25 s
        canned(mean_return=1850.0, cleared_episodes=95, mean_time_to_clear_s=7.1),  # 7.345 s
        canned(mean_return=1700.0, collisions=1, mean_time_to_clear_s=6.0),  # a collision
    ]
    chosen = []
    for k, summary in enumerate(candidates):
        validator.validate = lambda s=summary: s  # type: ignore[method-assign]
        validator.num_timesteps = 1024 * (k + 1)
        validator._on_rollout_end()
        chosen.append(validator.state["best_timesteps"] // 1024 - 1)
    assert chosen == [0, 1, 2, 3, 3]
    # held to its own validation budget (here looser than training's), the first is within it
    looser = from_dict(TrainConfig, {**to_dict(config), "constraints": {
        "comfort": {"budget": 0.01}, "safety": {"budget": 0.015, "validation_budget": 0.02},
        "clear_time": {"budget": 7.5}}})  # fmt: skip
    assert constraint_key(looser, candidates[0], 12.0) > constraint_key(looser, candidates[1], 12.0)
    assert constraint_key(config, candidates[0], 12.0) < constraint_key(config, candidates[1], 12.0)
    # speeding on 1 % of ticks, against a 0.2 % budget, ranks with the limits: below any return
    speedy = from_dict(TrainConfig, {**to_dict(config), "constraints": {
        **to_dict(config)["constraints"], "speeding": {"budget": 0.002}}})  # fmt: skip
    fast = canned(mean_return=2000.0, speeding_steps=600, speeding_episodes=40)
    slow = canned(mean_return=10.0)
    assert constraint_key(speedy, fast, 12.0) < constraint_key(speedy, slow, 12.0)
    assert constraint_key(config, fast, 12.0) > constraint_key(config, slow, 12.0)
    # a limit broken briefly in 10 % of the episodes (0.1 % of ticks), against a budget of 5 %
    # of episodes, ranks with the limits too: the share of ticks alone lets it through
    careful = from_dict(TrainConfig, {**to_dict(config), "constraints": {
        **to_dict(config)["constraints"], "comfort_episodes": {"budget": 0.05}}})  # fmt: skip
    brief = canned(mean_return=2000.0, comfort_violation_steps=60, comfort_violation_episodes=10)
    assert constraint_key(careful, brief, 12.0) < constraint_key(careful, slow, 12.0)
    assert constraint_key(config, brief, 12.0) > constraint_key(config, slow, 12.0)
    times = [float(r["clear_time_s"]) for r in rows(tmp_path)]
    assert times[2] == pytest.approx(0.95 * 7.0 + 0.05 * 12.0)


def test_a_resumed_run_appends_in_its_validation_files_own_columns(tmp_path):
    """A run validated by an older version has fewer columns in ``validation.csv``; resumed,
    its new rows follow that header instead of shifting every value after a new column."""
    from types import SimpleNamespace

    from stable_baselines3.common.logger import configure

    from safeswitch.training.validation import VALIDATION_FIELDS, Validator

    old = [f for f in VALIDATION_FIELDS if f != "speeding_episodes"]
    (tmp_path / "validation.csv").write_text(",".join(old) + "\n", encoding="utf-8")
    validator = Validator(from_dict(TrainConfig, SMALL), tmp_path)
    validator.model = SimpleNamespace(logger=configure(None, []))  # type: ignore[assignment]
    validator._save_best = lambda: None  # type: ignore[method-assign]
    validator.validate = lambda: canned(mean_return=5.0, cut_episodes=7)  # type: ignore[method-assign]
    validator.num_timesteps = 2048
    validator._on_rollout_end()
    (row,) = rows(tmp_path)
    assert list(row) == old
    assert row["timesteps"] == "2048" and row["cut_episodes"] == "7" and row["best"] == "1"


@pytest.mark.parametrize("criterion", ["return", "collisions_then_return"])
def test_a_run_resumed_from_before_selection_keys_keeps_its_best(tmp_path, criterion):
    """A checkpoint from before validation kept its selection key holds only the best return
    and collisions: a resumed run still compares new validations against that best."""
    from types import SimpleNamespace

    from stable_baselines3.common.logger import configure

    from safeswitch.training.validation import Validator

    config = from_dict(
        TrainConfig, SMALL | {"validation": {**SMALL["validation"], "criterion": criterion}}
    )
    validator = Validator(config, tmp_path)
    validator.model = SimpleNamespace(logger=configure(None, []))  # type: ignore[assignment]
    validator._save_best = lambda: None  # type: ignore[method-assign]
    validator.state = {"best_return": 100.0, "best_collisions": 0, "best_timesteps": 1024}
    for k, mean_return in enumerate((90.0, 110.0)):
        validator.validate = lambda r=mean_return: canned(mean_return=r)  # type: ignore[method-assign]
        validator.num_timesteps = 2048 * (k + 1)
        validator._on_rollout_end()
        expected = 1024 if mean_return < 100.0 else 4096
        assert validator.state["best_timesteps"] == expected


# where full throttle with no safety net collides in some scenarios, not all
STRESS = {"episodes": 200, "seed": 5_000_011, "scenarios": {"arrival_offset_s": [-1.5, -0.5]}}


def test_a_stress_set_counts_its_collisions_and_is_driven_only_for_a_would_be_best(tmp_path):
    """``validation.stress``: a policy that would become the best is also driven on the
    stress set and its collisions there count first; one that would not is not driven there
    (its rank could only fall) and its row leaves the column blank."""
    from types import SimpleNamespace

    from stable_baselines3.common.logger import configure

    from safeswitch.training.validation import Validator

    validation = {**SMALL["validation"], "criterion": "collisions_then_return", "stress": STRESS}
    config = from_dict(TrainConfig, SMALL | {"validation": validation})
    validator = Validator(config, tmp_path)
    validator.model = SimpleNamespace(logger=configure(None, []))  # type: ignore[assignment]
    validator._save_best = lambda: None  # type: ignore[method-assign]
    stressed = {1024: 0, 3072: 2, 4096: 0}  # timesteps -> its collisions on the stress set
    driven = []

    def stress_collisions(still_better):
        driven.append(validator.num_timesteps)
        return stressed[validator.num_timesteps]

    validator.stress_collisions = stress_collisions  # type: ignore[method-assign]
    for k, mean_return in enumerate((100.0, 90.0, 120.0, 110.0)):
        validator.validate = lambda r=mean_return: canned(mean_return=r)  # type: ignore[method-assign]
        validator.num_timesteps = 1024 * (k + 1)
        validator._on_rollout_end()
    assert driven == [1024, 3072, 4096]  # 2048 (a lower return) never was
    assert validator.state["best_timesteps"] == 4096  # 3072's return is higher, but it collided
    assert validator.state["best_stress_collisions"] == 0
    table = rows(tmp_path)
    assert [r["stress_collisions"] for r in table] == ["0", "", "2", "0"]
    assert [r["best"] for r in table] == ["1", "0", "0", "1"]


def test_the_stress_set_drives_the_policy_on_its_own_scenarios(tmp_path):
    """Its scenarios come from its own distribution and seed; its count is the collisions of
    the deterministic policy there, as a rollout of its own finds them."""
    import dataclasses
    from types import SimpleNamespace

    from safeswitch.evaluation.rollout import rollout
    from safeswitch.leftturn.config import ScenarioConfig
    from safeswitch.training.validation import Validator

    config = from_dict(TrainConfig, SMALL | {
        "env": {"switching": "none", "episode": {"learned_scope": "episode"}},
        "validation": {**SMALL["validation"], "stress": STRESS}})  # fmt: skip
    validator = Validator(config, tmp_path)
    offsets = validator.stress_scenarios.arrival_offset
    assert offsets.shape == (200,) and offsets.min() >= -1.5 and offsets.max() <= -0.5
    assert validator.scenarios.arrival_offset.max() > 2.0  # the validation set keeps its own

    def full_throttle(obs, state, tick):
        return np.ones(state.batch_size)

    validator._policy = lambda: SimpleNamespace(as_policy=lambda: full_throttle)  # type: ignore[method-assign]
    band = dataclasses.replace(config.env, scenarios=ScenarioConfig(arrival_offset_s=(-1.5, -0.5)))
    task = build_task(None, band)
    scenarios = task.draw_scenarios(5_000_011, np.arange(200), np.zeros(200, int))
    expected = int(np.count_nonzero(rollout(task, scenarios, full_throttle).collision))
    assert 0 < expected < 200
    assert validator.stress_collisions() == expected


def test_the_stress_set_stops_once_its_collisions_rule_the_policy_out(tmp_path, monkeypatch):
    """Driven in chunks: a policy is driven on until ``still_better`` says its collisions so
    far rule it out; the count is then the collisions of the chunks driven."""
    from types import SimpleNamespace

    from safeswitch.evaluation.rollout import rollout
    from safeswitch.training import validation as module

    monkeypatch.setattr(module, "STRESS_CHUNK", 40)
    config = from_dict(TrainConfig, SMALL | {
        "env": {"switching": "none", "episode": {"learned_scope": "episode"}},
        "validation": {**SMALL["validation"], "stress": STRESS}})  # fmt: skip
    validator = module.Validator(config, tmp_path)

    def full_throttle(obs, state, tick):
        return np.ones(state.batch_size)

    validator._policy = lambda: SimpleNamespace(as_policy=lambda: full_throttle)  # type: ignore[method-assign]
    per_chunk = [
        int(np.count_nonzero(rollout(validator.stress_task,
                                     validator.stress_scenarios.take(np.arange(k, k + 40)),
                                     full_throttle).collision))
        for k in range(0, 200, 40)
    ]  # fmt: skip
    assert sum(per_chunk) == validator.stress_collisions()
    seen = []

    def below(limit):
        def still_better(collisions):
            seen.append(collisions)
            return collisions < limit

        return still_better

    found = validator.stress_collisions(below(1))
    first = next(k for k, c in enumerate(per_chunk) if c > 0)
    assert found == per_chunk[first] and len(seen) == first + 1
    seen.clear()
    assert validator.stress_collisions(below(10_000)) == sum(per_chunk)  # never ruled out
    assert seen == list(np.cumsum(per_chunk))


def test_a_bad_stress_set_is_named():
    def stress(**given):
        return SMALL | {"validation": {**SMALL["validation"], "stress": STRESS | given}}

    with pytest.raises(ConfigError, match=r"validation\.stress\.seed .*2000003"):
        from_dict(TrainConfig, stress(seed=2_000_003))
    with pytest.raises(ConfigError, match=r"validation\.stress\.episodes"):
        from_dict(TrainConfig, stress(episodes=0))
    with pytest.raises(ConfigError, match=r"arrival_offset_s"):
        from_dict(TrainConfig, stress(scenarios={"arrival_offset_s": [3.0, 1.8]}))
    with pytest.raises(ConfigError, match=r"validation\.stress"):
        from_dict(TrainConfig, SMALL | {"traffic": "light", "validation": {
            **SMALL["validation"], "stress": STRESS}})  # fmt: skip


# a small run in traffic, selected on its limits (the families need constraints_then_return)
IN_TRAFFIC = SMALL | {
    "traffic": {"preset": "train", "observe": "conflicts", "horizon_s": 4.0},
    "env": {"switching": "certified", "episode": {"learned_scope": "episode"}},
    "constraints": {"safety": {"budget": 0.03}, "uncleared": {"budget": 0.5}},
}


def with_families(families, **validation):
    criterion = {"criterion": "constraints_then_return", "families": families}
    return IN_TRAFFIC | {"validation": {**SMALL["validation"], **criterion, **validation}}


def test_families_are_checked_when_read_and_named_when_wrong():
    with pytest.raises(ConfigError, match=r"validation\.families .*traffic presets.*'busy'"):
        from_dict(TrainConfig, with_families(["test", "busy"]))
    twice = r"validation\.families .*twice.*\['test', 'light', 'test'\]"
    with pytest.raises(ConfigError, match=twice):
        from_dict(TrainConfig, with_families(["test", "light", "test"]))
    with pytest.raises(ConfigError, match=r"validation\.families .*need traffic"):
        from_dict(TrainConfig, {**with_families(["test"]), "traffic": None})
    with pytest.raises(ConfigError, match=r"validation\.families .*constraints_then_return"):
        from_dict(TrainConfig, with_families(["test"], criterion="return"))
    config = from_dict(TrainConfig, with_families(["test", "light"]))
    assert config.validation.families == ("test", "light")
    from safeswitch.training.config import EnvTrainConfig  # a plant of its own has none

    with pytest.raises(ConfigError, match=r"validation\.families must be null"):
        from_dict(EnvTrainConfig, {"env_id": "CartPole-v1", "validation": {"families": ["test"]}})


def test_a_family_validation_set_draws_the_familys_scenes_and_keeps_the_policys_view(tmp_path):
    from safeswitch.training.validation import Validator

    validator = Validator(from_dict(TrainConfig, with_families(["test"])), tmp_path)
    own, family = validator.validation_set.task, validator.families["test"].task
    assert own.traffic.main_flow_veh_h == (100.0, 500.0)  # the run's `train` family
    assert family.traffic.main_flow_veh_h == (500.0, 800.0)  # the `test` family's scenes
    assert family.traffic.observe == own.traffic.observe == "conflicts"  # the policy's view
    assert family.observation_bounds[0].shape == own.observation_bounds[0].shape
    assert len(validator.families["test"].scenarios.arrival_offset) == 30  # validation.episodes


def test_families_hold_each_limit_at_the_worst_and_are_driven_only_for_a_would_be_best(tmp_path):
    """A candidate's safety share counts at the worst of the validation set and the families;
    clearing still ranks on the validation set; a policy that cannot become the best by the
    validation set alone is not driven in the families (its key could only fall)."""
    from types import SimpleNamespace

    from stable_baselines3.common.logger import configure

    from safeswitch.training.validation import Validator, constraint_key

    config = from_dict(TrainConfig, with_families(["test", "light"]))
    validator = Validator(config, tmp_path)
    validator.model = SimpleNamespace(logger=configure(None, []))  # type: ignore[assignment]
    validator._save_best = lambda: None  # type: ignore[method-assign]
    validator._policy = lambda: None  # type: ignore[method-assign]
    # per validation (1024, 2048, ...): its own summary, then each family's safety episodes
    own = [canned(mean_return=100.0, cleared_episodes=60),  # within every budget
           canned(mean_return=200.0, cleared_episodes=70),  # clears more, but 6 % in `test`
           canned(mean_return=90.0, cleared_episodes=55),  # clears less: never driven there
           canned(mean_return=150.0, cleared_episodes=65)]  # fmt: skip
    family = {1024: {"test": 2, "light": 1}, 2048: {"test": 6, "light": 0},
              4096: {"test": 3, "light": 2}}  # fmt: skip
    driven = []

    def family_summary(name):
        def summary(policy):
            driven.append((validator.num_timesteps, name))
            return canned(safety_activation_episodes=family[validator.num_timesteps][name])

        return summary

    for name, validation_set in validator.families.items():
        validation_set.summary = family_summary(name)  # type: ignore[method-assign]
    for k, summary in enumerate(own):
        validator.validate = lambda s=summary: dict(s)  # type: ignore[method-assign]
        validator.num_timesteps = 1024 * (k + 1)
        validator._on_rollout_end()
    assert sorted({t for t, _ in driven}) == [1024, 2048, 4096]  # 3072 clears less: not driven
    assert validator.state["best_timesteps"] == 4096  # 2048 clears the most, but not in `test`
    table = rows(tmp_path)
    assert [r["family_safety_episodes"] for r in table] == ["2", "6", "", "3"]
    assert [r["worst_family"] for r in table] == ["test", "test", "", "test"]
    assert [r["best"] for r in table] == ["1", "0", "0", "1"]
    # the rule itself: the worst family's 6 % against the 3 % budget, clearing on its own set
    worst = {**own[1], "families": {"test": canned(safety_activation_episodes=6)}}
    assert constraint_key(config, worst, 4.0)[0] == pytest.approx(-1.0)
    assert constraint_key(config, worst, 4.0)[1:] == constraint_key(config, own[1], 4.0)[1:]


# the paper's scene, selected on its limits with the north car at every speed as well
IN_THE_PAPERS_SCENE = SMALL | {
    "env": {**SMALL["env"], "switching": "certified"},
    "constraints": {"safety": {"budget": 0.03}},
}
NORTH_ANY = {"north_any": {"north_speed_kmh": [6.0, 44.0]}}
IN_TRAFFIC_SCENE = {"traffic": IN_TRAFFIC["traffic"]}


def with_scenes(scenes, **validation):
    criterion = {"criterion": "constraints_then_return", "scenes": scenes}
    return IN_THE_PAPERS_SCENE | {"validation": {**SMALL["validation"], **criterion, **validation}}


def test_scenes_are_checked_when_read_and_named_when_wrong():
    with pytest.raises(ConfigError, match=r"north_speed_kmh"):
        from_dict(TrainConfig, with_scenes({"bad": {"north_speed_kmh": [44.0, 6.0]}}))
    with pytest.raises(ConfigError, match=r"validation\.scenes .*traffic.*\['north_any'\]"):
        from_dict(TrainConfig, with_scenes(NORTH_ANY) | IN_TRAFFIC_SCENE)
    with pytest.raises(ConfigError, match=r"validation\.scenes .*constraints_then_return"):
        from_dict(TrainConfig, with_scenes(NORTH_ANY, criterion="return"))
    config = from_dict(TrainConfig, with_scenes(NORTH_ANY))
    assert config.validation.scenes["north_any"].north_speed_kmh == (6.0, 44.0)
    from safeswitch.training.config import EnvTrainConfig  # a plant of its own has none

    with pytest.raises(ConfigError, match=r"validation\.scenes must be null"):
        from_dict(EnvTrainConfig, {"env_id": "CartPole-v1", "validation": {"scenes": NORTH_ANY}})


def test_a_scene_is_drawn_from_its_distribution_under_the_deployment_logic(tmp_path):
    """A scene's validation set: its own distribution (keys not given at their defaults), the
    run's validation seed and size, the logic the policy is deployed under, and what the policy
    observes unchanged."""
    validator = Validator(from_dict(TrainConfig, with_scenes(NORTH_ANY)), tmp_path)
    own, scene = validator.validation_set, validator.families["north_any"]
    north = scene.scenarios.north_speed * 3.6
    assert north.min() >= 6.0 and north.max() <= 44.0
    assert north.min() < 20.0 and north.max() > 32.0  # beyond the default 20-32 km/h
    assert (own.scenarios.north_speed * 3.6).min() >= 20.0
    np.testing.assert_array_equal(scene.scenarios.ego_speed, own.scenarios.ego_speed)
    assert len(scene.scenarios.arrival_offset) == 30  # validation.episodes
    assert scene.task.config.switching == own.task.config.switching == "certified"
    assert scene.task.observation_bounds[0].shape == own.task.observation_bounds[0].shape


def test_a_run_selected_on_its_scenes_records_the_worst_and_ranks_by_it(tmp_path):
    """A small run with a scene: each would-be best validation is driven there too, the row
    names the worst set's safety episodes, and the key the run ranked by counts the safety
    share at the worst of the validation set and the scene."""
    from safeswitch.training.validation import constraint_key

    config = from_dict(TrainConfig, with_scenes(NORTH_ANY))
    train(config, tmp_path / "run", progress_bar=False)
    table = rows(tmp_path / "run")
    driven = [r for r in table if r["worst_family"]]
    assert driven and all(r["worst_family"] == "north_any" for r in driven)
    # a policy becomes the best only once it has been driven in the scene too
    assert all(r["worst_family"] for r in table if r["best"] == "1")
    within = canned(episodes=30)
    beyond = {
        **within,
        "families": {"north_any": canned(episodes=30, safety_activation_episodes=3)},
    }
    assert constraint_key(config, beyond, 2.0)[0] == pytest.approx(-(0.1 / 0.03 - 1.0))
    assert constraint_key(config, within, 2.0)[0] == 0.0


def weights_of(model):
    """A copy of the model's policy weights, by name."""
    return copied(model.policy.state_dict())


class WeightsAtRolloutEnd(BaseCallback):
    """The policy's weights at the end of every rollout: what the validator averages there
    (a user's callback runs before the validator, and nothing trains in between)."""

    def __init__(self):
        super().__init__()
        self.seen = []

    def _on_step(self):
        return True

    def _on_rollout_end(self):
        self.seen.append(weights_of(self.model))


@pytest.fixture
def validated(monkeypatch):
    """Every validated candidate, in order: (whether it is the average, its weights)."""
    seen = []
    original = Validator.validate

    def validate(self):
        seen.append((self.scalars == "validation_average", weights_of(self.model)))
        return original(self)

    monkeypatch.setattr(Validator, "validate", validate)
    return seen


def assert_same_weights(actual, expected):
    assert actual.keys() == expected.keys()
    for name in expected:
        torch.testing.assert_close(actual[name], expected[name], rtol=1e-6, atol=1e-7)


AVERAGED = SMALL | {"validation": SMALL["validation"] | {"average": 0.6}}


def test_the_weights_average_is_validated_beside_the_policy_and_can_be_the_runs(
    tmp_path, validated
):
    """``validation.average``: each validation drives the current policy, then the moving
    average of the weights over every update so far (``decay × average + (1 − decay) ×
    weights``); training itself is the same run as without it, and the run's policy is
    whichever candidate validated best, saved with the weights it was validated with."""
    decay = AVERAGED["validation"]["average"]
    recorder = WeightsAtRolloutEnd()
    run = tmp_path / "run"
    train(from_dict(TrainConfig, AVERAGED), run, progress_bar=False, callbacks=[recorder])
    table = rows(run)
    assert [(int(r["timesteps"]), r["averaged"]) for r in table] == [
        (t, a) for t in (1024, 2048, 3072, 4096) for a in ("0", "1")
    ]
    assert len(recorder.seen) == 4 and len(validated) == 8
    average = None
    for k, current in enumerate(recorder.seen):
        average = current if average is None else {
            n: decay * average[n] + (1 - decay) * current[n] for n in average
        }  # fmt: skip
        (first, policy), (second, averaged) = validated[2 * k], validated[2 * k + 1]
        assert (first, second) == (False, True)
        assert_same_weights(policy, current)
        assert_same_weights(averaged, average)
    assert any(  # the average is a different policy from the current one
        not torch.equal(validated[k][1][n], validated[k + 1][1][n])
        for k in range(2, 8, 2) for n in recorder.seen[0]
    )  # fmt: skip
    # the run's policy is the last row flagged best, with the weights it was validated with
    chosen = max(k for k, r in enumerate(table) if r["best"] == "1")
    assert_same_weights(weights_of(load_policy(run).model), validated[chosen][1])
    state = json.loads((run / "best" / "state.json").read_text())
    assert state.get("best_averaged", False) == (table[chosen]["averaged"] == "1")
    # without the average, training goes through the same weights (the validator puts the
    # policy's own weights back after driving the average)
    plain = WeightsAtRolloutEnd()
    train(from_dict(TrainConfig, SMALL), tmp_path / "plain", progress_bar=False, callbacks=[plain])
    for ours, theirs in zip(recorder.seen, plain.seen, strict=True):
        assert_same_weights(ours, theirs)


def test_a_resumed_run_goes_on_with_the_weights_average_of_its_checkpoint(
    tmp_path, interrupted_training, validated
):
    decay = AVERAGED["validation"]["average"]
    config = from_dict(TrainConfig, AVERAGED)
    run = tmp_path / "run"
    interrupted_training(config, run, at=2048)
    (checkpoint,) = [c for c in complete_checkpoints(run) if c.name.endswith("2048")]
    saved = torch.load(checkpoint / "average.pt", weights_only=True)
    validated.clear()
    recorder = WeightsAtRolloutEnd()
    train(config, run, resume=True, progress_bar=False, callbacks=[recorder])
    is_average, averaged = validated[1]
    assert is_average
    assert_same_weights(averaged, {
        n: decay * saved[n] + (1 - decay) * recorder.seen[0][n] for n in saved
    })  # fmt: skip
    assert not all(torch.equal(saved[n], recorder.seen[0][n]) for n in saved)


def test_a_weights_average_outside_0_to_1_is_refused():
    for decay in (-0.1, 1.0, float("nan")):
        with pytest.raises(ConfigError, match=r"validation\.average"):
            from_dict(TrainConfig, SMALL | {"validation": SMALL["validation"] | {"average": decay}})
