"""A user's own plant from the command line (issue #39, items 2–3): ``--import MODULE`` on
every command, Gymnasium's ``module:EnvId``, ``--switching`` checked after the imports,
``--penalty``, a configuration file alone, failures as the plant declares them, and Safety
controllers from installed packages' entry points."""

import csv
import json
import sys
from importlib import metadata

import gymnasium as gym
import pytest
import yaml

from safeswitch.cli import main
from safeswitch.core import registry

MODULE = "tests.core.user_plant"
ENV_ID = "UserWall-v0"
LOGIC = "stopping-distance"


@pytest.fixture
def forgotten():
    """The user's module not imported: its environment, controller and logic unknown. Other
    test modules import it for good: afterwards it is registered again as it was."""
    before = sys.modules.get(MODULE)

    def forget():
        sys.modules.pop(MODULE, None)
        gym.registry.pop(ENV_ID, None)
        registry._controllers.pop(ENV_ID, None)
        registry.unregister_logic(LOGIC)

    forget()
    yield
    forget()
    if before is not None:
        sys.modules[MODULE] = before
        before.register()


def train(tmp_path, *extra, name="run"):
    run = tmp_path / name
    args = ["train", *extra, "--timesteps", "512", "--n-envs", "2", "--out", str(run),
            "--no-progress"]  # fmt: skip
    return main(args), run


def error_line(capsys):
    return capsys.readouterr().err.strip().splitlines()[-1]


def test_failures_are_counted_as_the_plant_declares_them(tmp_path, forgotten):
    code, run = train(tmp_path, "--import", MODULE, "--env", ENV_ID, "--switching", "none")
    assert code == 0
    plant = sys.modules[MODULE]
    metrics = json.loads((run / "metrics.json").read_text())
    t, e = metrics["training"], metrics["evaluation"]
    # The cart drives into the wall with nothing to stop it; its info never says "crashed"
    # or "collision" — the count comes from the declared key, and matches what the plant did.
    assert t["failures"] > 0
    assert t["failures"] + e["failures"] == len(plant.HITS)
    assert not registry.failure_check(None)({"hit_wall": True})
    assert set(e) >= {"episodes", "failures", "steps", "safety_activation_steps",
                      "safety_share", "mean_return"}  # fmt: skip
    assert (run / "training_curves.png").stat().st_size > 0  # drawn for any plant


def test_a_users_logic_keeps_its_plant_safe_in_training_and_evaluation(tmp_path, forgotten):
    code, run = train(tmp_path, "--import", MODULE, "--env", ENV_ID, "--switching", LOGIC)
    assert code == 0
    metrics = json.loads((run / "metrics.json").read_text())
    t, e = metrics["training"], metrics["evaluation"]
    assert t["failures"] == 0 and e["failures"] == 0
    assert t["safety_activation_steps"] > 0 and 0 < e["safety_share"] <= 1
    assert len(sys.modules[MODULE].HITS) == 0


def test_switching_is_checked_after_the_imports(tmp_path, capsys, forgotten):
    code, _ = train(tmp_path, "--env", ENV_ID, "--switching", LOGIC)
    assert code == 2
    assert f"invalid choice: '{LOGIC}'" in error_line(capsys)
    code, _ = train(tmp_path, "--import", "tests.core.no_such_module", "--env", ENV_ID)
    assert code == 2
    line = error_line(capsys)
    assert "--import: cannot import 'tests.core.no_such_module'" in line
    assert "no module named" in line


def test_module_colon_id_is_imported_before_switching_is_checked(tmp_path, capsys, forgotten):
    # the module registers the logic too: --env module:EnvId alone makes it a valid choice
    code, run = train(tmp_path, "--env", f"{MODULE}:{ENV_ID}", "--switching", LOGIC)
    assert code == 0, error_line(capsys)
    assert yaml.safe_load((run / "config.yaml").read_text())["switching"] == LOGIC
    code, _ = train(tmp_path, "--env=tests.core.no_such_module:X-v0", name="missing")
    assert code == 2
    assert "--env: cannot import 'tests.core.no_such_module'" in error_line(capsys)


