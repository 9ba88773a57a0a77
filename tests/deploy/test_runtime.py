"""``safeswitch.runtime`` (issue #42): the exported controller decides exactly as the
environment does, runs without the training stack, honours its deadline and logs every
intervention with its reason."""

import json
import logging
import math
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml

from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.make import build_task
from safeswitch.runtime import DEADLINE_MISSED, Controller, ControllerLoadError, measurement_of
from safeswitch.training.policies import load_policy


def drive(controller, scenarios, index, on_decision=None):
    """One episode of ``scenarios[index]`` with the runtime in the loop and the embedded
    simulator as the plant; yields (record, pedals, decision) per tick."""
    task = controller.task
    state = task.initial(scenarios.take(np.array([index])))
    controller.reset()
    observation = task.observe(state)
    for _ in range(task.config.episode.horizon_ticks):
        pedals, decision = controller.decide(observation[0], measurement_of(state))
        if on_decision is not None:
            on_decision(observation, decision)
        state, record = task.step(state, np.array([decision.learned_action]))
        yield record, pedals, decision
        observation = record.observation
        if record.terminated[0] or record.truncated[0]:
            return


@pytest.fixture
def windowed(exported, tmp_path):
    """The paper policy's export with the paper's Algorithm 1 scope: ``PID_th`` drives outside
    the intersection window, so the rule's memory matters on every tick."""
    folder = tmp_path / "windowed"
    shutil.copytree(exported("paper"), folder)
    scene = yaml.safe_load((folder / "scene.yaml").read_text())
    scene["episode"]["learned_scope"] = "window"
    (folder / "scene.yaml").write_text(yaml.safe_dump(scene))
    return folder


@pytest.mark.parametrize(
    ("model", "switching", "scope"),
    [
        pytest.param("paper", None, "episode", marks=pytest.mark.slow),
        ("certified", "certified", "episode"),
        pytest.param("paper", None, "window", marks=pytest.mark.slow),
    ],
)
def test_the_runtime_decides_exactly_as_the_environment(
    exported, windowed, model, switching, scope
):
    controller = Controller(windowed if scope == "window" else exported(model, switching))
    assert controller.config.episode.learned_scope == scope
    task = controller.task
    torch_policy = load_policy(model)
    # with the `certified` policy's go predictor the environment is the policy's own (its
    # seventh value the predictor's probability, which the runtime's graph computes itself)
    env_task = task
    if torch_policy.config.env.episode.go_model is not None:
        env_task = build_task(None, torch_policy.config.deployed_env)
    go = env_task.go_model
    # end to end the predictor's and the policy's float32 roundings compound (docs/deploy.md)
    tolerance = 1e-5 if go is None else 2e-5
    scenarios = task.scenario_set(1_000_003, 12)
    interval = task.config.episode.decision_interval
    ticks, sources, outcomes = 0, set(), []

    def same_action_as_torch(observation, decision):
        if decision.tick % interval == 0:
            seen = (
                observation
                if go is None
                else np.concatenate([observation, go(observation)[:, None]], 1)
            )
            assert abs(torch_policy.act(seen)[0] - decision.learned_action) <= tolerance

    for i in range(12):
        for record, pedals, decision in drive(controller, scenarios, i, same_action_as_torch):
            # The environment's tick, given the runtime's learned action, executed exactly the
            # runtime's pedals for exactly the runtime's reason.
            assert (record.throttle[0], record.brake[0]) == (pedals.throttle, pedals.brake)
            assert task.reasons[record.reason[0]] == decision.reason
            assert bool(record.safety_active[0]) == decision.safety_active
            expected = ("learned", "rule", "safety")[record.controller[0]]
            assert decision.source == expected
            ticks += 1
            sources.add(decision.source)
        outcomes.append((bool(record.collision[0]), int(record.outcome[0])))
    assert ticks > 1_000
    assert sources >= ({"learned", "rule"} if scope == "window" else {"learned"})
    # The same episodes driven by the torch policy through the environment end the same way.
    result = rollout(env_task, scenarios, torch_policy.as_policy())
    assert outcomes == list(zip(result.collision.tolist(), result.outcome.tolist(), strict=True))


