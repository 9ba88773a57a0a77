"""``safeswitch adapt`` (issue #40): the policy keeps learning in deployment while the switch
stays authoritative — even an adversarial update cannot collide under ``certified`` —, a run
resumes after its last block, ``--set`` is validated like a file, and the original
distribution is evaluated after adapting."""

import json

import numpy as np
import pytest
import torch

from safeswitch.app import adapt as adapt_module
from safeswitch.app.adapt import AdaptError, adapt
from safeswitch.cli import main
from safeswitch.core.config import ConfigError
from safeswitch.training.policies import load_policy
from safeswitch.training.ppo import SwitchPPO

SHIFT = ["env.scenarios.ego_speed_kmh=[28, 30]"]
SMALL = dict(settings=SHIFT, episodes=96, block=48, n_envs=8, eval_episodes=40)


@pytest.fixture
def adversarial_updates(monkeypatch):
    """Every PPO update ends by driving the actor to full throttle (the action head's bias to
    +5); returns, per update asked, whether learning was paused (then nothing is changed)."""
    original = SwitchPPO.train
    paused = []

    def adversarial(self):
        paused.append(self.learning_paused)
        original(self)
        if not self.learning_paused:
            with torch.no_grad():
                self.policy.action_net.bias.fill_(5.0)

    monkeypatch.setattr(SwitchPPO, "train", adversarial)
    return paused


@pytest.mark.slow
def test_an_adversarial_update_still_cannot_collide_under_certified(tmp_path, adversarial_updates):
    """With adversarial updates the policy the switch supervises changes each rollout, for the
    worse, and no block collides (without rollback: the adversarial policy stays deployed;
    without settling: the frozen policy meets its targets on this shift's 40 held-out scenarios,
    and a settled run would not update at all)."""
    summary = adapt("certified", tmp_path / "a", **SMALL, rollback=False, settle=False)
    blocks = summary["blocks"]
    assert [b["episodes"] for b in blocks] == [48, 48]
    assert all(b["collisions"] == 0 and b["failures"] == 0 for b in blocks)
    assert summary["collisions"] == summary["failures"] == 0
    # the update took hold: the deployed policy is the full-throttle one, overruled often
    assert blocks[-1]["safety_activation_episodes"] == 48
    last = SwitchPPO.load(tmp_path / "a" / "checkpoint" / "model.zip", device="cpu")
    width = last.observation_space.shape[0]  # the certified policy's: with its go predictor
    full = last.predict(np.zeros((1, width), dtype=np.float32), deterministic=True)[0]
    assert full[0, 0] == pytest.approx(1.0)
    # ... and it is not what adapting hands back: the selection keeps the frozen policy
    assert summary["selected_block"] == 0
    adapted = load_policy(tmp_path / "a").act(np.zeros((1, width), dtype=np.float32))[0]
    frozen = load_policy("certified").act(np.zeros((1, width), dtype=np.float32))[0]
    assert adapted == pytest.approx(frozen) and adapted != pytest.approx(1.0)


@pytest.mark.slow
def test_a_block_that_ranks_below_the_selected_policy_is_rolled_back(tmp_path, adversarial_updates):
    """With adversarial updates and rollback (the default), every block's policy ranks below
    the frozen one, so learning goes on from the frozen policy each time (not from the rejected
    policy's last rollout): the policy left after the last block is the frozen one, not full
    throttle (without settling, as above, so that every block learns)."""
    summary = adapt("certified", tmp_path / "a", **SMALL, settle=False)
    assert [b["rolled_back"] for b in summary["blocks"]] == [True, True]
    # the update after each rollback is skipped: the restored policy does not learn from the
    # rejected policy's rollout
    assert adversarial_updates.count(True) == 2 and adversarial_updates.count(False) > 2
    assert summary["collisions"] == 0 and summary["selected_block"] == 0
    last = SwitchPPO.load(tmp_path / "a" / "checkpoint" / "model.zip", device="cpu")
    frozen = load_policy("certified").model
    for name, value in frozen.policy.state_dict().items():
        if name != "log_std":  # the noise is scheduled, not restored
            assert torch.equal(last.policy.state_dict()[name], value), name


def test_rollback_is_on_unless_asked_off_on_the_command_line():
    from safeswitch.cli import build_parser

    base = ["adapt", "--model", "certified", "--out", "x"]
    assert build_parser().parse_args(base).rollback is True
    assert build_parser().parse_args([*base, "--no-rollback"]).rollback is False


@pytest.fixture
def updates(monkeypatch):
    """Counts the PPO updates that ran (SB3's own ``PPO.train``, under ``SwitchPPO.train``)."""
    from stable_baselines3 import PPO

    count = [0]
    original = PPO.train

    def counted(self):
        count[0] += 1
        original(self)

    monkeypatch.setattr(PPO, "train", counted)
    return count


