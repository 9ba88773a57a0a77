"""A training run's directory, safe to interrupt and resume, and the left turn as a plant of
the one training pipeline (:mod:`safeswitch.training.pipeline`, which every plant trains
through).

Run directory::

    config.yaml          the resolved configuration
    progress.csv         one row per rollout (see training.callbacks)
    validation.csv       one row per validation (with ``validation.every``; training.validation)
    constraints.csv      what each constraint measured and its multiplier, per update (with
                         ``constraints``; training.constraints)
    *.discarded.csv      rows a run wrote after its last checkpoint before it was killed
                         (set aside by ``--resume``, which starts again from that checkpoint)
    best/                the best validated policy so far (model.zip, vecnormalize.pkl, its score)
    last/                the last policy, when the run's policy is the best validated one
    tb/                  TensorBoard logs
    checkpoints/step_N/  model.zip, vecnormalize.pkl, state.json (written whole, then renamed)
    warm_start.json      what the warm start did (if configured; written before PPO starts)
    model.zip            the run's policy: the last one, or the best validated one
    vecnormalize.pkl     its observation/reward statistics
    training_curves.png  the paper's Fig. 5 from progress.csv (drawn by the train command)
    metrics.json         written last: a run is complete exactly when this file exists
"""

from __future__ import annotations

import csv
import io
import json
import shutil
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.utils import LinearSchedule
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from safeswitch.evaluation.evaluate import run_controller, summary_against_oracle
from safeswitch.io import complete_checkpoints, write_atomic, write_snapshot
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.vec_env import LeftTurnVecEnv
from safeswitch.training.activations import NumpyTanh
from safeswitch.training.callbacks import ProgressLines, TrainingMonitor
from safeswitch.training.config import (
    ConstraintsConfig,
    EnvTrainConfig,
    ShapingConfig,
    TrainConfig,
    dump_config,
    write_config_with_files,
)
from safeswitch.training.constraints import CONSTRAINTS_LOG, ConstraintCosts, ConstraintUpdate
from safeswitch.training.interventions import InterventionRecorder
from safeswitch.training.plant import Plant
from safeswitch.training.policies import TrainedPolicy, load_policy
from safeswitch.training.ppo import SwitchPPO
from safeswitch.training.shaping import (
    ClearTimePenalty,
    CounterfactualLog,
    CounterfactualPenalty,
    PenaltySchedule,
    ProgressShaping,
    ReasonPenalty,
    ShapingSchedule,
)
from safeswitch.training.validation import Validator
from safeswitch.training.warm_start import check_start_policy, start_from_policy, warm_start


class RunDirectoryError(RuntimeError):
    """The run directory cannot be used as asked (exists, incomplete, or has no checkpoint)."""


def _activation(name: str, fast_tanh: bool = False) -> type[torch.nn.Module]:
    if name != "tanh":
        return torch.nn.ReLU
    return NumpyTanh if fast_tanh else torch.nn.Tanh


