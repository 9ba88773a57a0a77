"""What a new user hits, second round (issue #38): every case gives one line and leaves ``--out``
as it was, or does what was asked; no option is silently ignored; counts are honest."""

import http.server
import json
import signal
import subprocess
import sys
import threading
import time

import gymnasium as gym
import numpy as np
import pytest
import yaml

from safeswitch.cli import DEFAULT_CONFIG, main
from safeswitch.core.config import ConfigError
from safeswitch.core.switching import NeverSwitch, SwitchingError
from safeswitch.core.wrappers import SafeSwitch, SafeSwitchVecEnv
from safeswitch.training.config import DEFAULT_CONFIG as CONFIG_DEFAULT
from safeswitch.training.config import TrainConfig, load_config
from safeswitch.training.policies import PolicyLoadError, check_fits, load_policy
from safeswitch.training.run import INTERRUPTED, complete_checkpoints
from safeswitch.training.shipped import SHIPPED, SHIPPED_DIR


def error_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err  # one line, no traceback, no usage block
    return err[0]


def refused(capsys, args, *fragments):
    """``args`` exits with 2 and one error line holding every fragment."""
    assert main(args) == 2
    line = error_line(capsys)
    for fragment in fragments:
        assert fragment in line, line
    return line


# -- 2, 6: nothing is written before everything is checked; seeds are checked everywhere --


def test_a_bad_seed_is_refused_by_every_command_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "bad"
    refused(capsys, ["train", "--seed", "-3", "--out", str(out)], "--seed", "-3",
            "[0, 2**32 - 1]")  # fmt: skip
    refused(capsys, ["evaluate", "--seed", "-1", "--episodes", "2"], "--seed", "-1")
    refused(capsys, ["campaign", "--controller", "rule", "--seed", "-1", "--out", str(out)],
            "--seed")  # fmt: skip
    refused(capsys, ["evaluate", "--seed", "2**40"], "'2**40' is not an integer")
    config = tmp_path / "seed.yaml"
    config.write_text("seed: -3\n")
    refused(capsys, ["train", "--config", str(config), "--out", str(out)], "train.seed", "-3")
    assert not out.exists()


def test_campaign_arguments_are_checked_before_its_folder_is_written(tmp_path, capsys):
    out = tmp_path / "c"
    base = ["campaign", "--controller", "rule", "--episodes", "10", "--out", str(out)]
    refused(capsys, [*base, "--workers", "-1"], "--workers", "must be >= 0, got -1")
    refused(capsys, [*base, "--shard-size", "0"], "--shard-size", "must be >= 1, got 0")
    refused(capsys, [*base, "--episodes", "0"], "--episodes")
    refused(capsys, [*base, "--switching", "ttc"], "'ttc'", "highway-env", "LeftTurnTask")
    assert not out.exists()


def test_a_logic_that_does_not_fit_the_plant_is_refused_by_env_id_and_writes_nothing(
    tmp_path, capsys
):
    pytest.importorskip("highway_env")
    out = tmp_path / "hw"
    line = refused(capsys, ["train", "--env", "safeswitch/Highway-v0", "--switching", "paper",
                            "--timesteps", "64", "--out", str(out)],
                   "safeswitch/Highway-v0: the 'paper' switching logic")  # fmt: skip
    assert "OrderEnforcing" not in line
    assert not out.exists()
    refused(capsys, ["train", "--switching", "ttc", "--timesteps", "64", "--out", str(out)],
            "'ttc'")  # fmt: skip
    assert not out.exists()


# -- 3: an address where no Ray head answers ---------------------------------------------------


@pytest.fixture
def foreign_service():
    """An HTTP server on the loopback address: a port that is open, but no Ray head."""

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):  # its log would land in the captured stderr
            pass

    server = http.server.HTTPServer(("127.0.0.1", 0), Quiet)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def test_an_address_without_a_ray_head_fails_fast_in_one_line(tmp_path, capsys, foreign_service):
    pytest.importorskip("ray")
    for address, reason in (("127.0.0.1:9", "Connection refused"),
                            (foreign_service, "another service does")):  # fmt: skip
        out = tmp_path / "c"
        started = time.perf_counter()
        refused(capsys, ["campaign", "--controller", "rule", "--episodes", "5", "--address",
                         address, "--out", str(out)], address, reason)  # fmt: skip
        assert time.perf_counter() - started < 5.0
        assert not out.exists()


# -- 4, 5: a policy on the wrong environment; a model file --------------------------------------


def test_a_policy_on_the_wrong_env_is_refused_naming_both(capsys):
    pytest.importorskip("highway_env")
    refused(capsys, ["evaluate", "--model", "shipped", "--env", "safeswitch/Highway-v0",
                     "--episodes", "1"],
            "trained on safeswitch/LeftTurn-v0, not safeswitch/Highway-v0")  # fmt: skip
    policy = load_policy("shipped")
    pendulum = gym.make("Pendulum-v1")
    with pytest.raises(PolicyLoadError, match=r"observation \(6,\), action \(1,\).*Pendulum-v1 "
                       r"has observation \(3,\), action \(1,\)"):  # fmt: skip
        check_fits(policy, "Pendulum-v1", pendulum.observation_space, pendulum.action_space)


