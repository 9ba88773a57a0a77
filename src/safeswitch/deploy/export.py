"""``safeswitch export``: a trained policy as ONNX, with its switch's parameters and a manifest,
checked against the original on observations of its own evaluation episodes.

The folder (see docs/deploy.md):

* ``policy.onnx`` — the deterministic action, observation normalisation (and a left-turn
  policy's go predictor, ``episode.go_model``) folded in (:mod:`~safeswitch.deploy.onnx_policy`);
* ``scene.yaml`` — the scene the policy is deployed in: the switching logic's and the Safety
  controller's parameters (``switching``, ``paper``/``certified``, ``controllers``), the
  vehicle, the geometry and the tick: everything :class:`safeswitch.runtime.Controller` builds
  the switch from (a plant of a user's: its training configuration);
* ``manifest.json`` — versions, the observation and action layouts with units, the logic and
  its assumptions, the parity check's result. Written last: a folder without it is incomplete,
  and the runtime refuses it.

Parity: the ONNX actions must equal SB3's deterministic ``predict`` (torch) within
``tolerance`` on ``observations`` observations drawn from evaluation episodes of the policy
itself; otherwise nothing is written and the command fails. A folded go predictor is checked
as its own part: its probability against the environment's within ``tolerance``, and the
actions against torch's given that probability (:func:`parity`).
"""

from __future__ import annotations

import hashlib
import platform
from dataclasses import dataclass, replace
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from gymnasium.spaces import Box
from numpy.typing import NDArray

from safeswitch.core.config import to_dict
from safeswitch.deploy.onnx_policy import INPUT, OPSET, ExportError, policy_graph
from safeswitch.io import prepare_output_dir, write_atomic, write_bytes_atomic, write_json
from safeswitch.leftturn.go_model import GoModel

#: Manifest format written here and read by :mod:`safeswitch.runtime`.
FORMAT = "safeswitch-controller"
FORMAT_VERSION = 1
#: Largest tolerated |ONNX − torch| action difference (issue #42).
TOLERANCE = 1e-5
#: Seed of the evaluation episodes the parity observations come from (the evaluation seed of
#: the README's tables: never a training scenario).
PARITY_SEED = 1_000_003

#: The left turn's observation and action, as the manifest states them.
LEFT_TURN_OBSERVATION = [
    {"name": "x_e", "unit": "m", "meaning": "ego's centre of gravity, east"},
    {"name": "y_e", "unit": "m", "meaning": "ego's centre of gravity, north"},
    {"name": "v_e", "unit": "m/s", "meaning": "ego's speed"},
    {"name": "x_n", "unit": "m", "meaning": "north car's centre of gravity, east"},
    {"name": "y_n", "unit": "m", "meaning": "north car's centre of gravity, north"},
    {"name": "v_n", "unit": "m/s", "meaning": "north car's speed"},
]


def left_turn_observation(episode: Any) -> list[dict[str, str]]:
    """The left turn's observation as the manifest states it, for the scene's ``episode``."""
    if not episode.observe_time_left:
        return LEFT_TURN_OBSERVATION
    left = f"time left to the episode's {episode.horizon_s:g} s horizon"
    return [*LEFT_TURN_OBSERVATION, {"name": "t_left", "unit": "s", "meaning": left}]


def left_turn_action(controllers: Any) -> list[dict[str, str]]:
    """The left turn's action as the manifest states it, for the scene's ``controllers``."""
    top = controllers.learned_speed_command_kmh
    if controllers.learned_brake:
        meaning = "learned pedals: a >= 0 the throttle a, a < 0 the brake -a (throttle closed)"
    elif top is None:
        meaning = "learned throttle command: throttle = (a + 1) / 2; the brake stays released"
    else:
        meaning = (
            f"learned speed set point: v* = (a + 1) / 2 · {top:g} km/h, tracked by the learned "
            f"controller's throttle (gain {controllers.learned_speed_command_gain:g} per m/s); "
            "the brake stays released"
        )
    return [{"name": "a", "unit": "1", "meaning": meaning}]


#: What each built-in logic's claim rests on (docs/certified.md, docs/leftturn.md).
ASSUMPTIONS = {
    "paper": [
        "the paper's rule (Algorithm 1): a time-to-reach comparison and a speed threshold; a "
        "heuristic with no collision-freedom guarantee",
        "perfect perception: positions and speeds exact, no latency",
    ],
    "certified": [
        "the other car drives its route and never exceeds other_top_speed (its set speed)",
        "perfect perception: positions, speeds and arc lengths exact, no latency",
        "the ego's brakes deliver the modelled deceleration on the modelled road (tyre "
        "friction μ of scene.yaml's vehicle)",
        "the switch runs every tick (dt of scene.yaml's episode)",
    ],
}