def test_every_intervention_is_logged_with_its_reason(exported, caplog):
    controller = Controller(exported("paper"))
    # The shipped policy rarely meets the paper logic (under 2 % of episodes): find, in one
    # batched rollout, a scenario where it does, then drive that one through the runtime.
    scenarios = controller.task.scenario_set(1_000_003, 1000)
    result = rollout(controller.task, scenarios, load_policy("paper").as_policy())
    acting = np.flatnonzero(result.safety_steps > 0)
    assert acting.size, "no safety action in 1,000 episodes: drive an adversary instead"
    caplog.set_level(logging.INFO, logger="safeswitch.runtime")
    active = [d for _, _, d in drive(controller, scenarios, int(acting[0])) if d.safety_active]
    assert active  # the runtime meets it too: it decides as the environment does
    logged = controller.interventions
    assert [e["tick"] for e in logged] == [d.tick for d in active]
    assert [e["reason"] for e in logged] == [d.reason for d in active]
    assert all(e["reason"] not in ("learned", "rule_in_charge") for e in logged)
    assert sum("safety action" in r.getMessage() for r in caplog.records) == len(active)


class Slow:
    """The exported policy with an injected delay."""

    def __init__(self, policy, delay_s):
        self.policy, self.delay_s = policy, delay_s

    def __call__(self, observation):
        time.sleep(self.delay_s)
        return self.policy(observation)


def test_a_missed_deadline_never_executes_the_learned_action(exported, caplog):
    folder = exported("certified", "certified")
    late = Controller(folder, deadline_s=0.002)
    late.policy = Slow(late.policy, 0.005)
    task = late.task
    scenarios = task.scenario_set(1_000_003, 3)
    caplog.set_level(logging.WARNING, logger="safeswitch.runtime")
    misses = 0
    for i in range(3):
        for record, _, decision in drive(late, scenarios, i):
            if decision.tick % task.config.episode.decision_interval == 0:
                assert decision.deadline_missed and decision.reason == DEADLINE_MISSED
                assert math.isnan(decision.learned_action) and decision.safety_active
                assert decision.inference_s > 0.002
                misses += 1
            assert record.collision[0] == 0
            assert not record.safety_active[0] or decision.safety_active
    assert misses > 50
    assert sum("deadline" in r.getMessage() for r in caplog.records) == misses
    assert len([e for e in late.interventions if e["reason"] == DEADLINE_MISSED]) > 0


def test_no_deadline_miss_within_budget(exported):
    controller = Controller(exported("paper"), deadline_s=1.0)
    scenarios = controller.task.scenario_set(1_000_003, 2)
    episodes = [[d for _, _, d in drive(controller, scenarios, i)] for i in range(2)]
    assert not any(d.deadline_missed for episode in episodes for d in episode)
    # What a user sees at a prompt: the folder, the logic, the budget and where the episode is.
    text = repr(controller)
    assert f"{str(exported('paper'))!r}" in text and "switching='paper'" in text
    assert "deadline=1000 ms" in text and f"tick={len(episodes[1])})" in text


def test_bad_deadline_and_incomplete_folders_are_refused(exported, tmp_path):
    with pytest.raises(ValueError, match="deadline_s must be a positive number of seconds, got 0"):
        Controller(exported("paper"), deadline_s=0)
    with pytest.raises(ControllerLoadError, match=r"manifest\.json is missing"):
        Controller(tmp_path)
    with pytest.raises(ControllerLoadError, match="trained in traffic"):
        Controller(exported("traffic-certified"))
    broken = tmp_path / "broken"
    broken.mkdir()
    manifest = json.loads((exported("paper") / "manifest.json").read_text())
    (broken / "manifest.json").write_text(json.dumps({**manifest, "format_version": 99}))
    with pytest.raises(ControllerLoadError, match="version 99"):
        Controller(broken)


_WITHOUT_TRAINING_STACK = """
import importlib.abc, json, sys

class Absent(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("torch", "stable_baselines3", "gymnasium"):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

if sys.argv[2] == "absent":
    sys.meta_path.insert(0, Absent())
from safeswitch.runtime import Controller, Measurement
controller = Controller(sys.argv[1])
pedals, decision = controller.decide(
    [1.75, -36.0, 5.6, -1.75, 32.1, 8.6],
    Measurement(1.75, -36.0, 1.5708, 5.6, 20.0, 0.0, 0.3, 0.0, -1.75, 32.1, 8.6, 20.0, 8.6),
)
heavy = sorted(m for m in sys.modules if m.split(".")[0] in ("torch", "stable_baselines3",
                                                              "gymnasium"))
print(json.dumps({"heavy": heavy, "throttle": pedals.throttle, "source": decision.source}))
"""


@pytest.mark.parametrize("stack", ["installed", "absent"])
def test_the_runtime_imports_no_torch_sb3_or_gymnasium(exported, stack):
    done = subprocess.run(
        [sys.executable, "-c", _WITHOUT_TRAINING_STACK, str(exported("paper")), stack],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["heavy"] == []
    assert 0.0 <= out["throttle"] <= 1.0