@pytest.mark.slow
def test_a_policy_within_every_target_is_deployed_without_noise_and_not_updated(
    tmp_path, monkeypatch, updates
):
    """Settled (the frozen policy already meets every target: here a budget of 100 %), every
    block deploys the selected policy without exploration noise, no update runs, and the
    policy handed back is the frozen one, parameter for parameter."""
    monkeypatch.setattr(adapt_module, "SAFETY_BUDGET", 1.0)
    summary = adapt("certified", tmp_path / "a", **SMALL)
    assert [b["settled"] for b in summary["blocks"]] == [True, True]
    assert updates[0] == 0 and summary["selected_block"] == 0
    frozen = load_policy("certified").model.policy.state_dict()
    last = SwitchPPO.load(tmp_path / "a" / "checkpoint" / "model.zip", device="cpu")
    for name, value in last.policy.state_dict().items():
        if name == "log_std":  # deployed without noise
            assert float(value.max()) == adapt_module.SETTLED_LOG_STD
        else:
            assert torch.equal(value, frozen[name]), name
    # ... and with --no-settle the same run learns
    adapt("certified", tmp_path / "b", **SMALL, settle=False)
    assert updates[0] > 0


@pytest.mark.slow
def test_a_deployed_block_over_the_budget_resumes_learning(tmp_path, monkeypatch, updates):
    """The selection says the frozen policy meets its targets, but the field disagrees (a
    budget of 0 deployed safety actions): the first block is settled, learning resumes after
    it, and the selected policy settles again after the next block."""
    monkeypatch.setattr(adapt_module, "meets_targets", lambda key: True)
    monkeypatch.setattr(adapt_module, "SAFETY_BUDGET", 0.0)
    # the ego fast and close: a shift on which the frozen policy meets the filter in deployment
    close = [*SHIFT, "env.scenarios.ego_start_distance_m=[22, 28]"]
    summary = adapt("certified", tmp_path / "a", **{**SMALL, "settings": close, "episodes": 144})
    blocks = summary["blocks"]
    assert blocks[0]["safety_activation_episodes"] > 0  # the filter acts
    assert [b["settled"] for b in blocks] == [True, False, True]
    assert updates[0] > 0


def test_settling_is_on_unless_asked_off_on_the_command_line():
    from safeswitch.cli import build_parser

    base = ["adapt", "--model", "certified", "--out", "x"]
    assert build_parser().parse_args(base).settle is True
    assert build_parser().parse_args([*base, "--no-settle"]).settle is False


