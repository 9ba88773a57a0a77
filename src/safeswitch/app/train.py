"""``safeswitch train``: a training run, then its training curves (the paper's Fig. 5)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from safeswitch.report.training import training_curves
from safeswitch.training import train
from safeswitch.training.config import EnvTrainConfig, TrainConfig, load_any_config


def train_and_plot(
    config: TrainConfig | EnvTrainConfig,
    out: str | Path,
    resume: bool = False,
    progress_bar: bool = True,
) -> dict[str, Any]:
    """:func:`~safeswitch.training.pipeline.train` — the left turn or any other plant —, then
    ``training_curves.png`` in the run directory; returns the run's metrics."""
    metrics = train(config, out, resume=resume, progress_bar=progress_bar)
    try:
        plot_run(Path(out))
    except Exception as exc:  # a figure must never cost a finished run
        print(f"warning: training_curves.png not written: {exc}", file=sys.stderr)
    return metrics


def plot_run(run: Path) -> Path:
    """``training_curves.png`` of the run directory ``run`` from its ``progress.csv``, titled
    with its plant, logic and penalty as its ``config.yaml`` has them. Returns the figure's
    path."""
    config = load_any_config(run / "config.yaml")
    if isinstance(config, EnvTrainConfig):
        logic = config.switching or "the environment's default"
        penalty = "the default" if config.penalty is None else f"{config.penalty:g}"
        title = f"{config.env_id}: switching {logic}, penalty {penalty}"
    else:
        env = config.env
        title = f"switching={env.switching}, R_ADAS {'on' if env.adas_penalty else 'off'}"
    out = run / "training_curves.png"
    training_curves(run / "progress.csv", out, title=title, selected=kept_step(run))
    return out


def kept_step(run: Path) -> int | None:
    """The time step of the PPO policy the run kept after validating (``metrics.json``), or
    ``None``: no validation chose one, or a later stage (the search-guided refinement)
    replaced it."""
    path = run / "metrics.json"
    if not path.is_file():
        return None
    metrics = json.loads(path.read_text(encoding="utf-8"))
    selected, refined = metrics.get("selected") or {}, metrics.get("refined") or {}
    if refined.get("selected_iteration"):
        return None
    step = selected.get("best_timesteps")
    return None if step is None else int(step)
