"""``safeswitch render``: one episode of a controller as an animated GIF, to watch a model.

A window (``render_mode="human"``) is not offered: the package draws with Pillow, not a GUI
toolkit, and the machines it is tested on have no screen; open the GIF in any browser or image
viewer instead.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from safeswitch.app.evaluate import controller_setup, fit_observations, traffic_setup
from safeswitch.evaluation.evaluate import run_controller
from safeswitch.io import OutputDirectoryError, write_bytes_atomic
from safeswitch.leftturn.config import SCENARIO_NAMES
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.report.figures import Trace


def scenario_by_name(task: LeftTurnTask, name: str, seed: int) -> Scenarios:
    """``cut``, ``yield1``, ``yield2``, or ``random:K`` (random scenario ``K`` of ``seed``,
    the one ``evaluate --seed`` calls ``random-K``)."""
    if name in SCENARIO_NAMES:
        return task.named(name, 1, seed)  # in traffic: the paper's cars among others
    prefix, _, index = name.partition(":")
    if prefix == "random" and index.isdigit():
        k = int(index)
        return task.draw_scenarios(seed, np.array([k]), np.zeros(1, dtype=np.int64))
    raise ValueError(f"--scenario {name!r} is not one of {', '.join(SCENARIO_NAMES)} or random:K")


def render(
    controller: str,
    model: str | None,
    scenario: str,
    seed: int,
    switching: str | None,
    out: str | Path,
    overwrite: bool = False,
    traffic: str | None = None,
) -> Path:
    """Write the animation of one episode to ``out`` (a ``.gif``); returns its path.
    ``traffic``: as for :func:`~safeswitch.app.evaluate.evaluate`.

    Raises:
        OutputDirectoryError: ``out`` exists and ``overwrite`` is off, or is not a ``.gif``.
    """
    path = Path(out)
    if path.suffix.lower() != ".gif":
        raise OutputDirectoryError(f"--out {path} must name a .gif file")
    if path.exists() and not overwrite:
        raise OutputDirectoryError(f"--out {path} exists; pass --overwrite to replace it")
    if controller == "oracle":
        raise ValueError("the oracle plans a trajectory, it does not drive the plant: no render")
    config, policy = controller_setup(controller, model, switching)
    settings, _ = traffic_setup(controller, model, traffic)
    task = build_task(None, replace(config, scenario=None), traffic=settings)
    policy = fit_observations(policy, model if controller == "learned" else None, task)
    batch = scenario_by_name(task, scenario, seed)
    trace = Trace(task, animate=(0,))
    assert policy is not None
    run_controller(task, policy, batch, trace.on_tick)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(path, trace.gif(0))
    return path