class LearningEnv:
    """The learning-only wrappers a configuration asks for, around the batched environment:
    progress shaping, the reason penalties, the minimum-time cost, the constraints' costs
    (each only if configured, in that order), and the callbacks that move them over the run.
    What the learner sees (``env``); what the task pays is what ``vec`` records.

    Args:
        vec: The batched left-turn environment.
        shaping: The configuration's ``shaping`` section.
        gamma: PPO's discount (the progress shaping's potential is discounted with it).
        constraints: The configuration's ``constraints`` section (default: none).
        deploy_switching: The logic the policy is deployed under (the counterfactual
            penalty's; needed only with ``shaping.counterfactual_penalty``).
    """

    def __init__(
        self,
        vec: LeftTurnVecEnv,
        shaping: ShapingConfig,
        gamma: float,
        constraints: ConstraintsConfig | None = None,
        deploy_switching: str | None = None,
    ) -> None:
        self.shaping = shaping
        self.shaped = (
            ProgressShaping(vec, shaping.progress_shaping, gamma)
            if shaping.progress_shaping
            else None
        )
        env: VecEnv = vec if self.shaped is None else self.shaped
        self.charged = None
        if shaping.reason_penalties:
            env = self.charged = ReasonPenalty(env, shaping.reason_penalties)
        self.counterfactual = None
        if shaping.counterfactual_penalty:
            if deploy_switching is None:
                raise ValueError("shaping.counterfactual_penalty needs deploy_switching")
            env = self.counterfactual = CounterfactualPenalty(
                env,
                shaping.counterfactual_penalty,
                shaping.counterfactual_horizon_s,
                deploy_switching,
            )
        if shaping.clear_time_penalty:
            env = ClearTimePenalty(env, shaping.clear_time_penalty)
        self.constrained = None
        if constraints is not None and constraints.active():
            env = self.constrained = ConstraintCosts(env, constraints)
        self.env = env

    def schedules(self, run: Path | None = None) -> list[BaseCallback]:
        """Callbacks that move the shaping and the charge over the run, as configured (with
        ``run``, the constraints' log in it)."""
        shaping = self.shaping
        out: list[BaseCallback] = []
        if self.shaped is not None and shaping.progress_shaping_final is not None:
            out.append(
                ShapingSchedule(
                    self.shaped, shaping.progress_shaping, shaping.progress_shaping_final
                )
            )
        if self.charged is not None and shaping.reason_penalties_initial_scale != 1.0:
            out.append(PenaltySchedule(self.charged, shaping.reason_penalties_initial_scale))
        if self.counterfactual is not None:
            out.append(CounterfactualLog(self.counterfactual))
        if self.constrained is not None:
            out.append(ConstraintUpdate(self.constrained, run / CONSTRAINTS_LOG if run else None))
        return out

    def state(self) -> dict[str, Any]:
        """What a checkpoint must keep of the learning-only terms (the multipliers)."""
        return {} if self.constrained is None else {"constraints": self.constrained.state()}

    def restore(self, checkpoint: dict[str, Any]) -> None:
        """The learning-only terms as a checkpoint's state left them."""
        if self.constrained is not None and "constraints" in checkpoint:
            self.constrained.restore(checkpoint["constraints"])


def build_model(
    config: TrainConfig | EnvTrainConfig, env: VecEnv, tensorboard_log: Path | None
) -> SwitchPPO:
    """PPO with the configured hyper-parameters (Table II by default)."""
    ppo, policy = config.ppo, config.policy
    arch = list(ppo.net_arch)
    model = SwitchPPO(
        "MlpPolicy",
        env,
        learning_rate=(
            ppo.learning_rate
            if policy.learning_rate_final is None
            else LinearSchedule(ppo.learning_rate, policy.learning_rate_final, 1.0)
        ),
        n_steps=ppo.n_steps,
        batch_size=config.batch_size,
        n_epochs=ppo.n_epochs,
        gamma=ppo.gamma,
        gae_lambda=ppo.gae_lambda,
        clip_range=ppo.clip_range,
        ent_coef=ppo.ent_coef,
        vf_coef=ppo.vf_coef,
        max_grad_norm=ppo.max_grad_norm,
        seed=config.seed,
        device="cpu",
        use_sde=policy.use_sde,
        sde_sample_freq=policy.sde_sample_freq,
        policy_kwargs={
            "net_arch": {"pi": arch, "vf": arch},
            "activation_fn": _activation(ppo.activation, policy.fast_tanh),
            "log_std_init": policy.log_std_init,
        },
        tensorboard_log=str(tensorboard_log) if tensorboard_log else None,
        verbose=0,
        actor_learning_rate=policy.actor_learning_rate,
        actor_frozen_steps=policy.actor_frozen_steps,
        actor_ramp_steps=policy.actor_ramp_steps,
        learn_log_std=policy.learn_log_std,
        log_std_final=policy.log_std_final,
        intervention_imitation=policy.intervention_imitation,
        action_bound_loss=policy.action_bound_loss,
        action_bound_margin=policy.action_bound_margin,
    )
    if policy.initial_action is not None:
        with torch.no_grad():
            head = model.policy.action_net
            assert isinstance(head, torch.nn.Linear)
            head.bias.fill_(policy.initial_action)
    return model


#: A file in a checkpoint saved on an interrupt: such a checkpoint is never pruned (the
#: interrupt's message named it, and a user may evaluate it after resuming).
INTERRUPTED = "interrupted"


