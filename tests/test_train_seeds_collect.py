"""``benchmarks/train_seeds.py --collect``: a table rebuilt from kept runs holds exactly what
their ``metrics.json`` recorded — and the fields the script reports now — and refuses a run
that is missing or was trained with another seed or another configuration."""

import importlib.util
import json
import shutil
from pathlib import Path

import pytest

from safeswitch.training.config import dump_config, load_config, write_config_with_files
from safeswitch.training.policies import resolve_model_dir, run_config_path

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


@pytest.fixture
def train_seeds(benchmark_module):
    return benchmark_module("train_seeds")


def kept_run(folder, evaluation, warm_start=None):
    """A run as ``--keep`` leaves it: the shipped `certified` config (seed 1), a metrics.json."""
    folder.mkdir(parents=True)
    shipped = load_config(run_config_path(resolve_model_dir("certified")))
    write_config_with_files(folder, dump_config(shipped))  # with its go predictor
    metrics = {
        "timesteps": 2_000_000, "wall_time_s": 200.0,
        "training": {"collision_episodes": 0, "safety_activation_episodes": 40, "episodes": 900},
        "evaluation": evaluation, "warm_start": warm_start,
    }  # fmt: skip
    (folder / "metrics.json").write_text(json.dumps(metrics))


def test_collect_rebuilds_the_rows_of_kept_runs(train_seeds, tmp_path):
    evaluation = {k: i + 1 for i, k in enumerate(train_seeds.EVALUATED)}
    kept_run(tmp_path / "runs" / "seed_1", evaluation)
    out = tmp_path / "table.json"
    argv = ["--config", "certified", "--seeds", "1", "--collect", str(tmp_path / "runs")]
    assert train_seeds.main([*argv, "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    (row,) = result["runs"]
    assert {k: row[k] for k in train_seeds.EVALUATED} == evaluation
    assert row["faster_than_oracle_comfort"] == evaluation["faster_than_oracle_comfort"]
    assert row["training_safety_episodes"] == 40 and row["seed"] == 1
    assert result["collected_from"] == str(tmp_path / "runs")
    assert result["parallel"] is None  # how the kept runs were trained is not known here
    # a run kept before a field was reported: that field is None, the others kept
    del evaluation["faster_than_oracle_either"]
    kept_run(tmp_path / "older" / "seed_1", evaluation)
    train_seeds.main(["--config", "certified", "--seeds", "1", "--collect",
                      str(tmp_path / "older"), "--out", str(out)])  # fmt: skip
    (row,) = json.loads(out.read_text())["runs"]
    assert row["faster_than_oracle_either"] is None and row["collisions"] == 1


@pytest.mark.parametrize(
    ("warm_start", "collisions"),
    [({"episodes": 400, "collisions": 2}, 2), ({"policy": "certified", "parameters": 9}, None)],
)
def test_a_row_states_a_cloning_s_collisions_and_none_for_a_started_policy(
    train_seeds, tmp_path, warm_start, collisions
):
    """A run cloned from a teacher records the cloning's collisions; one started from a trained
    policy (``warm_start.policy``) has none to record, and its row says so."""
    kept_run(tmp_path / "runs" / "seed_1", {k: 0 for k in train_seeds.EVALUATED}, warm_start)
    out = tmp_path / "table.json"
    train_seeds.main(["--config", "certified", "--seeds", "1", "--collect",
                      str(tmp_path / "runs"), "--out", str(out)])  # fmt: skip
    (row,) = json.loads(out.read_text())["runs"]
    assert row["warm_start_collisions"] == collisions


def test_collect_evaluates_the_kept_policies_when_asked_for(train_seeds, tmp_path):
    """``--collect DIR --deploy LOGIC``: the kept run's policy (here the shipped `certified`
    one, copied) is evaluated under that logic as after training, on the recipe's scenarios."""
    run = tmp_path / "runs" / "seed_1"
    shutil.copytree(resolve_model_dir("certified"), run)
    out = tmp_path / "table.json"
    argv = ["--config", "certified", "--seeds", "1", "--collect", str(tmp_path / "runs"),
            "--set", "eval_episodes=50", "--deploy", "none", "--out", str(out)]  # fmt: skip
    assert train_seeds.main(argv) == 0
    (row,) = json.loads(out.read_text())["runs"]
    deployed = row["deployed"]  # evaluated now, on 50 scenarios, with no logic to act
    assert deployed["switching"] == "none" and deployed["safety_activation_episodes"] == 0
    assert deployed["cleared_episodes"] <= 50 < row["cleared_episodes"]  # the kept 1,000's


def test_collect_refuses_a_missing_run_another_seed_or_another_recipe(train_seeds, tmp_path):
    kept_run(tmp_path / "runs" / "seed_2", {k: 0 for k in train_seeds.EVALUATED})  # seed 1's
    base = ["--config", "certified", "--collect", str(tmp_path / "runs"), "--out",
            str(tmp_path / "t.json")]  # fmt: skip
    with pytest.raises(SystemExit, match=r"seed_3/metrics\.json does not exist"):
        train_seeds.main([*base, "--seeds", "3"])
    with pytest.raises(SystemExit, match="not trained with seed 2"):
        train_seeds.main([*base, "--seeds", "2"])
    with pytest.raises(SystemExit):
        train_seeds.main([*base, "--seeds", "1", "--keep", str(tmp_path / "k")])
    # a run of another recipe, or of this one with another training setting, is not its row
    kept_run(tmp_path / "runs" / "seed_1", {k: 0 for k in train_seeds.EVALUATED})
    with pytest.raises(SystemExit, match="another configuration than --config"):
        train_seeds.main([*base, "--seeds", "1", "--config", "paper"])
    with pytest.raises(SystemExit, match="another configuration than --config"):
        train_seeds.main([*base, "--seeds", "1", "--set", "ppo.gamma=0.9"])
    assert not (tmp_path / "t.json").exists()


USER_PLANT = "tests.core.user_plant"


def plant_recipe(folder, switching="stopping-distance", seed=1):
    """A user's plant's recipe file (the cart before the wall, imported as a user's plant)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "config.yaml"
    path.write_text(
        f"env_id: {USER_PLANT}:UserWall-v0\nswitching: {switching}\npenalty: -1.0\n"
        f"timesteps: 512\nn_envs: 2\nseed: {seed}\neval_episodes: 4\n"
    )
    return path


def test_any_plant_rows_and_table_come_from_its_metrics(train_seeds, tmp_path, capsys):
    recipe = plant_recipe(tmp_path / "runs" / "seed_2", seed=2)
    evaluation = {"seed": 1000003, "episodes": 50, "failures": 0, "steps": 7550,
                  "safety_activation_episodes": 3, "safety_activation_steps": 12,
                  "safety_share": 12 / 7550, "mean_return": 105.25,
                  "cost_steps": {"speeding": 7}, "safety_cost_steps": {"speeding": 2}}  # fmt: skip
    metrics = {"env_id": f"{USER_PLANT}:UserWall-v0", "switching": "stopping-distance",
               "timesteps": 512, "wall_time_s": 9.0, "selected": None, "constraints": {},
               "training": {"failures": 1, "safety_activation_steps": 40, "episodes": 17,
                            "steps": 512},
               "evaluation": evaluation}  # fmt: skip
    (recipe.parent / "metrics.json").write_text(json.dumps(metrics))
    out = tmp_path / "t.json"
    plant = ["--import", USER_PLANT, "--config", str(recipe), "--seeds", "2"]
    assert train_seeds.main([*plant, "--collect", str(tmp_path / "runs"), "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    (row,) = result["runs"]
    assert result["env_id"] == f"{USER_PLANT}:UserWall-v0"
    assert {k: row[k] for k in train_seeds.PLANT_EVALUATED} == {
        k: evaluation[k] for k in train_seeds.PLANT_EVALUATED
    }
    assert (row["training_failures"], row["training_safety_steps"]) == (1, 40)
    printed = capsys.readouterr().out
    assert "| 2 | 1 / 17 | 40 of 512 | 0 / 50 | 0.16% (12 of 7,550) | 105.2 | speeding 7 (2) |" in (
        printed
    )
    # a left-turn option on another plant is refused, naming it
    with pytest.raises(SystemExit):
        train_seeds.main([*plant, "--deploy", "paper"])
    assert "--deploy is an option of the left turn, not of" in capsys.readouterr().err


@pytest.mark.slow
def test_a_users_plant_trains_over_seeds_with_its_failures_and_logic(monkeypatch, tmp_path):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    train_seeds = importlib.import_module("train_seeds")  # by its name: the workers import it
    recipe = plant_recipe(tmp_path)
    base = ["--import", USER_PLANT, "--config", str(recipe), "--seeds", "1", "2"]
    assert train_seeds.main([*base, "--out", str(tmp_path / "safe.json")]) == 0
    safe = json.loads((tmp_path / "safe.json").read_text())["runs"]
    # under the plant's own logic: no failure, the Safety controller did act
    assert [r["seed"] for r in safe] == [1, 2]
    assert all(r["training_failures"] == 0 == r["failures"] for r in safe)
    assert all(r["training_safety_steps"] > 0 for r in safe)
    # --switching and --set reach the recipe: without a logic the cart hits the wall, and the
    # count comes from the plant's declared key (its info never says crashed or collision)
    argv = [*base, "--switching", "none", "--set", "eval_episodes=6", "--out",
            str(tmp_path / "none.json")]  # fmt: skip
    assert train_seeds.main(argv) == 0
    free = json.loads((tmp_path / "none.json").read_text())
    assert free["switching"] == "none"
    assert all(r["episodes"] == 6 and r["safety_activation_steps"] == 0 for r in free["runs"])
    assert sum(r["training_failures"] + r["failures"] for r in free["runs"]) > 0
