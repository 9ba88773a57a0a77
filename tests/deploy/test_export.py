"""``safeswitch export`` (issue #42): the ONNX policy equals the torch one, the normalisation is
folded in, a failed parity check writes nothing, the manifest states what a deployment needs."""

import json

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import yaml

from safeswitch.cli import main
from safeswitch.deploy import export as export_module
from safeswitch.deploy.export import ExportError, export, left_turn_action, left_turn_observation
from safeswitch.deploy.onnx_policy import OPSET, policy_graph
from safeswitch.leftturn.config import ControllerConfig, EpisodeConfig
from safeswitch.training.policies import load_policy
from safeswitch.training.shipped import SHIPPED, SHIPPED_DIR

#: Every shipped left-turn policy that has a trained network.
TRAINED = sorted(
    name
    for name, folder in SHIPPED.items()
    if (SHIPPED_DIR / folder / "model.zip").is_file()
    and name != "shipped"
    and not name.startswith("highway-")
)
#: The shipped highway-env policies (their observations come from highway-env, about 10 ms a
#: step: 10,000 of them, not 100,000).
HIGHWAY = sorted(name for name in SHIPPED if name.startswith("highway-"))


def session(folder):
    return ort.InferenceSession(str(folder / "policy.onnx"), providers=["CPUExecutionProvider"])


def test_onnx_equals_torch_within_the_tolerance_including_clipped_observations(exported):
    folder = exported("paper")
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["parity"]["max_abs_diff"] <= 1e-5
    assert manifest["parity"]["observations"] == 4_000
    policy = load_policy("paper")
    # Observations far outside the training statistics: VecNormalize's clip must be folded in
    # (without it, these actions differ by far more than the tolerance).
    rng = np.random.default_rng(3)
    obs = rng.uniform(-400, 400, (5_000, 6)).astype(np.float32)
    onnx_actions = session(folder).run(None, {"observation": obs})[0]
    torch_actions, _ = policy.model.predict(policy.normalise(obs), deterministic=True)
    assert np.abs(onnx_actions - torch_actions).max() <= 1e-5
    assert np.all(np.abs(onnx_actions) <= 1.0)


def test_the_graph_is_a_valid_onnx_model_of_the_stated_opset(exported):
    model = onnx.load(str(exported("paper") / "policy.onnx"))
    onnx.checker.check_model(model, full_check=True)
    assert model.opset_import[0].version == OPSET
    ops = {node.op_type for node in model.graph.node}
    assert {"Sub", "Div", "Clip", "Gemm", "Tanh"} <= ops  # normalisation folded in


def test_manifest_states_layout_units_logic_assumptions_and_versions(exported):
    manifest = json.loads((exported("certified") / "manifest.json").read_text())
    assert [c["name"] for c in manifest["observation"]["layout"]] == [
        "x_e", "y_e", "v_e", "x_n", "y_n", "v_n"]  # fmt: skip
    assert all(c["unit"] for c in manifest["observation"]["layout"])
    assert manifest["switch"]["logic"] == "certified"
    assert any("other_top_speed" in a for a in manifest["switch"]["assumptions"])
    assert manifest["versions"]["onnxruntime"] != "not installed"
    assert manifest["runtime"]["supported"] is True
    assert manifest["policy"]["opset"] == OPSET
    # `certified` works both pedals (controllers.learned_brake); `paper` has the paper's throttle
    assert "a < 0 the brake -a" in manifest["action"]["layout"][0]["meaning"]
    paper = json.loads((exported("paper") / "manifest.json").read_text())
    assert "throttle = (a + 1) / 2" in paper["action"]["layout"][0]["meaning"]


def test_a_speed_set_point_action_is_stated_as_one():
    commanded = ControllerConfig(learned_speed_command_kmh=29.9)
    meaning = left_turn_action(commanded)[0]["meaning"]
    assert "speed set point" in meaning and "29.9 km/h" in meaning and "0.6" in meaning
    assert "throttle = (a + 1) / 2" in left_turn_action(ControllerConfig())[0]["meaning"]
    pedals = left_turn_action(ControllerConfig(learned_brake=True))[0]["meaning"]
    assert "the brake -a" in pedals


