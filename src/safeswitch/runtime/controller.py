"""The exported controller for one vehicle: the ONNX policy, the Safety controller and the
switching logic, tick by tick, with numpy, numba and onnxruntime only.

:meth:`Controller.decide` runs exactly what a tick of the left-turn environment runs before the
plant (:meth:`~safeswitch.leftturn.task.LeftTurnTask.switch`: ``PID_th``, ``PID_b``,
``PID_lka``, who proposes, the learned controller's speed limiter, the supervision step) on a
batch of one, so the runtime decides as the environment does — the same code, not a copy
(``tests/deploy/test_runtime.py`` drives both side by side). The controller keeps its own
memory (the PID states, the learned action held between decisions); the vehicle gives its
measurements each tick (:class:`Measurement`).

A **deadline**: if the policy's inference takes longer than ``deadline_s``, its action is
not used. The switch then treats the tick as one without a learned action — the framework's
one rule for a learned action that is not there (:func:`~safeswitch.core.switching.supervise`):
the pedals are held if the logic accepts holding them, else the logic's safety action (the
Safety controller's brake, or the certified logic's own backup) runs — and the miss is logged
with reason ``deadline_missed``. (Braking blindly wherever the car is can stop it in the
oncoming car's path; holding, judged by the logic, cannot under ``certified``.)

Every intervention is logged: the logger ``safeswitch.runtime`` (INFO; deadline misses at
WARNING) and :attr:`Controller.interventions`.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import yaml
from numpy.typing import NDArray

from safeswitch.core.config import from_dict
from safeswitch.core.pid import PIDState
from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.task import CONTROLLERS, LeftTurnTask, TaskState
from safeswitch.sim.vehicle import VehicleState
from safeswitch.sim.world import WorldState

if TYPE_CHECKING:
    from safeswitch.leftturn.task import ControllerMemory

LOG = logging.getLogger("safeswitch.runtime")

#: The manifest format this runtime reads (written by ``safeswitch export``).
FORMAT, FORMAT_VERSION = "safeswitch-controller", 1
#: Reason of a tick whose learned action missed the deadline.
DEADLINE_MISSED = "deadline_missed"


class ControllerLoadError(ValueError):
    """An export folder cannot be run; the message names the file and why."""


class Measurement(NamedTuple):
    """What the vehicle measures at one tick, SI units (the ego and the oncoming car).

    Attributes:
        ego_x: Ego's centre of gravity, east [m].
        ego_y: Ego's centre of gravity, north [m].
        ego_yaw: Ego's heading, counter-clockwise from east [rad].
        ego_speed: Ego's speed [m/s].
        ego_progress: Ego's arc length along its route (scene.yaml's geometry) [m].
        ego_accel_lon: Ego's longitudinal acceleration on the last tick [m/s²] (``PID_b``'s
            feedback).
        ego_throttle: Throttle position now, in [0, 1].
        ego_brake: Brake position now, in [0, 1].
        other_x: Oncoming car's centre of gravity, east [m].
        other_y: Oncoming car's centre of gravity, north [m].
        other_speed: Oncoming car's speed [m/s].
        other_progress: Oncoming car's arc length along its route [m].
        other_top_speed: The fastest the oncoming car will drive [m/s] (the certified logic's
            assumption; in the simulator, its set speed).
    """

    ego_x: float
    ego_y: float
    ego_yaw: float
    ego_speed: float
    ego_progress: float
    ego_accel_lon: float
    ego_throttle: float
    ego_brake: float
    other_x: float
    other_y: float
    other_speed: float
    other_progress: float
    other_top_speed: float


class Pedals(NamedTuple):
    """The ego's commands for this tick: throttle and brake in [0, 1], steering in [-1, 1]."""

    throttle: float
    brake: float
    steer: float


@dataclass(frozen=True)
class SwitchDecision:
    """Who drove this tick and why.

    Attributes:
        tick: Ticks since :meth:`Controller.reset`.
        source: ``learned``, ``rule`` (``PID_th``, outside the learned controller's scope) or
            ``safety`` (a safety action ran).
        reason: The logic's reason name (``learned`` when the learned action ran),
            ``invalid_learned_action``, ``rule_in_charge`` or ``deadline_missed``.
        safety_active: The learned controller was overruled (the paper's ``s*``).
        learned_action: The policy's action ``a`` in [-1, 1] this tick (NaN when it missed the
            deadline).
        inference_s: The policy's inference time this tick [s] (0 between decisions).
        deadline_missed: The inference exceeded the deadline.
    """

    tick: int
    source: str
    reason: str
    safety_active: bool
    learned_action: float
    inference_s: float
    deadline_missed: bool