def test_a_run_can_be_named_by_its_model_zip(capsys):
    args = ["evaluate", "--episodes", "3", "--json", "--no-progress", "--model"]
    assert main([*args, str(SHIPPED_DIR / "paper")]) == 0
    by_folder = json.loads(capsys.readouterr().out)
    assert main([*args, str(SHIPPED_DIR / "paper" / "model.zip")]) == 0
    by_file = json.loads(capsys.readouterr().out)
    assert {k: v for k, v in by_file.items() if k != "model"} == {
        k: v for k, v in by_folder.items() if k != "model"
    }
    refused(capsys, [*args, str(SHIPPED_DIR / "paper" / "nope.zip")], "nope.zip")


# -- 7: no silent option -----------------------------------------------------------------------


def test_options_that_do_not_apply_are_refused(tmp_path, capsys):
    refused(capsys, ["evaluate", "--controller", "oracle", "--switching", "certified"],
            "--switching does not apply to --controller oracle")  # fmt: skip
    refused(capsys, ["evaluate", "--controller", "rule", "--scenarios", "paper", "--episodes",
                     "7"], "--episodes counts random scenarios")  # fmt: skip
    refused(capsys, ["campaign", "--controller", "rule", "--model", "shipped", "--out",
                     str(tmp_path / "c")], "--model", "--controller rule uses none")  # fmt: skip
    refused(capsys, ["evaluate", "--model", "shipped", "--env", "Pendulum-v1", "--scenarios",
                     "paper"], "--scenarios is an option of the left turn")  # fmt: skip
    assert not (tmp_path / "c").exists()
    # where they do apply, the defaults still hold: three paper scenarios, 1,000 random ones
    assert main(["evaluate", "--controller", "rule", "--scenarios", "paper", "--json",
                 "--no-progress"]) == 0  # fmt: skip
    assert json.loads(capsys.readouterr().out)["episodes"] == 3


# -- 8: configuration messages -----------------------------------------------------------------


def test_config_messages_name_every_value_they_are_about(tmp_path, capsys):
    config = tmp_path / "c.yaml"
    config.write_text("ppo: {n_steps: 100, n_minibatches: 7}\nn_envs: 4\n")
    refused(capsys, ["train", "--config", str(config), "--out", str(tmp_path / "r")],
            "n_envs (4) × ppo.n_steps (100) = 400", "ppo.n_minibatches (7)")  # fmt: skip
    empty = tmp_path / "empty.yaml"
    empty.write_text("")
    refused(capsys, ["train", "--config", str(empty), "--out", str(tmp_path / "r")],
            f"leave out --config: it is {DEFAULT_CONFIG}")  # fmt: skip
    assert DEFAULT_CONFIG == CONFIG_DEFAULT and load_config(DEFAULT_CONFIG) == load_config(
        CONFIG_DEFAULT
    )
    assert not (tmp_path / "r").exists()
    with pytest.raises(ConfigError, match=r"train\.eval_seed"):
        TrainConfig(eval_seed=2**32)


# -- 9: honest counts ----------------------------------------------------------------------------


def test_rounded_timesteps_are_announced_and_no_count_is_made_up(tmp_path, capsys):
    config = tmp_path / "short.yaml"
    config.write_text(yaml.safe_dump({"base": "paper_scratch", "eval_episodes": 0,
                                      "torch_threads": 1}))  # fmt: skip
    args = ["train", "--config", str(config), "--timesteps", "1", "--out", str(tmp_path / "r"),
            "--no-progress"]  # fmt: skip
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "n_envs × n_steps = 16 × 128 = 2,048 steps: 1 timesteps become 2,048" in captured.err
    assert "no training episode finished (no collision or safety counts" in captured.out
    assert "0 collisions" not in captured.out
    metrics = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert metrics["timesteps"] == 2048 and metrics["training"]["episodes"] == 0


# -- 10, 12: the wrappers' arguments -------------------------------------------------------------


def _brake(state):
    return np.zeros((len(state), 1))


@pytest.mark.parametrize(
    ("penalty", "message"),
    [("-1", "must be a number <= 0, got '-1'"), (True, "got True"), (None, "got None"),
     (float("nan"), "finite"), (5.0, "must be <= 0, got 5.0")],
)  # fmt: skip
def test_a_penalty_that_is_not_a_number_below_zero_is_refused(penalty, message):
    with pytest.raises(SwitchingError, match=message.replace("(", r"\(").replace("*", r"\*")):
        SafeSwitch(gym.make("Pendulum-v1"), _brake, NeverSwitch(), penalty=penalty)
    SafeSwitch(gym.make("Pendulum-v1"), _brake, NeverSwitch(), penalty=np.float32(-1.5))


