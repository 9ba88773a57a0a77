"""``safeswitch evaluate``: any controller × any switching logic × a set of scenarios."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from safeswitch.evaluation.evaluate import (
    BASELINES,
    EpisodeCSV,
    baseline_setup,
    run_controller,
    scenario_chunks,
)
from safeswitch.evaluation.metrics import SummaryAccumulator
from safeswitch.evaluation.rollout import Policy
from safeswitch.io import prepare_output_dir, write_json
from safeswitch.leftturn.config import SCENARIO_NAMES, LeftTurnConfig
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.progress import Progress
from safeswitch.training.config import TrainConfig
from safeswitch.training.policies import load_policy

#: Every ``--controller``.
CONTROLLERS: tuple[str, ...] = ("learned", *BASELINES)


def controller_setup(
    controller: str, model: str | None, switching: str | None
) -> tuple[LeftTurnConfig, Policy | None]:
    """The task configuration and policy of a controller (``None`` for the oracle, which
    plans instead of acting): a trained policy (``learned``, from ``model``) with the
    environment it was trained in, or a baseline (see
    :func:`~safeswitch.evaluation.evaluate.baseline_setup`); ``switching`` overrides the
    logic."""
    if controller == "learned":
        if model is None:
            raise ValueError("--controller learned needs --model (a run directory or 'shipped')")
        trained = load_policy(model)
        if not isinstance(trained.config, TrainConfig):
            raise ValueError(
                f"the policy in {trained.path} was trained on {trained.config.env_id}; "
                f"evaluate it with --env {trained.config.env_id}"
            )
        env_config = trained.config.env
        if switching is not None:
            env_config = replace(env_config, switching=switching)
        return replace(env_config, scenario=None), trained.as_policy()
    if controller not in BASELINES:
        raise ValueError(
            f"--controller must be one of {', '.join(CONTROLLERS)}, got {controller!r}"
        )
    if model is not None:
        raise ValueError(
            f"--model {model} is a trained policy, but --controller {controller} does not use "
            "one; drop --model or use --controller learned"
        )
    return baseline_setup(controller, switching)


def evaluate(
    controller: str,
    model: str | None,
    scenarios: str,
    episodes: int,
    seed: int,
    switching: str | None,
    out: str | Path | None,
    overwrite: bool = False,
    progress: bool = False,
) -> dict[str, Any]:
    """Run the evaluation and return its summary (see :mod:`safeswitch.evaluation.metrics` for
    the fields); with ``out``, write ``episodes.csv`` (row by row, as chunks finish) and
    ``summary.json`` there. Episodes run in chunks of
    :data:`~safeswitch.evaluation.evaluate.CHUNK`, so memory stays bounded whatever
    ``episodes`` is.

    Raises:
        OutputDirectoryError: ``out`` is a file, or holds files and ``overwrite`` is off.
    """
    env_config, policy = controller_setup(controller, model, switching)
    task = LeftTurnTask(env_config)
    chunks = scenario_chunks(task, scenarios, episodes, seed)  # validates the arguments
    folder = prepare_output_dir(out, overwrite) if out is not None else None
    total = len(SCENARIO_NAMES) if scenarios == "paper" else episodes
    accumulator = SummaryAccumulator()
    writer = EpisodeCSV(folder / "episodes.csv") if folder is not None else None
    bar = Progress(total, f"evaluate {controller}", enabled=progress)
    try:
        for names, batch in chunks:
            result, plan = run_controller(task, policy, batch, trace=False)
            accumulator.add(result, plan.time_to_clear, env_config.episode.horizon_s)
            if writer is not None:
                writer.write(names, batch, result, plan.time_to_clear)
            bar.update(len(names))
    except BaseException:
        if writer is not None:
            writer.abandon()
        raise
    finally:
        bar.close()
    if writer is not None:
        writer.close()
    summary = {
        "controller": controller,
        "model": str(model) if model else None,
        "switching": env_config.switching if policy is not None else None,
        "scenarios": scenarios,
        "seed": seed,
        **accumulator.summary(),
    }
    if folder is not None:
        write_json(folder / "summary.json", summary)
    return summary
