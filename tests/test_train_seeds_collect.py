"""``benchmarks/train_seeds.py --collect``: a table rebuilt from kept runs holds exactly what
their ``metrics.json`` recorded — and the fields the script reports now — and refuses a run
that is missing or was trained with another seed."""

import importlib.util
import json
import shutil
import sys
from pathlib import Path

import pytest

from safeswitch.training.policies import resolve_model_dir, run_config_path

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


@pytest.fixture
def train_seeds(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location("train_seeds_under_test",
                                                  BENCHMARKS / "train_seeds.py")  # fmt: skip
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop("train_seeds_under_test", None)


def kept_run(folder, evaluation):
    """A run as ``--keep`` leaves it: the shipped `certified` config (seed 1), a metrics.json."""
    folder.mkdir(parents=True)
    shutil.copyfile(run_config_path(resolve_model_dir("certified")), folder / "config.yaml")
    metrics = {
        "timesteps": 2_000_000, "wall_time_s": 200.0,
        "training": {"collision_episodes": 0, "safety_activation_episodes": 40, "episodes": 900},
        "evaluation": evaluation,
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
    # a run kept before a field was reported: that field is None, the others kept
    del evaluation["faster_than_oracle_either"]
    kept_run(tmp_path / "older" / "seed_1", evaluation)
    train_seeds.main(["--config", "certified", "--seeds", "1", "--collect",
                      str(tmp_path / "older"), "--out", str(out)])  # fmt: skip
    (row,) = json.loads(out.read_text())["runs"]
    assert row["faster_than_oracle_either"] is None and row["collisions"] == 1


def test_collect_refuses_a_missing_run_or_another_seed(train_seeds, tmp_path):
    kept_run(tmp_path / "runs" / "seed_2", {k: 0 for k in train_seeds.EVALUATED})  # seed 1's
    base = ["--config", "certified", "--collect", str(tmp_path / "runs"), "--out",
            str(tmp_path / "t.json")]  # fmt: skip
    with pytest.raises(SystemExit, match=r"seed_3/metrics\.json does not exist"):
        train_seeds.main([*base, "--seeds", "3"])
    with pytest.raises(SystemExit, match="not trained with seed 2"):
        train_seeds.main([*base, "--seeds", "2"])
    with pytest.raises(SystemExit):
        train_seeds.main([*base, "--seeds", "1", "--keep", str(tmp_path / "k")])
    assert not (tmp_path / "t.json").exists()
