"""``safeswitch export-scenario``: scenarios as OpenSCENARIO 1.0 with their OpenDRIVE road and
the trajectories of a run (see :mod:`safeswitch.deploy.openscenario`).

Which scenarios (``--scenarios``): the paper's three, ``random`` ones (``--episodes``,
``--seed``: the same as ``safeswitch evaluate`` draws), or ``falsify:FOLDER`` — every
counterexample a ``safeswitch falsify`` run found (its ``scenarios.csv`` rows that failed), then
recorded under the falsified controller and logic themselves. The run that gives the oncoming
car's trajectory is the controller's (``--controller``/``--model``/``--switching``, as
``evaluate`` takes them); ``index.json`` lists every file with the run's outcome.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from safeswitch.io import prepare_output_dir, write_json
from safeswitch.progress import Progress

FALSIFY = "falsify:"


def counterexamples(folder: Path) -> tuple[Any, list[str], dict[str, Any]]:
    """Every failing scenario of a falsification run (both methods, in the order simulated),
    their names, and the run's summary.

    Raises:
        FileNotFoundError: ``folder`` has no ``summary.json`` or ``scenarios.csv``.
        ValueError: The run found no failure.
    """
    from safeswitch.app.falsify import PARAMETERS, scenarios_of

    summary_path, rows_path = folder / "summary.json", folder / "scenarios.csv"
    for path in (summary_path, rows_path):
        if not path.is_file():
            raise FileNotFoundError(f"{path} is missing: is {folder} a safeswitch falsify --out?")
    summary = json.loads(summary_path.read_text(encoding="utf-8"))
    failed_column = "collision" if summary["failure"] == "collision" else "safety_ticks"
    values, names = [], []
    with open(rows_path, newline="", encoding="utf-8") as handle:
        for i, row in enumerate(csv.DictReader(handle)):
            if int(row[failed_column]) > 0:
                values.append([float(row[p]) for p in PARAMETERS])
                names.append(f"{row['method']}-{i:06d}")
    if not values:
        raise ValueError(f"{folder}: the falsification found no {summary['failure']} failure")
    return scenarios_of(np.array(values)), names, summary


def export_scenarios(
    out: str | Path,
    scenarios: str = "paper",
    episodes: int = 1000,
    seed: int = 0,
    controller: str | None = None,
    model: str | None = None,
    switching: str | None = None,
    overwrite: bool = False,
    progress: bool = False,
    traffic: str | None = None,
) -> dict[str, Any]:
    """Write the scenarios with a run's trajectories to ``out``; returns the index.
    ``traffic``: a preset's name (the paper's scene without)."""
    from safeswitch.app.evaluate import controller_setup, fit_observations
    from safeswitch.deploy import openscenario
    from safeswitch.deploy.openscenario import PARAMETERS
    from safeswitch.evaluation.evaluate import scenario_set
    from safeswitch.leftturn.config import traffic_config
    from safeswitch.leftturn.make import build_task

    source: dict[str, Any] = {"scenarios": scenarios, "traffic": traffic or "none"}
    if scenarios.startswith(FALSIFY):
        from safeswitch.app.falsify import Target, target_setup

        if any(v is not None for v in (controller, model, switching, traffic)):
            raise ValueError(
                "--scenarios falsify:FOLDER replays the counterexamples under the controller "
                "and logic that failed, in the paper's scene; drop --controller, --model, "
                "--switching and --traffic"
            )
        batch, names, summary = counterexamples(Path(scenarios[len(FALSIFY) :]))
        if str(summary["controller"]).startswith("adversary:"):
            raise ValueError(
                f"{scenarios}: an adversary draws its actions at random, so its "
                "counterexamples do not replay; falsify a controller (rule, planner, learned)"
            )
        target = Target(summary["controller"], summary["model"], summary["switching"])
        task, policy = target_setup(target, len(names), int(summary["seed"]))
        source.update(controller=target.controller, model=target.model,
                      switching=target.switching, failure=summary["failure"])  # fmt: skip
    else:
        controller = controller or ("learned" if model is not None else "rule")
        config, policy = controller_setup(controller, model, switching)
        if policy is None:
            raise ValueError("--controller oracle plans instead of driving; record another one")
        task = build_task(None, config, traffic=traffic_config(traffic))
        policy = fit_observations(policy, model if controller == "learned" else None, task)
        batch, names = scenario_set(task, scenarios, episodes, seed)
        source.update(controller=controller, model=model, switching=config.switching, seed=seed)
    folder = prepare_output_dir(out, overwrite)
    openscenario.write_road(folder, task)
    bar = Progress(len(names), "export-scenario", enabled=progress)
    entries = []
    chunk = 256
    for start in range(0, len(names), chunk):
        rows = np.arange(start, min(start + chunk, len(names)))
        part = batch.take(rows)
        runs, result = openscenario.record(task, part, policy)
        for k, i in enumerate(rows):
            name = names[i]
            description = (
                f"safeswitch {scenarios} scenario {name} (traffic: {source['traffic']}); the "
                f"other vehicles as they drove while the ego ran {source['controller']} under "
                f"the {source['switching']} logic"
            )
            openscenario.write_scenario(
                folder, name, task, part.take(np.array([k])), runs[k], description,
                traffic=source["traffic"],
            )  # fmt: skip
            values = {osc: float(getattr(part, field)[k]) for osc, field, _ in PARAMETERS}
            entries.append({
                "file": f"{name}.xosc",
                **values,
                "other_vehicles": len(runs[k].others),
                "collision": bool(result.collision[k]),
                "outcome": int(result.outcome[k]),
                "safety_steps": int(result.safety_steps[k]),
                "min_separation_m": float(result.min_separation[k]),
            })  # fmt: skip
            bar.update(1)
    bar.close()
    index = {"source": source, "road": openscenario.ROAD_FILE,
             "openscenario": f"1.{openscenario.OSC_MINOR}", "scenarios": entries}  # fmt: skip
    write_json(folder / "index.json", index)
    return index