def test_the_observed_time_left_is_stated_as_the_last_input():
    names = [entry["name"] for entry in left_turn_observation(EpisodeConfig())]
    assert names == ["x_e", "y_e", "v_e", "x_n", "y_n", "v_n"]
    timed = left_turn_observation(EpisodeConfig(observe_time_left=True, horizon_s=8.0))
    assert [entry["name"] for entry in timed] == [*names, "t_left"]
    assert timed[-1]["unit"] == "s" and "8 s horizon" in timed[-1]["meaning"]


def test_a_failed_parity_check_writes_nothing(tmp_path, monkeypatch):
    real = policy_graph

    def perturbed(policy, go_model=None):
        model = real(policy, go_model)
        bias = next(t for t in model.graph.initializer if t.name == "b0")
        values = onnx.numpy_helper.to_array(bias).copy()
        values[0] += 0.5  # the first hidden unit's bias, as a broken export would have it
        bias.CopyFrom(onnx.numpy_helper.from_array(values, "b0"))
        return model

    monkeypatch.setattr(export_module, "policy_graph", perturbed)
    with pytest.raises(ExportError, match="parity check failed"):
        export("paper", tmp_path / "out", observations=2_000)
    assert not (tmp_path / "out").exists()


def test_the_switching_override_is_validated(tmp_path):
    with pytest.raises(ExportError, match="'nonsense' is not a registered logic"):
        export("paper", tmp_path / "out", switching="nonsense", observations=10)


def test_cli_exports_and_reports_parity(tmp_path, capsys):
    out = tmp_path / "exported"
    code = main(["export", "--model", "paper", "--out", str(out), "--observations", "2000"])
    assert code == 0
    text = capsys.readouterr().out
    assert "parity: max |ONNX - torch|" in text and "2,000 observations" in text
    assert {p.name for p in out.iterdir()} == {"policy.onnx", "scene.yaml", "manifest.json"}
    # A used folder is refused without --overwrite, in one line.
    assert main(["export", "--model", "paper", "--out", str(out), "--observations", "10"]) == 2
    assert "not empty" in capsys.readouterr().err


@pytest.mark.slow
def test_a_traffic_policy_exports_the_policy_and_says_the_runtime_does_not_run_it(exported):
    """`traffic-certified` reads a learned go predictor (``traffic.go_model``): the export folds
    it into the graph, as for the left turn's, and the scene it writes leaves it to the graph."""
    folder = exported("traffic-certified")
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["parity"]["max_abs_diff"] <= 1e-5
    assert manifest["parity"]["go_probability_max_abs_diff"] <= 1e-5
    assert "traffic.go_model" in manifest["policy"]["go_predictor"]
    assert yaml.safe_load((folder / "scene.yaml").read_text())["traffic"]["go_model"] is None
    assert manifest["runtime"]["supported"] is False
    assert "traffic" in manifest["runtime"]["scope"]


@pytest.mark.slow
@pytest.mark.parametrize("name", TRAINED)
def test_every_shipped_policy_exports_within_1e5_on_100000_observations(tmp_path, name):
    result = export(name, tmp_path / name)
    assert result.observations == 100_000
    assert result.max_abs_diff <= 1e-5


@pytest.mark.slow
@pytest.mark.parametrize("name", HIGHWAY)
def test_the_highway_policies_export_from_their_own_plant_within_1e5(tmp_path, name):
    pytest.importorskip("highway_env")
    result = export(name, tmp_path / name, observations=10_000)
    assert result.max_abs_diff <= 1e-5
    manifest = json.loads((tmp_path / name / "manifest.json").read_text())
    assert manifest["source"]["env_id"] == "safeswitch/Highway-v0"
    assert manifest["switch"]["logic"] == name.removeprefix("highway-")
    assert manifest["parity"]["observations"] == 10_000