@dataclass
class ExportResult:
    """What :func:`export` wrote and measured.

    Attributes:
        folder: The export folder.
        manifest: The manifest written.
        observations: How many observations the parity check used.
        parity: Every measure of the parity check.
    """

    folder: Path
    manifest: dict[str, Any]
    observations: int
    parity: Parity

    @property
    def max_abs_diff(self) -> float:
        """Largest |ONNX − torch| action difference on the parity observations (given the
        same policy inputs: :class:`Parity`)."""
        return self.parity.max_abs_diff


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for package in (
        "safeswitch",
        "numpy",
        "onnx",
        "onnxruntime",
        "torch",
        "stable-baselines3",
        "gymnasium",
    ):
        try:
            out[package] = version(package)
        except PackageNotFoundError:
            out[package] = "not installed"
    return out


def left_turn_observations(
    policy: Any, config: Any, traffic: Any, count: int, seed: int = PARITY_SEED
) -> NDArray[np.float32]:
    """``count`` observations the policy meets in its own evaluation episodes (random
    scenarios under ``seed``, the episodes' live ticks only), in episode order."""
    from safeswitch.evaluation.rollout import rollout
    from safeswitch.leftturn.make import build_task

    task = build_task(None, config, traffic=traffic)
    seen: list[NDArray[np.float32]] = []
    total, chunk = 0, 256
    act = policy.as_policy()
    live = np.ones(chunk, dtype=bool)

    def recording(obs: NDArray[np.float32], state: Any, tick: int) -> NDArray[np.float64]:
        seen.append(obs[live].copy())
        return act(obs, state, tick)

    def on_tick(state: Any, record: Any, tick: int) -> None:
        live[:] &= ~(record.terminated | record.truncated)

    first = 0
    while total < count:
        live[:] = True
        scenarios = task.draw_scenarios(
            seed, np.arange(first, first + chunk), np.zeros(chunk, dtype=np.int64)
        )
        before = len(seen)
        rollout(task, scenarios, recording, on_tick)
        total += sum(len(o) for o in seen[before:])
        first += chunk
    return np.concatenate(seen)[:count]


def env_observations(policy: Any, config: Any, count: int, seed: int = PARITY_SEED) -> Any:
    """``count`` observations the policy meets in its own episodes of the plant it was trained
    on (``config``, an :class:`~safeswitch.training.config.EnvTrainConfig`: its environment,
    logic, penalty and keyword arguments; deterministic actions; one seed per episode from
    ``seed``)."""
    from safeswitch.training.generic import make_supervised_env

    env = make_supervised_env(
        config.env_id, config.switching, config.penalty, config.logic_params, **config.env_kwargs
    )
    seen: list[Any] = []
    episode = 0
    try:
        while len(seen) < count:
            obs, _ = env.reset(seed=seed + episode)
            done = False
            while not done and len(seen) < count:
                seen.append(np.asarray(obs, dtype=np.float32))
                obs, _, terminated, truncated, _ = env.step(policy.act_one(obs))
                done = terminated or truncated
            episode += 1
    finally:
        env.close()
    return np.stack(seen)


@dataclass(frozen=True)
class Parity:
    """The parity check's measures (:func:`parity`).

    Attributes:
        max_abs_diff: Largest |ONNX − torch| action difference given the same policy inputs
            (with a folded go predictor: torch given the graph's own probability).
        actions: The ONNX actions.
        go_max_abs_diff: With a folded go predictor, the largest |ONNX − numpy| difference
            of its probability (numpy: :class:`~safeswitch.leftturn.go_model.GoModel`, as
            in training); else ``None``.
        end_to_end_max_abs_diff: Largest difference between the ONNX action on the vehicle's
            values and torch's on the environment's observation (the two float32 roundings
            of a folded predictor compound, amplified by the network; equal to
            ``max_abs_diff`` without one).
    """

    max_abs_diff: float
    actions: NDArray[np.float32]
    go_max_abs_diff: float | None
    end_to_end_max_abs_diff: float