class OnnxPolicy:
    """The exported policy's deterministic action on one observation (onnxruntime, one
    thread)."""

    def __init__(self, path: Path, threads: int = 1) -> None:
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        self.input = self.session.get_inputs()[0].name

    def __call__(self, observation: NDArray[np.float32]) -> float:
        out = self.session.run(None, {self.input: observation.reshape(1, -1)})[0]
        return float(out[0, 0])


def read_manifest(folder: Path) -> dict[str, Any]:
    """The export folder's manifest, checked (format, version, files present)."""
    path = folder / "manifest.json"
    if not path.is_file():
        raise ControllerLoadError(
            f"{path} is missing: not an export folder, or an export that did not finish "
            "(run safeswitch export --model M --out DIR)"
        )
    try:
        manifest: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ControllerLoadError(f"{path} is not valid JSON ({exc})") from exc
    if manifest.get("format") != FORMAT or manifest.get("format_version") != FORMAT_VERSION:
        raise ControllerLoadError(
            f"{path}: format {manifest.get('format')!r} version "
            f"{manifest.get('format_version')!r}; this runtime reads {FORMAT!r} version "
            f"{FORMAT_VERSION}"
        )
    for name in ("policy.onnx", "scene.yaml"):
        if not (folder / name).is_file():
            raise ControllerLoadError(f"{folder / name} is missing")
    return manifest


