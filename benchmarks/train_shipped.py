"""Reproduce the shipped policies: train each from its configuration and copy the run's
artefacts into ``src/safeswitch/policies/<name>/`` with a README of how it was made.

Usage: ``python benchmarks/train_shipped.py [--from-runs] [name ...]`` (default: all nine).
Training is the same as ``safeswitch train --config <name> --out runs/<name>``;
``--from-runs`` only copies already finished runs from ``runs/``.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import yaml

from safeswitch.app.train import train_and_plot
from safeswitch.training.config import load_config, named_files

ROOT = Path(__file__).resolve().parent.parent
NAMES = (
    "paper", "paper_warm", "paper_scratch", "no_adas", "certified", "none", "traffic_paper",
    "traffic_certified", "traffic_certified_clone",
)  # fmt: skip
ARTEFACTS = ("model.zip", "vecnormalize.pkl", "config.yaml", "metrics.json", "training_curves.png")
#: Shipped too when the run wrote them: the training log (the report's Fig. 5) and the
#: validation records.
OPTIONAL_ARTEFACTS = ("progress.csv", "validation.csv")


def policy_readme(
    name: str,
    metrics: dict,
    traffic: str | None = None,
    teacher: str = "planner",
    logs: tuple[str, ...] = (),
    named: tuple[str, ...] = (),
) -> str:
    t, e, warm = metrics["training"], metrics["evaluation"], metrics.get("warm_start")
    warm_note = ""
    if warm:
        warm_note = (
            f"\n\nIt is warm-started: before PPO, {warm['episodes']:,} scenarios were driven by "
            f"the\n{teacher.replace('_', ' ')} or its clone ({warm['collisions']} collisions; "
            f"{warm['wall_time_s']:.0f} s of the wall time above)."
        )
    trained = metrics["switching"]
    deployed = metrics.get("deployed_switching", trained)
    logic = f"the `{trained}` switching logic"
    if deployed != trained:
        logic += f" (deployed, and evaluated below, under `{deployed}`)"
    selected = metrics.get("selected") or {}
    if selected.get("best_timesteps"):
        warm_note += (
            f"\n\nThe run's policy is the one it selected on its validation scenarios (seed "
            f"{selected['validation_seed']}), at {selected['best_timesteps']:,} steps."
        )
    logs_text = "".join(f", `{name}`" for name in logs)
    logs_text += "".join(f", `{name}` (the go predictor its observation reads)" for name in named)
    scene, horizon = "random scenarios", "12 s"
    if traffic:
        scene, horizon = f"random scenes of the `{traffic}` traffic family", "30 s"
        warm_note += (
            "\n\nIn traffic from every leg. On the denser, ruder `test` family: "
            "`python benchmarks/traffic_certified.py`\n"
            "(`benchmarks/results/traffic_certified.json`) and docs/traffic.md."
        )
    return f"""# Shipped policy `{name}`

Made with

    safeswitch train --config {name} --out runs/{name}

(seed {metrics["seed"]}, {metrics["timesteps"]:,} steps, {metrics["n_envs"]} environments,
{metrics["torch_threads"]} torch thread(s); {metrics["wall_time_s"]:.0f} s on the project's
two-core machine). Re-running the command reproduces it up to the non-determinism of CPU
floating point across machines.{warm_note}

Trained under {logic}. During training: {t["collisions"]} collisions, a safety
action in {t["safety_activation_episodes"]} of {t["episodes"]} episodes.

Evaluation on {e["episodes"]} unseen {scene} (seed {e["seed"]}): {e["collisions"]}
collisions, safety action in {e["safety_activation_episodes"]} episodes, comfort limits exceeded
on {100 * e["comfort_violation_fraction"]:.2f} % of ticks, {e["stops"]} episodes with a full
stop, mean time to clear the conflict zone {e["mean_time_to_clear_s"]:.2f} s (NaN: it never
cleared it within the {horizon} episode), crossed first in {e["cut_episodes"]} episodes and after
the north car in {e["yield_episodes"]}; {e["mean_efficiency"]:.3f} of the oracle (mean over
scenarios of its time to clear over this policy's).

Files: `model.zip` (SB3 PPO), `vecnormalize.pkl` (observation statistics), `config.yaml`
(the resolved configuration), `metrics.json`, `training_curves.png` (the paper's Fig. 5){logs_text}.
"""


def ship(name: str) -> None:
    run = ROOT / "runs" / name
    target = ROOT / "src" / "safeswitch" / "policies" / name
    target.mkdir(parents=True, exist_ok=True)
    for artefact in ARTEFACTS:
        shutil.copy2(run / artefact, target / artefact)
    for artefact in OPTIONAL_ARTEFACTS:
        if (run / artefact).is_file():
            shutil.copy2(run / artefact, target / artefact)
    files = tuple(n for _, _, n in named_files(yaml.safe_load((run / "config.yaml").read_text())))
    for named in files:
        shutil.copy2(run / named, target / named)  # the run's copy (a go predictor)
    metrics = json.loads((run / "metrics.json").read_text())
    config = load_config(run / "config.yaml")
    traffic = config.traffic
    preset = traffic.get("preset", "custom") if isinstance(traffic, dict) else traffic
    logs = tuple(a for a in OPTIONAL_ARTEFACTS if (run / a).is_file())
    readme = policy_readme(name, metrics, preset, config.warm_start.teacher, logs, files)
    (target / "README.md").write_text(readme)


def main(argv: list[str]) -> int:
    from_runs = "--from-runs" in argv
    names = [a for a in argv if a != "--from-runs"] or list(NAMES)
    for name in names:
        if name not in NAMES:
            print(f"unknown policy {name!r}; choose from {list(NAMES)}", file=sys.stderr)
            return 2
        if not from_runs:
            run = ROOT / "runs" / name
            shutil.rmtree(run, ignore_errors=True)
            train_and_plot(load_config(name), run, progress_bar=False)
        ship(name)
        print(f"shipped {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