def save_checkpoint(
    run: Path,
    model: SwitchPPO,
    env: VecNormalize,
    state: dict[str, Any],
    extra: Callable[[Path], None] | None = None,
) -> Path:
    """A resumable checkpoint ``run/checkpoints/step_N`` (model, normaliser, ``state`` as
    ``state.json`` and what ``extra(folder)`` writes), written into a temporary folder and
    renamed whole; the last two are kept."""
    final = write_snapshot(
        run / "checkpoints" / f"step_{model.num_timesteps:09d}",
        model,
        env,
        {"timesteps": model.num_timesteps, **state},
        extra,
    )
    for old in complete_checkpoints(run)[:-2]:  # keep the last two, and every interrupt's
        if not (old / INTERRUPTED).is_file():
            shutil.rmtree(old, ignore_errors=True)
    return final


def open_run(run: Path, resume: bool) -> dict[str, Any] | None:
    """Check ``run`` for a new run (empty or absent) or for ``--resume`` (an incomplete run
    with a checkpoint), writing nothing; returns the latest checkpoint's state with its
    ``path`` when resuming, else ``None``. A new run is started by :func:`start_run` once
    everything else has been checked, so a run that cannot start leaves ``run`` as it was.

    Raises:
        RunDirectoryError: Saying what is wrong and what to do.
    """
    if resume:
        if not (run / "config.yaml").is_file():
            raise RunDirectoryError(f"--resume: {run} holds no run (no config.yaml)")
        if (run / "metrics.json").is_file():
            raise RunDirectoryError(f"--resume: the run in {run} is already complete")
        checkpoints = complete_checkpoints(run)
        if not checkpoints:
            raise RunDirectoryError(
                f"--resume: {run} has no complete checkpoint yet (it was interrupted before "
                "the first one, e.g. during the warm start); delete it and start again"
            )
        latest = checkpoints[-1]
        state: dict[str, Any] = json.loads((latest / "state.json").read_text(encoding="utf-8"))
        return {**state, "path": latest}
    if run.exists() and not run.is_dir():
        raise RunDirectoryError(f"--out {run} is a file, not a folder; choose another --out")
    if run.exists() and any(run.iterdir()):
        raise RunDirectoryError(
            f"{run} is not empty; choose another --out, or --resume an interrupted run"
        )
    return None


def start_run(run: Path, config_text: str) -> None:
    """Create the new run directory with its resolved configuration and the files it names
    (:func:`~safeswitch.training.config.write_config_with_files`; after :func:`open_run` and
    every other check passed)."""
    run.mkdir(parents=True, exist_ok=True)
    write_config_with_files(run, config_text)


def normalized(venv: Any, config: Any, checkpoint: dict[str, Any] | None) -> VecNormalize:
    """``venv`` behind ``VecNormalize`` as the configuration asks (or as the checkpoint left
    it)."""
    if checkpoint is not None:
        return VecNormalize.load(str(checkpoint["path"] / "vecnormalize.pkl"), venv)
    return VecNormalize(
        venv,
        norm_obs=config.ppo.normalize_observations,
        norm_reward=config.ppo.normalize_rewards,
        gamma=config.ppo.gamma,
    )


def learner_env(env: VecNormalize, config: TrainConfig | EnvTrainConfig) -> VecEnv:
    """What PPO steps: ``env``, with an
    :class:`~safeswitch.training.interventions.InterventionRecorder` around it when the policy
    learns from the interventions (``policy.intervention_imitation``)."""
    if config.policy.intervention_imitation > 0:
        return InterventionRecorder(env)
    return env


def load_model(checkpoint: dict[str, Any], env: VecEnv, run: Path) -> SwitchPPO:
    """The checkpoint's model, learning in ``env``."""
    return SwitchPPO.load(
        checkpoint["path"] / "model.zip", env=env, device="cpu", tensorboard_log=str(run / "tb")
    )


#: The per-rollout logs that ``--resume`` cuts back to the checkpoint it starts from.
RUN_LOGS = ("progress.csv", "validation.csv", CONSTRAINTS_LOG)


