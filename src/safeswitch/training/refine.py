"""Search-guided refinement of a trained left-turn policy, alone or in traffic: the pipeline's
last stage (``refine:``; ours, off by default).

PPO under constraints leaves time on the table: a careful driver that knows each scene clears
sooner than the policy in most scenes (``benchmarks/certified_ceiling.py --careful``). The
scene is deterministic given its start (the north car holds its speed; in traffic the other
vehicles follow their rules), so the policy's own actions replayed open loop drive exactly its
episode, and a trajectory search can start from them. Each iteration (the idea is expert
iteration / guided policy search with a sampling optimiser):

1. the policy drives ``refine.scenes`` fresh training scenarios (the run's seed, environment
   ids no training environment uses) under the run's logic (with ``refine.env``'s stricter
   rules where set: labels clean under a stricter filter or comfort limit);
2. where it fails — never clears, or breaks a comfort limit, passes the speed limit or needs
   the safety action on some tick — the cross-entropy search
   (:func:`~safeswitch.evaluation.search.search_sequences`) starts from its actions; where it
   clears cleanly (or, in a scene the policy never clears, with at most
   ``refine.uncleared_dirty_ticks`` dirty ticks), its actions become the labels;
3. on ``refine.speed_scenes`` of the scenes it drives cleanly, a cheaper search looks for a
   clean clear at least ``refine.min_gain_s`` sooner; found, its actions become the labels;
4. the actor's mean is fitted to the labels at the observations they drive through — the
   policy's own actions everywhere else, so it keeps what it does well — the improved scenes
   counted ``refine.weight`` times;
5. the policy is validated on the run's validation scenarios.

The run keeps the iteration (0: PPO's own policy) with no collision, then the least summed
excess of the comfort, speeding and safety constraints over their validation budgets (the
recipe's own ``constraints``, ranked as ``validation.criterion: constraints_then_return``
ranks them), then the highest efficiency against the oracle (a scenario never cleared counts
0). A label is clean, but a policy fitted to labels that drive along the filter's edge touches
the filter near it (in our runs in 5–9 % of the episodes, a median of 2–3 ticks each:
docs/learning_experiments.md); ``refine.env`` searches under a stricter filter (or comfort
limits) for a margin from that edge.

``refine.finetune`` adds a constrained PPO phase: the search's fastest iteration with no
collision (budgets aside) is fine-tuned by PPO under the run's constraints, validation and
selection, a run of its own in ``run/refine/finetune/``; the run keeps its selected policy if
the criterion above ranks it at least as high as PPO's own. The safety constraint's multiplier
pulls the filter back toward the budget the fitted policy alone misses (within it on one of
three seeds of the ``certified`` recipe).

The search needs a logic under which no action sequence can collide: ``certified``.
"""

from __future__ import annotations

import copy
import csv
import io
import json
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from safeswitch.evaluation.rollout import rollout
from safeswitch.evaluation.search import (
    SEGMENT_S,
    family_of_drivers,
    policy_actions,
    search_sequences,
)
from safeswitch.io import (
    complete_checkpoints,
    copy_policy_files,
    write_atomic,
    write_policy_files,
)
from safeswitch.leftturn.config import EpisodeConfig
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.spaces import throttle_driver
from safeswitch.leftturn.task import LeftTurnTask, TaskState
from safeswitch.training.config import RefineConfig, TrainConfig
from safeswitch.training.policies import TrainedPolicy, load_policy
from safeswitch.training.validation import (
    SAFETY_CONSTRAINTS,
    VALIDATION_FIELDS,
    ValidationSet,
    constraint_excess,
    constraint_measures,
)
from safeswitch.training.warm_start import action_error, actor_mean, fit_actor

#: Environment ids of iteration ``i``'s scenes start at ``i`` times this (training uses the
#: first ``n_envs``).
REFINE_ENV_OFFSET = 5_000_000

#: The validation's columns of ``refine.csv`` (``validation.csv``'s summary fields).
VALIDATED = tuple(
    f for f in VALIDATION_FIELDS if f not in ("timesteps", "stress_collisions", "best")
)

