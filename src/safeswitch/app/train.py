"""``safeswitch train``: a training run, then its training curves (the paper's Fig. 5)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from safeswitch.report.training import training_curves
from safeswitch.training import train
from safeswitch.training.config import TrainConfig, load_config


def train_and_plot(
    config: TrainConfig, out: str | Path, resume: bool = False, progress_bar: bool = True
) -> dict[str, Any]:
    """:func:`~safeswitch.training.pipeline.train`, then ``training_curves.png`` in the run
    directory; returns the run's metrics."""
    metrics = train(config, out, resume=resume, progress_bar=progress_bar)
    run = Path(out)
    env = load_config(run / "config.yaml").env
    try:
        training_curves(
            run / "progress.csv",
            run / "training_curves.png",
            title=f"switching={env.switching}, R_ADAS {'on' if env.adas_penalty else 'off'}",
        )
    except Exception as exc:  # a figure must never cost a finished run
        print(f"warning: training_curves.png not written: {exc}", file=sys.stderr)
    return metrics
