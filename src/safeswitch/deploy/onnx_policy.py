"""A trained policy's deterministic action as one ONNX graph, observation statistics folded in.

The graph is written node by node from the network's weights (no tracing): what SB3's
deterministic ``predict`` computes for a ``MlpPolicy`` with a flat Box observation, in the same
order and precision —

1. the observation normalised as ``VecNormalize.normalize_obs`` does it, in float64:
   ``clip((obs − mean) / sqrt(var + ε), −clip_obs, clip_obs)``, then cast to float32;
2. the actor's layers (``Linear`` → ``Gemm``; ``Tanh``, ``ReLU``, ``ELU``, ``LeakyReLU`` → their
   ONNX operators) and the action head: the Gaussian's mean;
3. the mean clipped to the action space's bounds (``Min`` then ``Max``, per component).

A policy whose observation ends with a learned go predictor's probability
(``episode.go_model``) gets the predictor in front (its tanh MLP, the logit clipped, a
``Sigmoid``, then ``Concat`` with the input): the graph then reads the observation without that
value, as a vehicle gives it.

Anything else (a squashed or state-dependent-noise policy, a CNN or dict feature extractor, an
activation not listed) is refused by name rather than exported approximately.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from safeswitch.leftturn.go_model import GO_LOGIT_BOUND, GoModel

if TYPE_CHECKING:
    from safeswitch.training.policies import TrainedPolicy

#: The ONNX operator set the graphs are written for.
OPSET = 17
#: Names of the graph's input and output.
INPUT, OUTPUT = "observation", "action"
#: A folded go predictor's probability, the graph's second output.
GO_OUTPUT = "go_probability"


class ExportError(ValueError):
    """A policy cannot be exported faithfully; the message says what and why."""


def _activation(layer: Any) -> tuple[str, dict[str, Any]] | None:
    """The ONNX operator (and its attributes) of an activation layer, ``None`` if unknown."""
    import torch

    if isinstance(layer, torch.nn.Tanh):  # NumpyTanh is a subclass: the same function
        return "Tanh", {}
    if isinstance(layer, torch.nn.ReLU):
        return "Relu", {}
    if isinstance(layer, torch.nn.ELU):
        return "Elu", {"alpha": float(layer.alpha)}
    if isinstance(layer, torch.nn.LeakyReLU):
        return "LeakyRelu", {"alpha": float(layer.negative_slope)}
    return None


def policy_graph(policy: TrainedPolicy, go_model: GoModel | None = None) -> onnx.ModelProto:
    """The ONNX model of ``policy``'s deterministic action: input ``observation`` float32
    ``[N, *obs_shape]`` (raw, as the environment gives it; an observation of more than one
    axis, such as highway-env's ``[vehicles, features]``, is flattened after its statistics
    are applied, as SB3's ``FlattenExtractor`` does), output ``action`` float32 ``[N, A]``.
    With ``go_model`` (the policy's ``episode.go_model``) the predictor is folded in: the
    input is the observation without its last value, which the graph computes from the rest
    as :class:`~safeswitch.leftturn.go_model.GoModel` does, and gives as a second output
    ``go_probability`` float32 ``[N, 1]`` (the action stays the first).

    Raises:
        ExportError: The policy is not an MLP policy with a Box observation and a flat Box
            action.
    """
    import torch
    from gymnasium import spaces
    from stable_baselines3.common.torch_layers import FlattenExtractor

    model = policy.model
    net = model.policy
    where = f"the policy in {policy.path}"
    obs_space, act_space = net.observation_space, net.action_space
    if not isinstance(obs_space, spaces.Box) or len(obs_space.shape) < 1:
        raise ExportError(f"{where}: only a Box observation exports, got {obs_space}")
    if not isinstance(act_space, spaces.Box) or len(act_space.shape) != 1:
        raise ExportError(f"{where}: only a flat Box action exports, got {act_space}")
    if not isinstance(net.features_extractor, FlattenExtractor):
        raise ExportError(
            f"{where}: its features extractor {type(net.features_extractor).__name__} does not "
            "export (only FlattenExtractor)"
        )
    if getattr(net, "squash_output", False) or getattr(net, "use_sde", False):
        raise ExportError(f"{where}: squashed or gSDE policies do not export")
    if not getattr(net, "share_features_extractor", True) and net.pi_features_extractor is None:
        raise ExportError(f"{where}: no actor features extractor")

    nodes: list[onnx.NodeProto] = []
    inits: list[onnx.TensorProto] = []

    def constant(name: str, value: np.ndarray) -> str:
        inits.append(numpy_helper.from_array(value, name))
        return name

    x = INPUT
    input_shape = obs_space.shape
    if go_model is not None:
        if len(obs_space.shape) != 1 or go_model.mean.shape[0] != obs_space.shape[0] - 1:
            raise ExportError(
                f"{where}: its go predictor reads {go_model.mean.shape[0]} values, its "
                f"observation has {obs_space.shape}"
            )
        input_shape = (obs_space.shape[0] - 1,)
        nodes += [
            helper.make_node("Sub", [x, constant("go_mean", go_model.mean)], ["go_centred"]),
            helper.make_node("Mul", ["go_centred", constant("go_scale", go_model.scale)], ["go0"]),
        ]
        for i, (w, b) in enumerate(go_model.layers):
            gemm = [f"go{i}", constant(f"go_w{i}", w), constant(f"go_b{i}", b)]
            nodes.append(helper.make_node("Gemm", gemm, [f"go_lin{i}"]))
            if i < len(go_model.layers) - 1:
                nodes.append(helper.make_node("Tanh", [f"go_lin{i}"], [f"go{i + 1}"]))
        last = f"go_lin{len(go_model.layers) - 1}"
        bound = np.float32(GO_LOGIT_BOUND)
        nodes += [
            helper.make_node(
                "Clip",
                [last, constant("go_low", np.array(-bound)), constant("go_high", np.array(bound))],
                ["go_logit"],
            ),
            helper.make_node("Sigmoid", ["go_logit"], ["go_probability"]),
            helper.make_node("Concat", [x, "go_probability"], ["with_go"], axis=1),
        ]
        x = "with_go"
    normalizer = policy.normalizer
    if normalizer is not None:
        rms: Any = normalizer.obs_rms
        if isinstance(rms, dict):
            raise ExportError(f"{where}: per-key (dict) observation statistics do not export")
        mean = np.asarray(rms.mean, dtype=np.float64)
        std = np.sqrt(np.asarray(rms.var, dtype=np.float64) + normalizer.epsilon)
        clip = float(normalizer.clip_obs)
        nodes += [
            helper.make_node("Cast", [x], ["obs64"], to=TensorProto.DOUBLE),
            helper.make_node("Sub", ["obs64", constant("obs_mean", mean)], ["centred"]),
            helper.make_node("Div", ["centred", constant("obs_std", std)], ["scaled"]),
            helper.make_node(
                "Clip",
                [
                    "scaled",
                    constant("clip_low", np.array(-clip)),
                    constant("clip_high", np.array(clip)),
                ],
                ["clipped"],
            ),
            helper.make_node("Cast", ["clipped"], ["normalised"], to=TensorProto.FLOAT),
        ]
        x = "normalised"

    if len(obs_space.shape) > 1:
        nodes.append(helper.make_node("Flatten", [x], ["flat"], axis=1))
        x = "flat"
    layers = [*net.mlp_extractor.policy_net, net.action_net]
    for index, layer in enumerate(layers):
        out = f"layer{index}"
        if isinstance(layer, torch.nn.Linear):
            weight = layer.weight.detach().cpu().numpy().astype(np.float32)
            inputs = [x, constant(f"W{index}", weight)]
            if layer.bias is not None:
                inputs.append(constant(f"b{index}", layer.bias.detach().cpu().numpy()))
            nodes.append(helper.make_node("Gemm", inputs, [out], transB=1))
        else:
            op = _activation(layer)
            if op is None:
                raise ExportError(
                    f"{where}: layer {index} ({type(layer).__name__}) does not export"
                )
            nodes.append(helper.make_node(op[0], [x], [out], **op[1]))
        x = out
    low = np.asarray(act_space.low, dtype=np.float32)
    high = np.asarray(act_space.high, dtype=np.float32)
    nodes += [
        helper.make_node("Min", [x, constant("action_high", high)], ["below_high"]),
        helper.make_node("Max", ["below_high", constant("action_low", low)], [OUTPUT]),
    ]
    outputs = [helper.make_tensor_value_info(OUTPUT, TensorProto.FLOAT, ["N", act_space.shape[0]])]
    if go_model is not None:  # second, for the parity check: the predictor's own value
        outputs.append(helper.make_tensor_value_info(GO_OUTPUT, TensorProto.FLOAT, ["N", 1]))
    graph = helper.make_graph(
        nodes,
        "safeswitch_policy",
        [helper.make_tensor_value_info(INPUT, TensorProto.FLOAT, ["N", *input_shape])],
        outputs,
        inits,
    )
    onnx_model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="safeswitch",
        doc_string="Deterministic action of a safeswitch policy (observation statistics folded in)",
    )
    onnx.checker.check_model(onnx_model, full_check=True)
    return onnx_model