def test_a_config_files_module_is_imported_before_switching_is_checked(tmp_path, capsys,
                                                                      forgotten):  # fmt: skip
    config = tmp_path / "wall.yaml"
    config.write_text(f"env_id: {MODULE}:{ENV_ID}\n")
    code, run = train(tmp_path, "--config", str(config), "--switching", LOGIC)
    assert code == 0, error_line(capsys)
    assert yaml.safe_load((run / "config.yaml").read_text())["switching"] == LOGIC


def test_module_colon_id_imports_the_module_and_the_run_remembers_it(tmp_path, capsys, forgotten):
    code, run = train(tmp_path, "--env", f"{MODULE}:{ENV_ID}", "--switching", "none")
    assert code == 0
    saved = yaml.safe_load((run / "config.yaml").read_text())
    assert saved["env_id"] == f"{MODULE}:{ENV_ID}"  # a resumed or evaluated run imports it
    sys.modules.pop(MODULE)
    gym.registry.pop(ENV_ID)
    capsys.readouterr()
    args = ["evaluate", "--model", str(run), "--env", f"{MODULE}:{ENV_ID}", "--episodes", "3",
            "--json"]  # fmt: skip
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["episodes"] == 3 and summary["steps"] >= 3
    assert summary["failures"] == len(sys.modules[MODULE].HITS)


def test_a_configuration_file_alone_trains_a_users_plant(tmp_path, forgotten):
    config = tmp_path / "wall.yaml"
    config.write_text(yaml.safe_dump({
        "env_id": f"{MODULE}:{ENV_ID}", "switching": LOGIC, "penalty": -5.0,
        "eval_episodes": 4, "ppo": {"n_steps": 64},
    }))  # fmt: skip
    code, run = train(tmp_path, "--config", str(config))
    assert code == 0
    saved = yaml.safe_load((run / "config.yaml").read_text())
    assert (saved["switching"], saved["penalty"], saved["ppo"]["n_steps"]) == (LOGIC, -5.0, 64)
    assert json.loads((run / "metrics.json").read_text())["evaluation"]["episodes"] == 4


def test_penalty_is_set_from_the_command_line_and_checked(tmp_path, capsys, forgotten):
    for bad in ("5", "nan", "-inf", "x"):
        code, _ = train(tmp_path, "--import", MODULE, "--env", ENV_ID, "--penalty", bad)
        assert code == 2 and "--penalty" in error_line(capsys)
    code, run = train(tmp_path, "--import", MODULE, "--env", ENV_ID, "--penalty", "-3",
                      "--timesteps", "256")  # fmt: skip
    assert code == 0
    assert yaml.safe_load((run / "config.yaml").read_text())["penalty"] == -3.0


def test_installed_packages_register_safety_controllers_by_entry_point(monkeypatch, forgotten):
    entry = metadata.EntryPoint(
        name="wall", value=f"{MODULE}:register", group=registry.CONTROLLER_ENTRY_POINTS
    )
    real = metadata.entry_points

    def entry_points(**kwargs):
        if kwargs.get("group") == registry.CONTROLLER_ENTRY_POINTS:
            return [entry]
        return real(**kwargs)

    monkeypatch.setattr(registry.metadata, "entry_points", entry_points)
    monkeypatch.setattr(registry, "_ENTRY_POINTS_LOADED", [])
    found = registry.safety_controller_for(ENV_ID)  # the entry point imports and registers
    assert found is not None and found.failure == "hit_wall"
    assert registry.failure_of(ENV_ID)({"hit_wall": True})
    assert not registry.failure_of(ENV_ID)({"crashed": True})
    with pytest.raises(ValueError, match="failure must be an info key"):
        registry.register_safety_controller(ENV_ID, lambda env: None, failure=3)