#: Columns of ``refine.csv``: the iteration's stage (``ppo``, ``search``, ``finetune``) and work,
#: its validation, the fine-tune phase's steps and the step its selection chose, whether the
#: run keeps it.
REFINE_FIELDS = (
    "iteration", "stage", "failing", "fixed", "sped_up", "samples", "mse_before", "mse",
    "wall_time_s", *VALIDATED, "timesteps", "selected_timesteps", "selected",
)  # fmt: skip

#: What ``metrics.json`` keeps of the fine-tune phase (``refine.finetune``).
FINETUNED = ("timesteps", "selected_timesteps", "finetune_wall_time_s")


def refine_iteration(
    task: LeftTurnTask, policy: TrainedPolicy, config: RefineConfig, seed: int, iteration: int
) -> dict[str, Any]:
    """One iteration of the module docstring's steps 1–4 on ``policy`` (its actor changed in
    place), on the scenes of ``seed`` and ``iteration``; returns what it did."""
    episode = task.config.episode
    n = config.scenes
    ids = REFINE_ENV_OFFSET * iteration + np.arange(n)
    scenes = task.draw_scenarios(seed, ids, np.zeros(n, dtype=np.int64))
    to_scene = throttle_driver(task.config.controllers, "the refinement's structured drivers")
    actions, clear, dirty, first_dirty = policy_actions(task, scenes, policy.as_policy())
    drivers = to_scene(_drivers(episode))
    failing = np.flatnonzero(np.isnan(clear) | (dirty > 0))
    frozen = None
    if config.lock_s is not None:  # its own decisions up to lock_s before its first dirty tick
        lock = round(config.lock_s / episode.dt)
        frozen = np.maximum(0, (first_dirty[failing] - lock) // episode.decision_interval)
    f_clear, f_dirty, f_seqs = search_sequences(
        task, scenes.take(failing), actions[failing], population=config.population,
        rounds=config.rounds, seed=seed + iteration, seeds=drivers, knot=config.knot,
        margin=config.margin, frozen=frozen,
    )  # fmt: skip
    allowed = np.where(np.isnan(clear[failing]), config.uncleared_dirty_ticks, 0)
    fixed = ~np.isnan(f_clear) & (f_dirty <= allowed)
    labels, weight = actions.copy(), np.ones(n, dtype=np.int64)
    labels[failing[fixed]] = f_seqs[fixed]
    weight[failing[fixed]] = config.weight
    clean = np.setdiff1d(np.arange(n), failing)[: config.speed_scenes]
    sped_up = 0
    if clean.size:
        s_clear, s_dirty, s_seqs = search_sequences(
            task, scenes.take(clean), actions[clean], population=config.speed_population,
            rounds=config.speed_rounds, seed=seed + iteration, seeds=drivers, knot=config.knot,
            margin=config.margin,
        )  # fmt: skip
        faster = ~np.isnan(s_clear) & (s_dirty == 0) & (s_clear < clear[clean] - config.min_gain_s)
        labels[clean[faster]] = s_seqs[faster]
        weight[clean[faster]] = config.weight
        sped_up = int(faster.sum())
    obs, alive = observed(task, scenes, labels)
    take = np.repeat(np.arange(n), weight)
    x = policy.normalise(obs[take][alive[take]]).astype(np.float32)
    y = labels[take][alive[take]].astype(np.float32)
    before = _label_error(policy, x, y)
    fit_actor(policy.model, x, y, config.epochs, config.learning_rate, clipped=True)
    return {
        "failing": int(failing.size),
        "fixed": int(fixed.sum()),
        "sped_up": sped_up,
        "samples": len(x),
        "mse_before": round(before, 6),
        "mse": round(_label_error(policy, x, y), 6),
    }


def _label_error(policy: TrainedPolicy, x: NDArray[np.float32], y: NDArray[np.float32]) -> float:
    """The mean squared error of the actions the policy takes (its mean, clipped to [-1, 1])
    to the labels ``y`` at normalised observations ``x``."""
    if not len(y):
        return 0.0
    with torch.no_grad():
        mean = actor_mean(policy.model, torch.as_tensor(x))
        error = action_error(mean, torch.as_tensor(y).reshape(-1, 1), clipped=True)
    return float(torch.mean(error**2))


def observed(
    task: LeftTurnTask, scenarios: Scenarios, labels: NDArray[np.float64]
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """The observation at each decision of ``labels`` [n, decisions] driven open loop
    [n, decisions, obs], and which decisions fall before the episode's end [n, decisions]."""
    episode = task.config.episode
    interval, decisions = episode.decision_interval, labels.shape[1]
    size = int(np.prod(task.observation_bounds[0].shape))
    obs = np.zeros((len(labels), decisions, size), np.float32)

    def drive(o: NDArray[np.float32], state: TaskState, tick: int) -> NDArray[np.float64]:
        obs[:, tick // interval] = o.reshape(len(labels), size)
        return labels[:, tick // interval]

    result = rollout(task, scenarios, drive)
    alive = np.arange(decisions)[None, :] * interval < result.ticks[:, None]
    return obs, alive


def _drivers(episode: EpisodeConfig) -> NDArray[np.float64]:
    """The structured drivers at one action per decision of ``episode``: each decision takes
    the driver's action of the half-second segment it starts in (any decision interval)."""
    segment_ticks = max(1, round(SEGMENT_S / episode.dt))
    segments = -(-episode.horizon_ticks // segment_ticks)
    decisions = episode.horizon_ticks // episode.decision_interval
    columns = np.arange(decisions) * episode.decision_interval // segment_ticks
    return family_of_drivers(segments)[:, columns]


def search_task(config: TrainConfig) -> LeftTurnTask:
    """The task the stage drives and searches: the training environment with ``refine.env``
    (stricter rules for the search) merged in, in the run's traffic if it has any."""
    return build_task(None, config.refine_env, traffic=config.traffic_settings)


def selection_key(
    config: TrainConfig, summary: dict[str, Any], budgets: bool = True
) -> tuple[float, ...]:
    """What the stage maximises over its iterations: no collision, then the least summed
    excess of the comfort, speeding and safety constraints over their selection budgets (as
    ``constraints_then_return`` ranks them; none without constraints or ``budgets`` off),
    then the efficiency against the oracle."""
    excess = constraint_excess(config, summary, config.horizon_s) if budgets else {}
    efficiency = summary.get("mean_efficiency")
    return (
        -float(summary["collisions"]),
        -sum(excess.get(name, 0.0) for name in SAFETY_CONSTRAINTS),
        float(efficiency) if efficiency is not None else float("-inf"),
    )


#: The pipeline's :func:`~safeswitch.training.pipeline.train` (passed in: the pipeline calls this
#: stage).
Trainer = Callable[..., dict[str, Any]]


def refine_run(
    run: Path, config: TrainConfig, train: Trainer | None = None
) -> dict[str, Any] | None:
    """The stage on a finished run's policy (``run/model.zip``): ``refine.iterations``
    iterations, each validated, then (``refine.finetune``) the constrained PPO phase on the
    fastest; the policy selected becomes the run's (PPO's own moves to ``run/ppo/``);
    ``refine.csv`` records every iteration and the phase. Returns the record for
    ``metrics.json`` (``None``: no refinement configured). ``train``: the pipeline's, which
    the fine-tune phase needs. The run's policy is replaced only
    once all is done, so an interrupted stage leaves PPO's policy in place (``--resume`` runs
    the stage again, and continues an interrupted fine-tune phase from its checkpoint)."""
    r = config.refine
    if not r.iterations:
        return None
    if r.finetune is not None and train is None:
        raise ValueError("refine.finetune trains a phase: refine_run needs the pipeline's train")
    started = time.perf_counter()
    policy = load_policy(run)
    task = search_task(config)
    validation = ValidationSet(config)
    horizon = validation.task.config.episode.horizon_s
    # With a fine-tune phase the search's iterations compete on efficiency alone: the phase's
    # constraints, not the choice of its start, bring the budgets back.
    budgets = r.finetune is None
    rows: list[dict[str, Any]] = []
    best, best_state = 0, None  # the best iteration so far and its weights (None: PPO's)

    def validate(row: dict[str, Any], validated: TrainedPolicy) -> None:
        summary = validation.summary(validated)
        row.update({k: summary.get(k) for k in VALIDATED if k in summary})
        row["clear_time_s"] = constraint_measures(summary, horizon)["clear_time"]
        row["final_key"] = selection_key(config, summary)
        row["key"] = row["final_key"] if budgets else selection_key(config, summary, budgets)
        row["wall_time_s"] = round(time.perf_counter() - started, 1)
        rows.append(row)

    validate({"iteration": 0, "stage": "ppo"}, policy)
    for it in range(1, r.iterations + 1):
        done = refine_iteration(task, policy, r, config.seed, it)
        validate({"iteration": it, "stage": "search", **done}, policy)
        if rows[-1]["key"] > rows[best]["key"]:
            best, best_state = it, copy.deepcopy(policy.model.policy.state_dict())
    if best_state is not None:
        policy.model.policy.load_state_dict(best_state)
    kept, tuned = best, None
    if r.finetune is not None and best_state is not None:
        searched = run / "refine" / "searched"
        searched.mkdir(parents=True, exist_ok=True)
        write_policy_files(searched, policy.model, policy.normalizer)
        assert train is not None
        tuned, trained = finetune(run, config, searched, train)
        validate({"iteration": r.iterations + 1, "stage": "finetune", **trained}, tuned)
        kept = len(rows) - 1 if rows[-1]["final_key"] >= rows[0]["final_key"] else 0
    for index, row in enumerate(rows):
        row["selected"] = int(index == kept)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=REFINE_FIELDS, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    if kept:
        ppo = run / "ppo"
        ppo.mkdir(exist_ok=True)
        copy_policy_files(run, ppo)
        if tuned is None:
            write_policy_files(run, policy.model, policy.normalizer)
        else:  # the fine-tune phase's files as it wrote them, byte for byte
            copy_policy_files(tuned.path, run)
    write_atomic(run / "refine.csv", buffer.getvalue())
    stage = rows[kept]["stage"]
    return {
        "iterations": r.iterations,
        "selected_iteration": best,
        "kept": stage,
        **({"finetune": {k: rows[-1][k] for k in FINETUNED}} if tuned is not None else {}),
        "wall_time_s": round(time.perf_counter() - started, 1),
        "validation": {k: rows[kept].get(k) for k in VALIDATED},
    }


def finetune(
    run: Path, config: TrainConfig, start: Path, train: Trainer
) -> tuple[TrainedPolicy, dict[str, Any]]:
    """The fine-tune phase (``refine.finetune``) from the policy in ``start``, a run of its own
    in ``run/refine/finetune/`` trained by ``train`` (continued from its checkpoint if an
    earlier one was interrupted); returns its selected policy and what it did."""
    out = run / "refine" / "finetune"
    if (out / "metrics.json").is_file():  # done before the stage was interrupted
        metrics = json.loads((out / "metrics.json").read_text(encoding="utf-8"))
        return load_policy(out), _finetuned(metrics)
    resume = bool(complete_checkpoints(out))
    if out.is_dir() and not resume:
        shutil.rmtree(out)  # begun and never checkpointed: nothing to continue
    try:
        metrics = train(config.finetune_config(str(start)), out, resume=resume)
    except KeyboardInterrupt:
        print(
            f"the refinement's fine-tune phase was interrupted; continue the run with: "
            f"safeswitch train --resume --out {run}",
            file=sys.stderr,
        )
        raise
    return load_policy(out), _finetuned(metrics)


def _finetuned(metrics: dict[str, Any]) -> dict[str, Any]:
    """What the stage keeps of the fine-tune phase's ``metrics.json``."""
    selected = metrics["selected"] or {}  # none: its last policy
    return {
        "timesteps": metrics["timesteps"],
        "selected_timesteps": selected.get("best_timesteps") or metrics["timesteps"],
        "finetune_wall_time_s": metrics["wall_time_s"],
    }
