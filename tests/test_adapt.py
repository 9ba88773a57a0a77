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


def test_an_adversarial_update_still_cannot_collide_under_certified(tmp_path, monkeypatch):
    """Every update drives the actor to full throttle (the action head's bias to +5): the
    policy the switch supervises changes each rollout, for the worse, and no block collides."""
    original = SwitchPPO.train

    def adversarial(self):
        original(self)
        with torch.no_grad():
            self.policy.action_net.bias.fill_(5.0)

    monkeypatch.setattr(SwitchPPO, "train", adversarial)
    summary = adapt("certified", tmp_path / "a", **SMALL)
    blocks = summary["blocks"]
    assert [b["episodes"] for b in blocks] == [48, 48]
    assert all(b["collisions"] == 0 and b["failures"] == 0 for b in blocks)
    assert summary["collisions"] == summary["failures"] == 0
    # the update took hold: the deployed policy is the full-throttle one, overruled often
    assert blocks[-1]["safety_activation_episodes"] == 48
    adapted = load_policy(tmp_path / "a")
    assert adapted.act(np.zeros((1, 6), dtype=np.float32))[0] == pytest.approx(1.0)


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
    adapt("certified", out, **{**SMALL, "episodes": 48}, noise=0.05)
    assert json.loads((out / "adapt.json").read_text())["noise"] == 0.05
    adapted = load_policy(out).model.policy.log_std.detach().numpy()
    np.testing.assert_allclose(adapted, np.log(0.05), rtol=1e-6)
    assert not np.allclose(trained, np.log(0.05))
    with pytest.raises(AdaptError, match="asked differently"):
        adapt("certified", out, **{**SMALL, "episodes": 48}, noise=0.1, resume=True)