def test_a_plants_named_costs_are_constraints_whose_multipliers_move(tmp_path, capsys, forgotten):
    config = tmp_path / "wall.yaml"
    config.write_text(yaml.safe_dump({
        "env_id": f"{MODULE}:{ENV_ID}", "switching": LOGIC, "eval_episodes": 2,
        "ppo": {"n_steps": 64},
        "constraints": {"speeding": {"budget": 0.01, "integral_gain": 2.0},
                        "safety": {"budget": 0.5}},
    }))  # fmt: skip
    code, run = train(tmp_path, "--config", str(config))
    assert code == 0
    metrics = json.loads((run / "metrics.json").read_text())
    # A cart paid for speed drives faster than 5 m/s on far more than 1 % of its steps: the
    # speeding multiplier has risen; safety episodes above half of them would raise theirs.
    assert metrics["constraints"]["speeding"]["value"] > 0
    assert set(metrics["constraints"]) == {"speeding", "safety"}
    with open(run / "constraints.csv", newline="") as handle:  # the multipliers, update by update
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == ["timesteps", "safety", "safety_multiplier", "speeding",
                             "speeding_multiplier"]  # fmt: skip
    assert [float(r["speeding_multiplier"]) for r in rows] != [0.0] * len(rows)
    assert float(rows[-1]["speeding_multiplier"]) == pytest.approx(
        metrics["constraints"]["speeding"]["value"]
    )
    saved = yaml.safe_load((run / "config.yaml").read_text())
    assert saved["constraints"]["speeding"]["budget"] == 0.01
    # a cost the plant does not publish is refused before anything is written
    config.write_text(yaml.safe_dump({"env_id": f"{MODULE}:{ENV_ID}", "switching": LOGIC,
                                      "constraints": {"comfort": {"budget": 0.1}}}))  # fmt: skip
    code, other = train(tmp_path, "--config", str(config), name="other")
    assert code == 2 and not other.exists()
    line = error_line(capsys)
    assert "constraints.comfort" in line and "it publishes: speeding" in line
    config.write_text(yaml.safe_dump({"env_id": f"{MODULE}:{ENV_ID}", "constraints": {
        "safety": {"budget": 0.1, "reasons": ["x"]}}}))  # fmt: skip
    code, _ = train(tmp_path, "--config", str(config), name="third")
    assert code == 2 and "are the left turn's" in error_line(capsys)


def test_an_interrupted_constrained_run_resumes_with_its_multipliers(
    tmp_path, monkeypatch, forgotten, interrupted_training
):
    from safeswitch.training.config import ConstraintConfig, EnvTrainConfig
    from safeswitch.training.constraints import NamedCostConstraints

    config = EnvTrainConfig(
        env_id=f"{MODULE}:{ENV_ID}", switching=LOGIC, timesteps=2048, n_envs=2,
        checkpoint_every=512, eval_episodes=0,
        constraints={"speeding": ConstraintConfig(budget=0.01, integral_gain=2.0)},
    )  # fmt: skip
    run = tmp_path / "run"
    interrupted_training(config, run, at=1024)
    assert not (run / "metrics.json").exists()
    saved = sorted(run.glob("checkpoints/*/state.json"))
    assert saved, "the interrupt left no checkpoint"
    state = json.loads(saved[-1].read_text())
    risen = state["constraints"]["speeding"]["value"]
    assert risen > 0  # the multiplier had moved before the interrupt
    restored = []
    real = NamedCostConstraints.restore
    monkeypatch.setattr(NamedCostConstraints, "restore",
                        lambda self, s: restored.append(s) or real(self, s))  # fmt: skip
    # `train --resume --out RUN` alone: the run's config names its plant
    assert main(["train", "--resume", "--out", str(run), "--no-progress"]) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["timesteps"] >= 2048
    assert restored == [state["constraints"]]  # it went on from the saved multipliers
    assert metrics["constraints"]["speeding"]["integral"] >= risen


@pytest.mark.parametrize("switching", ["none", "braking-envelope"])
def test_the_car_following_plant_is_trained_by_module_and_id(tmp_path, switching):
    """The README's car-following plant, registered as a user would register it
    (``tests/core/follow_plant.py``; the benchmarks train it so): its logic keeps it out of the
    lead car in training and evaluation; without one, PPO's first policies hit it."""
    code, run = train(
        tmp_path, "--env", "tests.core.follow_plant:Follow-v0", "--switching", switching,
        "--set", "eval_episodes=5",
    )  # fmt: skip
    assert code == 0
    metrics = json.loads((run / "metrics.json").read_text())
    failures = metrics["training"]["failures"] + metrics["evaluation"]["failures"]
    if switching == "none":
        assert failures > 0
    else:
        assert failures == 0 and metrics["training"]["safety_activation_steps"] > 0
