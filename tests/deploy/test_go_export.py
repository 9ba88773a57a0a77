"""A left-turn policy with a go predictor in its observation (``episode.go_model``) exports with
the predictor folded into the ONNX graph, and the runtime runs it on the six values a vehicle
gives, deciding exactly as the environment."""

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
import yaml

from safeswitch.deploy import export as export_module
from safeswitch.deploy.export import export, go_predictor, parity
from safeswitch.deploy.onnx_policy import ExportError, policy_graph
from safeswitch.leftturn.go_model import GoModel
from safeswitch.leftturn.make import build_task
from safeswitch.runtime import Controller
from safeswitch.training.config import comparable, load_config
from safeswitch.training.pipeline import train
from safeswitch.training.policies import load_policy

from .test_runtime import drive

MODEL = Path(load_config("certified").env.episode.go_model)  # packaged beside the recipe


@pytest.fixture(scope="module")
def go_run(tmp_path_factory):
    """A short run of the `certified` recipe, with its packaged predictor (its policy need not
    be good: the export must reproduce whatever it computes)."""
    config = replace(load_config("certified"), timesteps=8192, n_envs=32, eval_episodes=50)
    run = tmp_path_factory.mktemp("go_run")
    train(config, run, progress_bar=False)
    return run


def test_the_predictor_is_folded_into_the_graph_and_the_runtime_decides_as_the_env(
    go_run, tmp_path
):
    result = export(go_run, tmp_path / "exported", observations=3_000)
    manifest = json.loads((result.folder / "manifest.json").read_text())
    assert manifest["policy"]["input"]["shape"] == ["N", 6]
    assert manifest["policy"]["go_predictor"].startswith("folded in")
    assert [e["name"] for e in manifest["observation"]["layout"]][-1] == "v_n"
    assert manifest["runtime"]["supported"] is True and result.max_abs_diff <= 1e-5
    # each folded part checked on its reference's inputs, the compound difference reported
    check = manifest["parity"]
    assert check["go_probability_max_abs_diff"] == result.parity.go_max_abs_diff <= 1e-5
    assert check["end_to_end_max_abs_diff"] == result.parity.end_to_end_max_abs_diff
    scene = yaml.safe_load((result.folder / "scene.yaml").read_text())
    assert scene["episode"]["go_model"] is None  # the graph computes it; nothing to ship beside
    # the graph's predictor is the task's: on six values it gives the policy's seventh
    policy = load_policy(go_run)
    session = ort.InferenceSession(str(result.folder / "policy.onnx"),
                                   providers=["CPUExecutionProvider"])  # fmt: skip
    rng = np.random.default_rng(0)
    six = rng.uniform([-40, -40, 0, -40, -40, 0], [40, 40, 10, 40, 40, 12], (500, 6))
    six = six.astype(np.float32)
    seven = np.concatenate([six, GoModel(str(MODEL), 6, "episode.go_model")(six)[:, None]], 1)
    onnx_actions = session.run(None, {"observation": six})[0][:, 0]
    torch_actions = np.asarray(policy.act(seven)).reshape(-1)
    np.testing.assert_allclose(onnx_actions, torch_actions, atol=1e-5)
    # the runtime, given the six values, drives exactly as the environment with the policy
    controller = Controller(result.folder)
    task = controller.task
    assert task.observation_bounds[0].shape == (6,)
    env_task = build_task(None, policy.config.deployed_env)
    scenarios = env_task.scenario_set(1_000_003, 6)
    for i in range(6):
        state = env_task.initial(scenarios.take(np.array([i])))
        for _, pedals, decision in drive(controller, scenarios, i):
            if decision.tick % task.config.episode.decision_interval == 0:
                seen = env_task.observe(state)
                assert abs(policy.act(seen)[0] - decision.learned_action) <= 1e-5
            state, expected = env_task.step(state, np.array([decision.learned_action]))
            assert (expected.throttle[0], expected.brake[0]) == (pedals.throttle, pedals.brake)


def test_a_run_keeps_its_go_predictor_beside_its_config_and_loads_wherever_it_is_moved(
    go_run, tmp_path
):
    """The run copies the file its recipe names into its folder and names it there by its file
    name, so the folder (a shipped policy's, a copied run) is whole: moved elsewhere, it loads
    and acts as before."""
    named = yaml.safe_load((go_run / "config.yaml").read_text())["env"]["episode"]["go_model"]
    assert named == MODEL.name and (go_run / named).read_bytes() == MODEL.read_bytes()
    moved = Path(shutil.copytree(go_run, tmp_path / "elsewhere" / "run"))
    config = load_config(moved / "config.yaml")
    assert Path(config.env.episode.go_model) == (moved / MODEL.name).resolve()
    seven = np.random.default_rng(1).uniform(-1, 1, (64, 7)).astype(np.float32)
    np.testing.assert_array_equal(load_policy(moved).act(seven), load_policy(go_run).act(seven))
    # and its recipe compares equal to the packaged one that made it, whose file it copied
    trained = replace(config, timesteps=8192, n_envs=32, eval_episodes=50)
    packaged = replace(load_config("certified"), timesteps=8192, n_envs=32, eval_episodes=50)
    assert trained != packaged and comparable(trained) == comparable(packaged)


def test_a_folded_predictor_that_disagrees_with_the_environment_is_refused(go_run, tmp_path):
    """The predictor is checked as its own part: a probability off by 1e-3 (as a predictor the
    graph got wrong would be) fails the check, and export writes nothing, naming it."""
    policy = load_policy(go_run)
    go = go_predictor(policy)
    graph = policy_graph(policy, go).SerializeToString()
    task = build_task(None, policy.config.deployed_env)
    seen = task.observe(task.initial(task.scenario_set(5, 64)))
    good = parity(graph, policy, seen, folded=True)
    assert good.go_max_abs_diff <= 1e-5 and good.max_abs_diff <= 1e-5
    off = seen.copy()
    off[:, -1] += 1e-3
    assert parity(graph, policy, off, folded=True).go_max_abs_diff >= 9e-4
    bad = replace(good, go_max_abs_diff=1e-3)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(export_module, "parity", lambda *args, **kwargs: bad)
        with pytest.raises(ExportError, match=r"go predictor's probability .*0\.001"):
            export(go_run, tmp_path / "refused", observations=500)
    assert not (tmp_path / "refused").exists()