def test_a_vecnormalize_inside_the_switch_is_refused():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    venv = make_vec_env("Pendulum-v1", n_envs=2)
    with pytest.raises(SwitchingError, match="put VecNormalize outside"):
        SafeSwitchVecEnv(VecNormalize(venv), _brake, NeverSwitch())
    outside = VecNormalize(SafeSwitchVecEnv(venv, _brake, NeverSwitch()))  # the right order
    outside.reset()
    outside.step(np.zeros((2, 1), dtype=np.float32))
    # with state_fn the user says where the plant state comes from: then it is theirs to choose
    SafeSwitchVecEnv(VecNormalize(venv), _brake, NeverSwitch(), state_fn=lambda v: np.zeros((2, 3)))


# -- 11: the help names every shipped policy -----------------------------------------------------


def test_evaluate_help_names_every_shipped_policy(capsys):
    with pytest.raises(SystemExit):
        main(["evaluate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for name in SHIPPED:
        assert name in text.replace("- ", "-"), name  # argparse may wrap after a hyphen


# -- 13: the checkpoint an interrupt named survives the resume ----------------------------------


def test_the_interrupts_checkpoint_is_kept_after_resuming(tmp_path, interrupted_training, capsys):
    config = TrainConfig(timesteps=8192, n_envs=8, checkpoint_every=1024, eval_episodes=0,
                         torch_threads=1, seed=2)  # fmt: skip
    run = tmp_path / "run"
    interrupted_training(config, run, at=3072)
    named = [p for p in complete_checkpoints(run) if (p / INTERRUPTED).is_file()]
    assert len(named) == 1
    assert main(["train", "--resume", "--out", str(run), "--no-progress"]) == 0
    assert named[0].is_dir()  # not pruned by the checkpoints written after it
    assert len(complete_checkpoints(run)) == 3  # the last two, and the interrupt's
    capsys.readouterr()
    assert main(["evaluate", "--model", str(named[0]), "--episodes", "2", "--json",
                 "--no-progress"]) == 0  # fmt: skip
    assert json.loads(capsys.readouterr().out)["episodes"] == 2


# -- 1: campaigns stream; progress goes to stderr whatever --json ---------------------------------


def _rss_mb(pid):
    with open(f"/proc/{pid}/status") as handle:
        for line in handle:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return 0.0


@pytest.mark.slow
def test_a_campaign_of_a_trillion_episodes_plans_first_and_keeps_its_memory(tmp_path):
    """Run in one process (``--workers 0``): the plan line comes within 5 s, the shards are
    generated as they are run (memory flat), Ctrl-C stops it and leaves whole shards."""
    command = [sys.executable, "-c",
               "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
               "from safeswitch.cli import main; sys.exit(main(sys.argv[1:]))",
               "campaign", "--controller", "rule", "--episodes", str(10**12), "--shard-size",
               "64", "--workers", "0", "--json", "--out", str(tmp_path / "c")]  # fmt: skip
    started = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        plan = child.stderr.readline()
        assert time.perf_counter() - started < 5.0, plan
        assert plan.startswith("campaign: 1 cell(s) × 15,625,000,000 shard(s)"), plan
        assert "warning" in child.stderr.readline()  # years, not an hour
        samples = []
        while time.perf_counter() - started < 20.0:
            time.sleep(1.0)
            samples.append(_rss_mb(child.pid))
        settled = samples[len(samples) // 2 :]
        assert max(settled) < 1024 and max(settled) - min(settled) < 50, samples
        child.send_signal(signal.SIGINT)
        out, _ = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 130 and out == ""  # stdout stays clean for --json
    shards = list((tmp_path / "c" / "shards" / "rule").glob("*.json"))
    assert shards and not list((tmp_path / "c" / "shards" / "rule").glob(".*"))


def test_progress_reaches_stderr_with_json_and_no_progress_silences_it(tmp_path, capsys):
    args = ["evaluate", "--controller", "rule", "--episodes", "5", "--json"]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["episodes"] == 5
    assert "evaluate rule: 5/5 episodes" in captured.err
    assert main([*args, "--no-progress"]) == 0
    assert capsys.readouterr().err == ""


def test_a_long_evaluation_is_announced(capsys, monkeypatch):
    import safeswitch.app.evaluate as app

    monkeypatch.setattr(app, "LONG_PLAN_S", 0.001)
    assert main(["evaluate", "--controller", "rule", "--episodes", "3", "--json"]) == 0
    assert "warning: 3 episodes would take about" in capsys.readouterr().err


def test_a_plant_the_switch_cannot_wrap_is_refused_with_its_reason(tmp_path, capsys):
    out = tmp_path / "run"
    refused(capsys, ["train", "--env", "Pendulum-v1", "--out", str(out)], "Pendulum-v1 takes no "
            "switching logic and no Safety controller is registered for it",
            "safeswitch.register_safety_controller")  # fmt: skip
    line = refused(capsys, ["train", "--env", "CartPole-v1", "--switching", "none", "--out",
                            str(out)], "SafeSwitch around CartPole-v1 needs a Box action "
                   "space", "got Discrete(2)")  # fmt: skip
    assert "register_safety_controller" not in line  # registering one would not help
    assert not out.exists()
