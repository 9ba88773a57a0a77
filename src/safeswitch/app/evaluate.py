"""``safeswitch evaluate``: any controller × any switching logic × a set of scenarios."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from safeswitch.evaluation.evaluate import (
    BASELINES,
    baseline_setup,
    episodes_csv,
    run_controller,
    scenario_set,
    summary_against_oracle,
)
from safeswitch.evaluation.rollout import Policy
from safeswitch.io import write_atomic, write_json
from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.training.config import load_config
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
        env_config = load_config(trained.path / "config.yaml").env
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
) -> dict[str, Any]:
    """Run the evaluation, write ``episodes.csv`` and ``summary.json`` into ``out``, and return
    the summary (see :mod:`safeswitch.evaluation.metrics` for its fields; ``mean_efficiency``
    is the mean over scenarios of the oracle's time to clear divided by the controller's)."""
    env_config, policy = controller_setup(controller, model, switching)
    task = LeftTurnTask(env_config)
    batch, names = scenario_set(task, scenarios, episodes, seed)
    result, plan = run_controller(task, policy, batch)
    summary = {
        "controller": controller,
        "model": str(model) if model else None,
        "switching": env_config.switching if policy is not None else None,
        "scenarios": scenarios,
        "seed": seed,
        **summary_against_oracle(result, plan, env_config.episode.horizon_s),
    }
    if out is not None:
        folder = Path(out)
        folder.mkdir(parents=True, exist_ok=True)
        write_atomic(
            folder / "episodes.csv", episodes_csv(names, batch, result, plan.time_to_clear)
        )
        write_json(folder / "summary.json", summary)
    return summary