def parity(
    onnx_bytes: bytes, policy: Any, observations: NDArray[np.float32], folded: bool = False
) -> Parity:
    """The ONNX graph against torch (SB3's deterministic ``predict`` on the normalised
    observations) on ``observations``. With ``folded`` the graph computes the observations'
    last value (a go predictor's probability) itself and is given the rest; each translated
    part is then checked on the same inputs as its reference: the predictor against the
    environment's value, the policy against torch given the graph's probability."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(onnx_bytes, options, providers=["CPUExecutionProvider"])
    given = observations[:, :-1] if folded else observations
    outputs = session.run(None, {INPUT: given})
    actions = np.asarray(outputs[0], dtype=np.float32)

    def torch_actions(inputs: NDArray[np.float32]) -> NDArray[np.float32]:
        reference, _ = policy.model.predict(policy.normalise(inputs), deterministic=True)
        return np.asarray(reference, dtype=np.float32).reshape(actions.shape)

    end_to_end = float(np.max(np.abs(actions - torch_actions(observations))))
    if not folded:
        return Parity(end_to_end, actions, None, end_to_end)
    probability = np.asarray(outputs[1], dtype=np.float32).reshape(-1, 1)
    go = float(np.max(np.abs(probability[:, 0] - observations[:, -1])))
    same = np.concatenate([given, probability], axis=1)
    worst = float(np.max(np.abs(actions - torch_actions(same))))
    return Parity(worst, actions, go, end_to_end)


def go_predictor(policy: Any) -> GoModel | None:
    """The left-turn policy's go predictor (``episode.go_model``, or in traffic
    ``traffic.go_model``: the task's own, :attr:`~safeswitch.leftturn.task.LeftTurnTask.go_model`),
    which its export folds into the graph; ``None`` for a policy without one or of another
    plant."""
    from safeswitch.leftturn.make import build_task
    from safeswitch.training.config import TrainConfig

    config = policy.config
    if not isinstance(config, TrainConfig):
        return None
    return build_task(None, config.env, traffic=config.traffic_settings).go_model


def runtime_support(policy: Any) -> tuple[bool, str]:
    """Whether :class:`safeswitch.runtime.Controller` runs the exported controller, and why
    not."""
    from safeswitch.training.config import TrainConfig

    if not isinstance(policy.config, TrainConfig):
        return False, (
            f"trained on {policy.config.env_id}: its Safety controller and switching logic are "
            "Python objects of the user's plant; the ONNX policy runs anywhere, the switch "
            "stays the plant's own"
        )
    if policy.config.traffic is not None:
        return False, (
            "trained in traffic: the traffic logics read every vehicle's state and the streams' "
            "phantoms, which the one-vehicle runtime does not take yet"
        )
    return True, "the paper's scene (one oncoming car)"


def export(
    model: str | Path,
    out: str | Path,
    *,
    switching: str | None = None,
    observations: int = 100_000,
    tolerance: float = TOLERANCE,
    overwrite: bool = False,
) -> ExportResult:
    """Export ``model`` (a run directory, a checkpoint or a shipped policy's name) to ``out``.

    Args:
        model: The policy.
        out: The export folder.
        switching: The switching logic to deploy under (default: the run's deployment logic).
        observations: Observations of the parity check.
        tolerance: Largest tolerated |ONNX − torch| action difference.
        overwrite: Replace the files of an earlier export in ``out``.

    Raises:
        ExportError: The policy does not export, or the parity check failed (nothing written).
    """
    from safeswitch.core.registry import logic_names
    from safeswitch.training.config import TrainConfig
    from safeswitch.training.policies import load_policy

    if observations < 1:
        raise ExportError(f"--observations must be at least 1, got {observations}")
    if not tolerance > 0:
        raise ExportError(f"the parity tolerance must be positive, got {tolerance}")
    policy = load_policy(model)
    go = go_predictor(policy)
    graph = policy_graph(policy, go)
    onnx_bytes = graph.SerializeToString()
    config = policy.config
    if isinstance(config, TrainConfig):
        scene = config.deployed_env
        if switching is not None:
            if switching not in logic_names():
                raise ExportError(
                    f"--switching {switching!r} is not a registered logic "
                    f"(known: {', '.join(sorted(logic_names()))})"
                )
            scene = replace(scene, switching=switching)
        seen = left_turn_observations(policy, scene, config.traffic_settings, observations)
        # the graph computes the predictor's value: the vehicle gives the values before it
        scene = replace(scene, episode=replace(scene.episode, go_model=None))
        scene_dict: dict[str, Any] = to_dict(scene)
        if config.traffic is not None:
            traffic = config.traffic_settings
            assert traffic is not None
            # the graph computes the predictor's value here too
            scene_dict = {"env": scene_dict, "traffic": to_dict(replace(traffic, go_model=None))}
        observation_layout = (
            left_turn_observation(scene.episode) if config.traffic is None else None
        )
        action_layout = left_turn_action(scene.controllers) if config.traffic is None else None
        logic: str | None = scene.switching
        decision_interval, dt = scene.episode.decision_interval, scene.episode.dt
        env_id = "safeswitch/LeftTurnTraffic-v0" if config.traffic else "safeswitch/LeftTurn-v0"
        assumptions = ASSUMPTIONS.get(str(logic), ["see the logic's documentation"])
    else:
        seen = env_observations(policy, config, observations)
        scene_dict = to_dict(config)
        observation_layout = action_layout = None
        logic = switching or config.switching
        decision_interval, dt = 1, None
        env_id = config.env_id
        # ASSUMPTIONS are the left turn's logics'; a plant's logic documents its own
        assumptions = [f"see the documentation of the {logic!r} logic for {env_id}"]
    check = parity(onnx_bytes, policy, seen, folded=go is not None)
    worst = check.max_abs_diff
    if not worst <= tolerance:
        raise ExportError(
            f"parity check failed: the ONNX actions differ from torch's by up to {worst:.3g} on "
            f"{len(seen):,} observations (tolerance {tolerance:g}); nothing was written"
        )
    if check.go_max_abs_diff is not None and not check.go_max_abs_diff <= tolerance:
        raise ExportError(
            f"parity check failed: the folded go predictor's probability differs from the "
            f"environment's by up to {check.go_max_abs_diff:.3g} on {len(seen):,} observations "
            f"(tolerance {tolerance:g}); nothing was written"
        )
    supported, why = runtime_support(policy)
    space, action_space = policy.model.observation_space, policy.model.action_space
    assert isinstance(space, Box) and isinstance(action_space, Box)  # checked by policy_graph
    given = slice(0, -1 if go is not None else None)  # the graph's input
    low, high = np.asarray(space.low)[given], np.asarray(space.high)[given]
    manifest: dict[str, Any] = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "source": {"model": str(model), "path": str(policy.path), "env_id": env_id},
        "versions": _versions(),
        "policy": {
            "file": "policy.onnx",
            "sha256": hashlib.sha256(onnx_bytes).hexdigest(),
            "opset": OPSET,
            "ir_version": int(graph.ir_version),
            "input": {"name": INPUT, "dtype": "float32", "shape": ["N", *map(int, low.shape)]},
            "output": {
                "name": "action",
                "dtype": "float32",
                "shape": ["N", int(action_space.shape[0])],
            },
            "normalisation": "folded in" if policy.normalizer is not None else "none",
            "go_predictor": "folded in: the graph computes the policy's last observed value "
            f"({go.setting}) from its input"
            if go is not None
            else "none",
            "deterministic": "the Gaussian's mean, clipped to the action bounds",
        },
        "observation": {
            "layout": observation_layout,
            "low": low.tolist(),
            "high": high.tolist(),
        },
        "action": {
            "layout": action_layout,
            "low": np.asarray(action_space.low).tolist(),
            "high": np.asarray(action_space.high).tolist(),
        },
        "decision_interval_ticks": decision_interval,
        "dt_s": dt,
        "switch": {
            "logic": logic,
            "assumptions": assumptions,
            "parameters": "scene.yaml",
        },
        "parity": {
            "observations": len(seen),
            "from": f"evaluation episodes of the policy (seed {PARITY_SEED})",
            "max_abs_diff": worst,
            **(
                {
                    "go_probability_max_abs_diff": check.go_max_abs_diff,
                    "end_to_end_max_abs_diff": check.end_to_end_max_abs_diff,
                    "checked": "each part on the same inputs as its reference: the go "
                    "predictor against the environment's probability, the policy against "
                    "torch given the graph's probability",
                }
                if check.go_max_abs_diff is not None
                else {}
            ),
            "tolerance": tolerance,
            "reference": "stable-baselines3 predict(deterministic=True), torch, CPU",
        },
        "runtime": {"supported": supported, "scope": why},
    }
    folder = prepare_output_dir(out, overwrite)
    write_bytes_atomic(folder / "policy.onnx", onnx_bytes)
    write_atomic(folder / "scene.yaml", yaml.safe_dump(scene_dict, sort_keys=False))
    write_json(folder / "manifest.json", manifest)
    return ExportResult(folder, manifest, len(seen), check)


def main_summary(result: ExportResult) -> str:
    """The command's closing lines."""
    runtime = result.manifest["runtime"]
    lines = [
        f"exported to {result.folder}: policy.onnx (opset {OPSET}), scene.yaml, manifest.json",
        f"parity: max |ONNX - torch| = {result.max_abs_diff:.2e} on {result.observations:,} "
        f"observations (tolerance {result.manifest['parity']['tolerance']:g})"
        + (
            f"; the folded go predictor's probability {result.parity.go_max_abs_diff:.2e}, "
            f"end to end {result.parity.end_to_end_max_abs_diff:.2e}"
            if result.parity.go_max_abs_diff is not None
            else ""
        ),
        "runtime: safeswitch.runtime.Controller runs it"
        if runtime["supported"]
        else f"runtime: policy only ({runtime['scope']})",
    ]
    return "\n".join(lines)
