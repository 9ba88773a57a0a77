"""One training pipeline for every plant: :func:`train`.

The left turn (:class:`~safeswitch.training.config.TrainConfig`) and any Gymnasium plant under
a switching logic (:class:`~safeswitch.training.config.EnvTrainConfig`) train through the same
steps, in the same run directory (see :mod:`safeswitch.training.run`):

1. the run directory checked (a new run, or ``--resume`` from the latest checkpoint), the
   environments built — a logic or a constrained cost that does not fit the plant is refused
   before anything is written;
2. the learning-only wrappers: constraints with PI-Lagrangian multipliers on the switch's and
   the plant's named costs (and, on the left turn, its shaping terms), then ``VecNormalize``;
3. PPO (built, or loaded from the checkpoint), an optional warm start (the left turn's planner),
   validation with best-policy selection (``validation.every``), progress rows, TensorBoard,
   checkpoints every ``checkpoint_every`` steps and on Ctrl-C;
4. the final model, the run's policy selected, a plant's stage after PPO (the left turn's
   search-guided refinement, :mod:`safeswitch.training.refine`, when ``refine:`` asks), the
   final evaluation on unseen scenarios or seeds, and ``metrics.json`` last.

What differs between plants is a :class:`Plant`: how its environments are built, what its
monitor counts (a driving plant's collisions are its failures; any plant's failures are what it
declares), how a policy is validated and evaluated. The pipeline reads only generic signals
from a plant's steps: ``info["safety_active"]`` and ``info["cost"]`` (the switch's
intervention), ``info["costs"]`` (its named costs) and the declared failure.
"""

from __future__ import annotations

import functools
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import torch
from stable_baselines3.common.callbacks import BaseCallback

from safeswitch.io import write_json, write_policy_files
from safeswitch.training.config import EnvTrainConfig, TrainConfig, load_any_config
from safeswitch.training.plant import Plant
from safeswitch.training.run import (
    build_model,
    learn,
    learner_env,
    load_model,
    normalized,
    open_run,
    save_checkpoint,
    set_aside_after,
    start_run,
)
from safeswitch.training.validation import best_so_far, select_best


def plant_for(
    config: TrainConfig | EnvTrainConfig, make_env: Callable[[], gym.Env[Any, Any]] | None = None
) -> Plant:
    """The plant a configuration trains on; ``make_env`` builds one environment of a
    Gymnasium plant (default: ``config.env_id`` under ``config.switching``)."""
    if isinstance(config, TrainConfig):
        if make_env is not None:
            raise ValueError(
                "make_env builds a Gymnasium plant's environments; the left turn builds its own "
                "batched environment from the configuration"
            )
        from safeswitch.training.run import LeftTurnPlant

        return LeftTurnPlant(config)
    from safeswitch.training.generic import GymPlant

    return GymPlant(config, make_env)


def train(
    config: TrainConfig | EnvTrainConfig,
    out: str | Path,
    resume: bool = False,
    progress_bar: bool = True,
    callbacks: list[BaseCallback] | None = None,
    make_env: Callable[[], gym.Env[Any, Any]] | None = None,
) -> dict[str, Any]:
    """Train (or resume) a run of any plant; returns the contents of ``metrics.json``.

    Args:
        config: The configuration (on ``resume``, the run's own ``config.yaml`` is used).
        out: The run directory.
        resume: Continue the interrupted run in ``out`` from its last checkpoint.
        progress_bar: SB3's bar on a terminal, a line every 15 s otherwise.
        callbacks: Further SB3 callbacks (e.g. a benchmark's own recording).
        make_env: Builds one environment of a Gymnasium plant (see :func:`plant_for`).

    Raises:
        RunDirectoryError: ``out`` holds another run and ``resume`` is off, or ``resume`` is on
            and there is nothing to resume.
        KeyboardInterrupt: after saving a checkpoint, if interrupted.
    """
    run = Path(out)
    checkpoint = open_run(run, resume)
    if checkpoint is not None:
        config = load_any_config(run / "config.yaml")
    plant = plant_for(config, make_env)
    torch.set_num_threads(config.torch_threads)
    # The environment first: it builds the switching logic for the plant, so a logic that does
    # not fit it is refused before the run directory is written.
    vec = plant.vec_env()
    plant.check(vec)
    if checkpoint is None:
        start_run(run, plant.dump())
    else:
        plant.restore_vec(vec, checkpoint)
        for name, rows in set_aside_after(run, int(checkpoint["timesteps"])).items():
            print(
                f"note: {rows} row(s) of {name} came after the checkpoint resumed from "
                f"({int(checkpoint['timesteps']):,} timesteps); moved to "
                f"{Path(name).stem}.discarded.csv",
                file=sys.stderr,
            )
        at = best_so_far(run)["best_timesteps"] or 0
        if at > int(checkpoint["timesteps"]):
            print(
                f"note: the best validated policy so far (best/, {at:,} timesteps) is from "
                "after that checkpoint; it stays the one later validations must beat",
                file=sys.stderr,
            )
    learning = plant.learning(vec)
    if checkpoint is not None:
        learning.restore(checkpoint)
    env = normalized(learning.env, config, checkpoint)
    if checkpoint is not None:
        model = load_model(checkpoint, learner_env(env, config), run)
    else:
        model = build_model(config, learner_env(env, config), run / "tb")

    validator = plant.validator(run)
    if validator is not None and checkpoint is not None:
        validator.resume(checkpoint)

    def save(monitor: Any) -> Path:
        state = {"totals": monitor.totals, **plant.vec_state(vec), **learning.state()}
        extra = validator.save_average if validator is not None else None
        return save_checkpoint(run, model, env, state, extra)

    monitor = plant.monitor(run, save, checkpoint["totals"] if checkpoint else None)
    if checkpoint is None and plant.warm_start(model, env, run):
        save(monitor)  # --resume starts after the warm start
    extra: list[BaseCallback] = [*(callbacks or [])]
    extra += [validator] if validator is not None else []
    extra += learning.schedules(run)
    learn(
        model, run, config.timesteps, monitor, lambda: save(monitor), resume, progress_bar,
        extra=extra,
    )  # fmt: skip
    wall = monitor.wall_time_s
    write_policy_files(run, model, env)
    selected = None
    if validator is not None and validator.state["best_timesteps"] is not None:
        select_best(run)
        selected = {"validation_seed": config.validation.seed, **validator.state}
    refined = plant.refine(run, functools.partial(train, progress_bar=progress_bar))
    started = time.perf_counter()
    evaluation = plant.evaluate(run) if config.eval_episodes else {}
    metrics: dict[str, Any] = {
        **plant.header(run),
        "timesteps": int(model.num_timesteps),
        "wall_time_s": round(wall, 2),
        "steps_per_s": round(model.num_timesteps / max(wall, 1e-9), 1),
        "n_envs": config.n_envs,
        "torch_threads": config.torch_threads,
        "seed": config.seed,
        "selected": selected,
        **({"refined": refined} if refined is not None else {}),
        **learning.state(),
        "training": plant.training(monitor.totals),
        "evaluation": {
            "seed": config.eval_seed,
            **evaluation,
            "wall_time_s": round(time.perf_counter() - started, 2),
        },
    }
    write_json(run / "metrics.json", metrics)
    return metrics