def set_aside_after(run: Path, timesteps: int) -> dict[str, int]:
    """Move the rows of the run's logs (:data:`RUN_LOGS`) written after ``timesteps`` — by a run
    killed before it could checkpoint them, a row it was writing when killed included — to
    ``<log>.discarded.csv`` (appended, with a header; written before the log is rewritten
    whole, so a second kill loses nothing), so that a resumed run's logs go on from its
    checkpoint without repeating timesteps. Returns the rows moved per log (logs with none
    left out)."""
    moved: dict[str, int] = {}
    for name in RUN_LOGS:
        path = run / name
        if not path.is_file():
            continue
        with open(path, newline="", encoding="utf-8") as handle:
            reader = csv.reader(handle)
            header = next(reader, None)
            rows = [row for row in reader if row]
        if header is None or "timesteps" not in header:
            continue
        kept: list[list[str]] = []
        later: list[list[str]] = []
        for row in rows:
            (kept if _logged_by(row, header, timesteps) else later).append(row)
        if not later:
            continue
        aside = run / f"{path.stem}.discarded.csv"
        new_file = not aside.exists()
        with open(aside, "a", newline="", encoding="utf-8") as handle:
            csv.writer(handle, lineterminator="\r\n").writerows(
                [header, *later] if new_file else later
            )
        text = io.StringIO()
        csv.writer(text, lineterminator="\r\n").writerows([header, *kept])
        write_atomic(path, text.getvalue())
        moved[name] = len(later)
    return moved


def _logged_by(row: list[str], header: list[str], timesteps: int) -> bool:
    """Whether a log row is whole and from ``timesteps`` or before."""
    try:
        return len(row) == len(header) and float(row[header.index("timesteps")]) <= timesteps
    except ValueError:
        return False


@contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """Within the block a SIGTERM (a scheduler's preemption, ``kill``, Ray stopping a task)
    raises ``KeyboardInterrupt`` as Ctrl-C does, so training checkpoints before it stops;
    outside the main thread, where Python cannot install a handler, nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def learn(
    model: SwitchPPO,
    run: Path,
    timesteps: int,
    monitor: Any,
    save: Any,
    resume: bool,
    progress_bar: bool,
    extra: list[BaseCallback] | None = None,
) -> None:
    """PPO up to ``timesteps``; on Ctrl-C or SIGTERM a checkpoint first (``save()``), then
    the interrupt goes on. ``progress_bar``: SB3's bar on a terminal, a plain line every 15 s
    otherwise (a log never stays silent for minutes). ``extra``: further callbacks."""
    remaining = timesteps - model.num_timesteps
    rollout = model.n_steps * model.n_envs
    if remaining > 0 and remaining % rollout:
        total = model.num_timesteps + -(-remaining // rollout) * rollout
        print(
            f"note: PPO trains in whole rollouts of n_envs × n_steps = {model.n_envs} × "
            f"{model.n_steps} = {rollout:,} steps: {timesteps:,} timesteps become {total:,}",
            file=sys.stderr,
        )
    terminal = sys.stderr.isatty()
    callbacks: list[BaseCallback] = [monitor, *(extra or [])]
    if progress_bar and not terminal:
        callbacks.append(ProgressLines(remaining, f"train {run.name}"))
    try:
        with terminate_as_interrupt():
            if remaining > 0:
                model.learn(
                    total_timesteps=remaining,
                    callback=CallbackList(callbacks),
                    progress_bar=progress_bar and terminal,
                    reset_num_timesteps=not resume,
                    tb_log_name="ppo",
                )
    except KeyboardInterrupt:
        monitor.totals["wall_time_s"] = monitor.wall_time_s
        path = save()
        (path / INTERRUPTED).write_text(
            f"saved on an interrupt at {model.num_timesteps} timesteps; kept\n", encoding="utf-8"
        )
        print(
            f"\ninterrupted at {model.num_timesteps:,} timesteps; checkpoint {path}; "
            f"continue with: safeswitch train --resume --out {run}",
            file=sys.stderr,
        )
        raise


def evaluate_trained(
    policy: TrainedPolicy, config: TrainConfig, episodes: int, seed: int
) -> dict[str, Any]:
    """Deterministic evaluation on ``episodes`` random scenarios drawn with ``seed`` under the
    logic the policy is deployed under, with the oracle's efficiency (``safeswitch
    evaluate``'s fields)."""
    task = build_task(None, config.deployed_env, traffic=config.traffic_settings)
    scenarios = task.scenario_set(seed, episodes)
    result, plan = run_controller(task, policy.as_policy(), scenarios, trace=False)
    return summary_against_oracle(result, plan, task.config.episode.horizon_s)


