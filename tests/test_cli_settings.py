"""``--set KEY=VALUE`` on train, evaluate and campaign (issue #40): the one way to change any
setting from the command line — a dotted key and a YAML value — validated like a file, a bad
key or value refused in one line before anything is written."""

import csv
import json

import pytest
import yaml

from safeswitch.cli import main
from safeswitch.core.config import ConfigError, with_settings
from safeswitch.training.config import TrainConfig


def error_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_settings_change_exactly_the_keys_named_and_are_validated():
    base = TrainConfig()
    changed = with_settings(base, ["ppo.gamma=0.995", "env.scenarios.north_speed_kmh=[30, 45]",
                                   "traffic=heavy"])  # fmt: skip
    assert changed.ppo.gamma == 0.995 and changed.env.scenarios.north_speed_kmh == (30.0, 45.0)
    assert changed.traffic == "heavy"
    assert changed.env.rewards == base.env.rewards and changed.n_envs == base.n_envs
    with pytest.raises(ConfigError, match=r"env\.scenarios has no key 'north_speed' \(its keys"):
        with_settings(base, ["env.scenarios.north_speed=[30, 45]"])
    with pytest.raises(ConfigError, match="north_speed_kmh must be"):
        with_settings(base, ["env.scenarios.north_speed_kmh=[45, 30]"])
    with pytest.raises(ConfigError, match="expected KEY=VALUE"):
        with_settings(base, ["ppo.gamma"])
    with pytest.raises(ConfigError, match="is not a YAML value"):
        with_settings(base, ["ppo.gamma=[0.9"])


def test_train_writes_its_settings_into_the_run_and_refuses_bad_ones(tmp_path, capsys):
    run = tmp_path / "run"
    args = ["train", "--timesteps", "256", "--n-envs", "2", "--out", str(run), "--no-progress",
            "--set", "eval_episodes=4", "--set", "env.scenarios.north_speed_kmh=[40, 44]",
            "--set", "ppo.n_steps=128"]  # fmt: skip
    assert main(args) == 0
    saved = yaml.safe_load((run / "config.yaml").read_text())
    assert saved["env"]["scenarios"]["north_speed_kmh"] == [40.0, 44.0]
    assert saved["eval_episodes"] == 4
    assert json.loads((run / "metrics.json").read_text())["evaluation"]["episodes"] == 4
    capsys.readouterr()
    bad = tmp_path / "bad"
    for setting, needle in (
        ("env.scenarios.north_speed_kmhh=[1,2]", "env.scenarios has no key 'north_speed_kmhh'"),
        ("ppo.gamma=2", "gamma"),
        ("env.episode=3", "env.episode: expected a mapping"),
    ):
        assert main(["train", "--out", str(bad), "--set", setting]) == 2
        assert needle in error_line(capsys)
        assert not bad.exists()  # nothing written
    assert main(["train", "--resume", "--out", str(run), "--set", "ppo.gamma=0.9"]) == 2
    assert "drop --set" in error_line(capsys)


def test_evaluate_drives_the_scene_the_settings_describe(tmp_path, capsys):
    out = tmp_path / "eval"
    args = ["evaluate", "--controller", "rule", "--episodes", "20", "--out", str(out),
            "--set", "env.scenarios.north_speed_kmh=[43, 44]", "--json"]  # fmt: skip
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["settings"] == ["env.scenarios.north_speed_kmh=[43, 44]"]
    with open(out / "episodes.csv", newline="") as handle:
        speeds = [float(r["north_speed_kmh"]) for r in csv.DictReader(handle)]
    assert len(speeds) == 20 and all(43.0 <= v <= 44.0 for v in speeds)
    assert main(["evaluate", "--controller", "rule", "--set", "ppo.gamma=0.9"]) == 2
    assert "env.KEY=VALUE" in error_line(capsys)
    # a scene whose north car would start off its road is refused before anything runs
    far = tmp_path / "far"
    args = ["evaluate", "--controller", "rule", "--out", str(far),
            "--set", "env.scenarios.north_speed_kmh=[40, 50]"]  # fmt: skip
    assert main(args) == 2
    line = error_line(capsys)
    assert "north car at up to 50 km/h" in line and "north_speed_kmh's upper end" in line
    assert not far.exists()


def test_evaluate_tunes_the_gap_planner_and_refuses_its_settings_for_others(capsys):
    """``gap_planner.KEY=VALUE`` tunes the gap planner (validated like a file, bad keys and
    values named); for any other controller it is refused in one line."""
    from safeswitch.app.evaluate import controller_setup

    settings = ["gap_planner.approach=brake", "gap_planner.coast_decel=2",
                "env.controllers.learned_brake=true"]  # fmt: skip
    config, planner = controller_setup("gap_planner", None, None, settings)
    assert planner.config.approach == "brake" and planner.config.coast_decel == 2.0
    assert planner.config.stop_extra_m == 4.0 and config.controllers.learned_brake
    with pytest.raises(ConfigError, match="gap_planner has no key 'aproach'"):
        controller_setup("gap_planner", None, None, ["gap_planner.aproach=brake"])
    with pytest.raises(ConfigError, match="approach: invalid value 'slide'"):
        controller_setup("gap_planner", None, None, ["gap_planner.approach=slide"])
    assert main(["evaluate", "--controller", "rule", "--set", "gap_planner.approach=brake"]) == 2
    assert "tunes --controller gap_planner, not --controller rule" in error_line(capsys)


def test_campaign_cells_run_in_the_scene_the_settings_describe(tmp_path, capsys):
    pq = pytest.importorskip("pyarrow.parquet")
    folder = tmp_path / "c"
    args = ["campaign", "--controller", "rule", "--episodes", "30", "--workers", "0",
            "--set", "env.scenarios.north_speed_kmh=[43, 44]", "--out", str(folder),
            "--no-progress", "--json"]  # fmt: skip
    assert main(args) == 0
    table = pq.read_table(next((folder / "shards" / "rule").glob("*.parquet")))
    speeds = [float(v) for v in table.column("north_speed_kmh").to_pylist()]
    assert len(speeds) == 30 and all(43.0 <= v <= 44.0 for v in speeds)
    capsys.readouterr()
    other = [*args[:-6], "--set", "env.scenarios.north_speed_kmh=[30, 44]", "--out",
             str(folder), "--resume", "--no-progress"]  # fmt: skip
    assert main(other) == 2
    assert "different campaign" in error_line(capsys)