def test_the_exploration_noise_narrows_with_the_episodes_deployed():
    from safeswitch.app.adapt import NoiseSchedule

    class Policy(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.log_std = torch.nn.Parameter(torch.zeros(1), requires_grad=False)

    class Model:
        policy = Policy()

    share = [0.0]
    schedule = NoiseSchedule(np.array([-2.0]), np.log(0.25), lambda: share[0])
    schedule.model = model = Model()
    for share[0], expected in ((0.0, 0.1353), (0.5, 0.0677), (1.0, 0.0338), (1.2, 0.0338)):
        schedule._on_rollout_start()
        assert float(Model.policy.log_std.exp()) == pytest.approx(expected, abs=1e-4)
        assert model.learning_paused is False
    # settled: no noise, and the update after the rollout is skipped; then back on schedule
    settled = [True]
    schedule = NoiseSchedule(np.array([-2.0]), np.log(0.25), lambda: 0.5, lambda: settled[0])
    schedule.model = model
    schedule._on_rollout_start()
    assert float(Model.policy.log_std) == adapt_module.SETTLED_LOG_STD and model.learning_paused
    settled[0] = False
    schedule._on_rollout_start()
    assert float(Model.policy.log_std.exp()) == pytest.approx(0.0677, abs=1e-4)
    assert model.learning_paused is False


@pytest.mark.slow
def test_the_summary_reports_both_distributions_and_the_policy_evaluates(tmp_path, capsys):
    out = tmp_path / "a"
    args = ["adapt", "--model", "certified", "--out", str(out), "--set", SHIFT[0],
            "--episodes", "96", "--block", "48", "--n-envs", "8", "--eval-episodes", "40",
            "--no-progress"]  # fmt: skip
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "shifted: safety action in" in printed and "original: safety action in" in printed
    summary = json.loads((out / "summary.json").read_text())
    for where in ("shifted", "original"):
        for who in ("frozen", "adapted"):
            assert summary[where][who]["episodes"] == 40
    assert summary["shift"] == SHIFT
    for block in summary["blocks"]:
        assert set(block) >= {"episodes", "collisions", "failures", "safety_activation_episodes",
                              "mean_efficiency", "speeding_episodes", "held_out"}  # fmt: skip
        assert 0.3 < block["mean_efficiency"] <= 1.05
        # where the certified recipe's constraint multipliers stand after the block
        assert set(block["multipliers"]) == {"comfort", "safety", "clear_time", "uncleared"}
        assert all(0 <= m <= 1000 for m in block["multipliers"].values())
    assert (out / "adaptation.png").stat().st_size > 10_000
    # the adapted policy is a run directory evaluate accepts, deployed under certified
    assert main(["evaluate", "--model", str(out), "--episodes", "5", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["switching"] == "certified"


@pytest.mark.slow
def test_resume_continues_after_the_last_complete_block(tmp_path, monkeypatch):
    out = tmp_path / "a"
    blocks_done = []
    real = adapt_module.write_snapshot

    def interrupt_after_first(folder, model, env, state):
        real(folder, model, env, state)
        if folder.name != "checkpoint":  # the selected policy's snapshot
            return
        blocks_done.append(len(state["blocks"]))
        if len(state["blocks"]) == 1:
            raise KeyboardInterrupt

    monkeypatch.setattr(adapt_module, "write_snapshot", interrupt_after_first)
    with pytest.raises(KeyboardInterrupt):
        adapt("certified", out, **SMALL)
    first = json.loads((out / "checkpoint" / "state.json").read_text())["blocks"]
    assert len(first) == 1 and not (out / "summary.json").exists()
    monkeypatch.setattr(adapt_module, "write_snapshot", real)
    with pytest.raises(AdaptError, match="asked differently"):
        adapt("certified", out, **{**SMALL, "episodes": 144}, resume=True)
    summary = adapt("certified", out, **SMALL, resume=True)
    assert summary["blocks"][0] == first[0]  # kept as it was measured
    assert [b["episodes"] for b in summary["blocks"]] == [48, 48]
    with pytest.raises(AdaptError, match="already complete"):
        adapt("certified", out, **SMALL, resume=True)


def test_a_bad_shift_is_refused_before_anything_is_written(tmp_path, capsys):
    with pytest.raises(ConfigError, match=r"env\.scenarios has no key 'ego_speed'"):
        adapt("certified", tmp_path / "a", settings=["env.scenarios.ego_speed=[1, 2]"])
    assert not (tmp_path / "a").exists()
    code = main(["adapt", "--model", "certified", "--out", str(tmp_path / "b"), "--set",
                 "ppo.gamma=0.9"])  # fmt: skip
    assert code == 2 and "env.KEY=VALUE" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


def test_the_training_terms_follow_the_deployment_logic():
    """The paper policy was trained under ``guarded`` with penalties and a safety constraint
    on guarded's reasons; deployed under ``certified`` they keep what certified has."""
    from safeswitch.app.adapt import learning_terms
    from safeswitch.app.evaluate import controller_setup
    from safeswitch.leftturn.task import LeftTurnTask

    config = load_policy("paper").config
    assert config.shaping.reason_penalties and config.constraints.safety.reasons
    reasons = LeftTurnTask(controller_setup("rule", None, "certified")[0]).reasons
    shaping, constraints = learning_terms(config, reasons)
    assert shaping.reason_penalties == {} and shaping.counterfactual_penalty == 0.0
    assert constraints.safety.reasons == ()  # every safety action of certified counts
    assert constraints.safety.budget == config.constraints.safety.budget
    assert constraints.overrule is None
    same, _ = learning_terms(config, (*reasons, *config.shaping.reason_penalties))
    assert same.reason_penalties == config.shaping.reason_penalties


@pytest.mark.slow
def test_the_deployed_exploration_noise_is_the_size_asked(tmp_path):
    """``noise`` sets the exploration noise the policy is deployed with (the shipped
    ``certified`` policy's is fixed, so the adapted one keeps it); a bad value is refused before
    anything is written, and a resume must ask the same."""
    for bad in (0.0, float("nan"), 2.0):
        with pytest.raises(AdaptError, match=rf"--noise must be .*got {bad}"):
            adapt("certified", tmp_path / "bad", **SMALL, noise=bad)
    assert not (tmp_path / "bad").exists()
    trained = load_policy("certified").model.policy.log_std.detach().numpy()
    out = tmp_path / "a"
    adapt("certified", out, **{**SMALL, "episodes": 48}, noise=0.05, noise_decay=1.0)
    assert json.loads((out / "adapt.json").read_text())["noise"] == 0.05
    adapted = load_policy(out).model.policy.log_std.detach().numpy()
    np.testing.assert_allclose(adapted, np.log(0.05), rtol=1e-6)
    assert not np.allclose(trained, np.log(0.05))
    with pytest.raises(AdaptError, match="asked differently"):
        adapt(
            "certified", out, **{**SMALL, "episodes": 48}, noise=0.1, noise_decay=1.0, resume=True
        )


@pytest.mark.slow
def test_the_rehearsing_environments_replay_the_original_scenarios_and_are_not_counted(
    tmp_path, monkeypatch
):
    """With ``rehearsal``, a quarter of the environments draw the policy's original
    distribution (the north car at 20–32 km/h) and the blocks count only the deployed, shifted
    episodes (at 38–44 km/h)."""
    seen = []
    real = adapt_module.DeploymentMonitor.summary

    def spy(self, rows):
        seen.extend(3.6 * row["scenario"]["north_speed"] for row in rows)
        return real(self, rows)

    monkeypatch.setattr(adapt_module.DeploymentMonitor, "summary", spy)
    shift = ["env.scenarios.north_speed_kmh=[38, 44]"]
    summary = adapt("certified", tmp_path / "a", **{**SMALL, "settings": shift})
    assert summary["rehearsal"] == 0.25
    assert len(seen) == 96 and min(seen) >= 38 - 1e-9 and max(seen) <= 44 + 1e-9
    assert [b["episodes"] for b in summary["blocks"]] == [48, 48]


def test_rehearsal_and_the_noise_decay_are_validated_before_anything_is_written(tmp_path):
    for bad in (-0.1, 1.0, float("nan")):
        message = rf"--rehearsal must be a share in \[0, 1\), got {bad}"
        with pytest.raises(AdaptError, match=message):
            adapt("certified", tmp_path / "a", **SMALL, rehearsal=bad)
    for bad in (0.0, 1.5):
        message = rf"--noise-decay must be a share in \(0, 1\], got {bad}"
        with pytest.raises(AdaptError, match=message):
            adapt("certified", tmp_path / "a", **SMALL, noise_decay=bad)
    with pytest.raises(AdaptError, match="leaves none deployed"):
        adapt("certified", tmp_path / "a", **{**SMALL, "n_envs": 2}, rehearsal=0.75)
    # the original scenarios replayed on another plant would not be a rehearsal
    other_plant = [*SHIFT, "env.vehicle.mass=1950"]
    with pytest.raises(AdaptError, match=r"scenario distribution alone.*--rehearsal 0"):
        adapt("certified", tmp_path / "a", **{**SMALL, "settings": other_plant})
    assert not (tmp_path / "a").exists()


def _evaluated(safety, efficiency, collisions=0, episodes=1000):
    return {"episodes": episodes, "collisions": collisions,
            "safety_activation_episodes": safety, "mean_efficiency": efficiency}  # fmt: skip


def test_the_selection_ranks_the_targets_before_the_efficiency():
    from safeswitch.app.adapt import selection_key

    frozen = {"held_out": _evaluated(120, 0.84), "held_out_original": _evaluated(15, 0.83)}
    key = lambda shift, original: selection_key(  # noqa: E731
        {"shifted": shift, "original": original}, frozen
    )
    within = key(_evaluated(20, 0.85), _evaluated(15, 0.825))
    assert within == (0.0, -0.85)
    # within every target, the more efficient on the shift wins
    assert key(_evaluated(5, 0.86), _evaluated(10, 0.83)) < within
    # a faster policy that needs the filter more often than 2 % of the shift's episodes loses
    assert key(_evaluated(21, 0.95), _evaluated(10, 0.83)) > within
    # ... as does a safe one slower than the frozen policy on the shift
    assert key(_evaluated(0, 0.83), _evaluated(10, 0.83)) > within
    # ... and one that forgets: the original distribution's efficiency falls by > 0.01
    assert key(_evaluated(5, 0.90), _evaluated(10, 0.815)) > within
    # smaller excesses rank first; any collision ranks last
    assert key(_evaluated(30, 0.85), _evaluated(10, 0.83)) < key(
        _evaluated(40, 0.9), _evaluated(10, 0.83)
    )
    assert key(_evaluated(0, 0.9, collisions=1), _evaluated(0, 0.9))[0] >= 1e9
    # on the original distribution, a policy that needs the filter more often than the frozen
    # one did has an excess, even within 2 % (no forgetting); the frozen policy's share is the
    # limit, above 2 % too
    assert key(_evaluated(20, 0.85), _evaluated(16, 0.825)) == (0.001, -0.85)
    frozen["held_out_original"] = _evaluated(100, 0.83)
    assert key(_evaluated(20, 0.85), _evaluated(100, 0.83)) == (0.0, -0.85)