class Controller:
    """The exported left-turn controller for one vehicle.

    Args:
        folder: An export folder (``safeswitch export``).
        deadline_s: Inference budget per decision [s] (``None``: none).
        threads: onnxruntime's threads.

    Raises:
        ControllerLoadError: The folder is incomplete, of another format, or holds a controller
            this runtime does not run (the manifest's ``runtime.scope`` says why).
    """

    def __init__(
        self, folder: str | Path, *, deadline_s: float | None = None, threads: int = 1
    ) -> None:
        self.folder = Path(folder)
        self.manifest = read_manifest(self.folder)
        runtime = self.manifest.get("runtime", {})
        if not runtime.get("supported", False):
            raise ControllerLoadError(
                f"{self.folder}: the runtime does not run this controller: {runtime.get('scope')}"
            )
        if deadline_s is not None and not (math.isfinite(deadline_s) and deadline_s > 0):
            raise ValueError(f"deadline_s must be a positive number of seconds, got {deadline_s}")
        self.deadline_s = deadline_s
        scene = yaml.safe_load((self.folder / "scene.yaml").read_text(encoding="utf-8"))
        self.config = from_dict(LeftTurnConfig, scene, "scene.yaml")
        self.task = LeftTurnTask(self.config)
        #: The policy: observation → action ``a``; replaceable (e.g. to test the deadline).
        self.policy: Callable[[NDArray[np.float32]], float] = OnnxPolicy(
            self.folder / "policy.onnx", threads
        )
        self._interval = self.config.episode.decision_interval
        #: Every intervention since :meth:`reset`: tick, reason, learned action, executed pedals.
        self.interventions: list[dict[str, Any]] = []
        self.reset()

    def __repr__(self) -> str:
        deadline = "none" if self.deadline_s is None else f"{self.deadline_s * 1e3:g} ms"
        return (
            f"Controller({str(self.folder)!r}, switching={self.config.switching!r}, "
            f"deadline={deadline}, tick={self._tick})"
        )

    def reset(self) -> None:
        """Start an episode: the controllers' memory as at an episode's start, no learned
        action held, the intervention log emptied."""
        self._memory: ControllerMemory = self.task.controller_memory(1)
        self._tick = 0
        self._held = 0.0
        self.interventions = []

    def decide(
        self, observation: NDArray[np.float32] | Any, state: Measurement
    ) -> tuple[Pedals, SwitchDecision]:
        """This tick's pedals and steering, and who decided them.

        Args:
            observation: The policy's observation (manifest ``observation.layout``).
            state: The measurements the switch reads.
        """
        obs = np.asarray(observation, dtype=np.float32).reshape(-1)
        inference, missed = 0.0, False
        if self._tick % self._interval == 0:
            start = time.perf_counter()
            action = self.policy(obs)
            inference = time.perf_counter() - start
            missed = self.deadline_s is not None and inference > self.deadline_s
            self._held = math.nan if missed else action
        switched = self.task.switch(self._task_state(state), np.array([self._held]))
        out, sup = switched.controllers, switched.supervision
        self._memory = type(self._memory)(
            PIDState(*out.pid_throttle),
            PIDState(*out.pid_brake),
            PIDState(*out.pid_lane),
            PIDState(*out.pid_north),
        )
        reason = self.task.reasons[int(sup.reason[0])]
        active = bool(sup.safety_active[0])
        if not out.in_charge[0] and not active:
            source, reason = "rule", self.task.reasons[-1]
        else:
            source = CONTROLLERS[2] if active else CONTROLLERS[0]
        if missed:
            reason = DEADLINE_MISSED
        pedals = Pedals(
            float(sup.executed[0, 0]), float(sup.executed[0, 1]), float(out.steer[0, 0])
        )
        decision = SwitchDecision(self._tick, source, reason, active, self._held, inference, missed)
        if active:
            self._log(decision, pedals)
        self._tick += 1
        return pedals, decision

    def _log(self, decision: SwitchDecision, pedals: Pedals) -> None:
        entry = {
            "tick": decision.tick,
            "reason": decision.reason,
            "learned_action": decision.learned_action,
            "throttle": pedals.throttle,
            "brake": pedals.brake,
        }
        self.interventions.append(entry)
        if decision.deadline_missed:
            LOG.warning(
                "tick %d: inference took %.3f ms, over the %.3f ms deadline; learned action "
                "not used (throttle %.3f, brake %.3f)",
                decision.tick,
                1e3 * decision.inference_s,
                1e3 * (self.deadline_s or 0.0),
                pedals.throttle,
                pedals.brake,
            )
        else:
            LOG.info(
                "tick %d: safety action (%s): throttle %.3f, brake %.3f instead of a = %.3f",
                decision.tick,
                decision.reason,
                pedals.throttle,
                pedals.brake,
                decision.learned_action,
            )

    def _task_state(self, m: Measurement) -> TaskState:
        """The measurements and the controllers' memory as the task's state of one episode
        (what the switch reads; the oncoming car's heading and the plant's history are not
        read)."""

        def pair(ego: float, other: float) -> NDArray[np.float64]:
            return np.array([[ego, other]], dtype=np.float64)

        vehicles = VehicleState(
            x=pair(m.ego_x, m.other_x),
            y=pair(m.ego_y, m.other_y),
            cos_yaw=pair(math.cos(m.ego_yaw), 1.0),
            sin_yaw=pair(math.sin(m.ego_yaw), 0.0),
            speed=pair(m.ego_speed, m.other_speed),
            throttle=pair(m.ego_throttle, 0.0),
            brake=pair(m.ego_brake, 0.0),
            steer=pair(0.0, 0.0),
        )
        world = WorldState(
            vehicles, pair(m.ego_progress, m.other_progress), np.zeros((1, 2)), np.zeros(1)
        )
        scenarios = Scenarios(
            *(
                np.array([m.other_top_speed if f.name == "north_speed" else 0.0])
                for f in fields(Scenarios)
            )
        )
        memory = self._memory
        return TaskState(
            world,
            scenarios,
            memory.throttle,
            memory.brake,
            memory.lane,
            memory.north,
            np.array([m.ego_accel_lon]),
            np.array([self._tick]),
            np.zeros(1, dtype=np.int8),
            None,
        )


def measurement_of(state: TaskState, index: int = 0) -> Measurement:
    """The measurements of episode ``index`` of a left-turn task's state: what a vehicle in
    that situation would give :meth:`Controller.decide`."""
    v, progress = state.world.vehicles, state.world.progress
    return Measurement(
        ego_x=float(v.x[index, 0]),
        ego_y=float(v.y[index, 0]),
        ego_yaw=float(math.atan2(v.sin_yaw[index, 0], v.cos_yaw[index, 0])),
        ego_speed=float(v.speed[index, 0]),
        ego_progress=float(progress[index, 0]),
        ego_accel_lon=float(state.accel_lon[index]),
        ego_throttle=float(v.throttle[index, 0]),
        ego_brake=float(v.brake[index, 0]),
        other_x=float(v.x[index, 1]),
        other_y=float(v.y[index, 1]),
        other_speed=float(v.speed[index, 1]),
        other_progress=float(progress[index, 1]),
        other_top_speed=float(state.scenarios.north_speed[index]),
    )