class LeftTurnPlant(Plant):
    """The left turn as the one pipeline's plant (:mod:`safeswitch.training.pipeline`): the
    batched VecEnv, its shaping and constraints, the planner's warm start, validation on
    scenario sets with the oracle, and the evaluation against the oracle."""

    def __init__(self, config: TrainConfig) -> None:
        self.config = config

    def dump(self) -> str:
        return dump_config(self.config)

    def vec_env(self) -> LeftTurnVecEnv:
        c = self.config
        return LeftTurnVecEnv(
            c.n_envs, config=c.train_env, seed=c.seed, traffic=c.traffic_settings,
            stagger=c.stagger_starts,
        )  # fmt: skip

    def learning(self, vec: VecEnv) -> LearningEnv:
        c = self.config
        assert isinstance(vec, LeftTurnVecEnv)
        return LearningEnv(vec, c.shaping, c.ppo.gamma, c.constraints, c.deploy_switching)

    def monitor(
        self, run: Path, save: Callable[[Any], object], totals: dict[str, float] | None
    ) -> TrainingMonitor:
        return TrainingMonitor(run / "progress.csv", self.config.checkpoint_every, save, totals)

    def vec_state(self, vec: VecEnv) -> dict[str, Any]:
        assert isinstance(vec, LeftTurnVecEnv)
        return {"episode_counters": vec.episode_counters.tolist()}

    def restore_vec(self, vec: VecEnv, checkpoint: dict[str, Any]) -> None:
        assert isinstance(vec, LeftTurnVecEnv)
        vec.episode_counters = np.asarray(checkpoint["episode_counters"], dtype=np.int64)

    def check(self, vec: VecEnv) -> None:
        start = self.config.warm_start.policy
        if start is not None:
            shape = tuple(vec.observation_space.shape or ())
            extend = self.config.warm_start.extend_inputs
            check_start_policy(start, tuple(self.config.ppo.net_arch), shape, extend)

    def warm_start(self, model: SwitchPPO, env: VecNormalize, run: Path) -> bool:
        ws = self.config.warm_start
        if ws.policy is not None:
            record = start_from_policy(model, env, ws.policy, ws.freeze_obs_stats, ws.extend_inputs)
        elif ws.episodes > 0:
            record = warm_start(model, env, self.config)
        else:
            return False
        write_atomic(run / "warm_start.json", json.dumps(record, indent=2))
        return True

    def validator(self, run: Path) -> Validator | None:
        return Validator(self.config, run) if self.config.validation.every else None

    def refine(self, run: Path, train: Callable[..., dict[str, Any]]) -> dict[str, Any] | None:
        from safeswitch.training.refine import refine_run

        return refine_run(run, self.config, train)

    def evaluate(self, run: Path) -> dict[str, Any]:
        c = self.config
        return evaluate_trained(load_policy(run), c, c.eval_episodes, c.eval_seed)

    def header(self, run: Path) -> dict[str, Any]:
        c = self.config
        record = run / "warm_start.json"
        return {
            "switching": c.env.switching,
            "deployed_switching": c.deployed_env.switching,
            "adas_penalty": c.env.adas_penalty,
            "warm_start": (
                json.loads(record.read_text(encoding="utf-8")) if record.is_file() else None
            ),
        }

    def training(self, totals: dict[str, float]) -> dict[str, Any]:
        t = totals
        return {
            "collisions": int(t["collisions"]),
            "collision_episodes": int(t["collision_episodes"]),
            "lost_control_episodes": int(t["lost_control"]),
            "failures": int(t["failures"]),
            "safety_activation_steps": int(t["safety_steps"]),
            "safety_activation_episodes": int(t["safety_episodes"]),
            "episodes": int(t["episodes"]),
        }
