"""Perception errors (the paper's Remark 2): what they do, what the certified guarantee holds
against, what it costs, and how fast the environment stays.

1. **Sweeps** — each perception key on its own and all bounded errors together, random and
   adversarial errors, for the paper policy under the paper logic and the certified policy under
   the certified logic assuming perfect perception or the declared bounds
   (:mod:`safeswitch.app.perception_study`); 1,000 unseen random scenarios (seed 1000003) per
   cell. Collisions and failures use the truth; efficiency is against the oracle (truth).
2. **Guarantee** — the certified logic with declared bounds against every adversary family of
   the single-car scene (``safeswitch.evaluation.adversaries``; the adversary drives the whole
   episode), adversarial errors with every key at once (100,800 episodes), then larger bounds
   with random and adversarial errors; beside it the logic that assumes perfect perception.
3. **Speed** — ``VecEnv`` steps per second at 4,096 environments with and without perception
   (every key on), measured alternately in one run (median of three).
4. **Calibration** — held-out coverage of split-conformal bounds on simulated sensors.
5. **Traffic from every leg** — the guarantee at every density (8 adversary families × 4
   presets × 3,200 scenes, adversarial errors on every key), and the policies trained in
   traffic under the same sweeps on the ``test`` family (300 scenes per cell).

Run: ``python benchmarks/perception.py [--parts sweeps,traffic,guarantee,speed,calibration]``
(one core, one torch thread; about 35 minutes in all); writes
``benchmarks/results/perception.json`` (the parts not run are kept from it),
``docs/perception.png`` and ``docs/perception_traffic.png``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

import _common
from safeswitch.app.perception_study import CONTROLLERS, TRAFFIC_CONTROLLERS, study, together
from safeswitch.bench import vec_env_steps_per_s
from safeswitch.evaluation.adversaries import catalogue
from safeswitch.evaluation.calibration import SensorModel, calibrate, simulate_pairs
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.config import resolve_config
from safeswitch.leftturn.make import build_task
from safeswitch.report.figures import perception_figure
from safeswitch.training.policies import load_policy

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results" / "perception.json"
FIGURE = ROOT / "docs" / "perception.png"
TRAFFIC_FIGURE = ROOT / "docs" / "perception_traffic.png"
PARTS = ("sweeps", "traffic", "guarantee", "speed", "calibration")
PAPER_SCENE = "in the paper's scene (1,000 scenarios per point)"
TRAFFIC_SCENE = "in traffic from every leg (test family, 300 scenes per point)"
SEED = 1_000_003

#: Every key at once, adversarial: the guarantee's main set.
EVERYTHING = {
    "position_error_m": 1.0, "speed_error_mps": 1.0, "latency_s": 0.2, "dropout_prob": 0.05,
    "dropout_max_s": 0.5, "sight_distance_m": 40.0, "errors": "adversarial",
}  # fmt: skip
LARGE = {
    "position_error_m": 3.0, "speed_error_mps": 3.0, "latency_s": 0.5, "dropout_prob": 0.1,
    "dropout_max_s": 1.0, "sight_distance_m": 25.0,
}  # fmt: skip


def sweeps() -> list[tuple[str, float, dict[str, object]]]:
    """Every cell: (sweep, level, perception). Level 0 is perfect perception (``errors`` alone
    changes nothing; it places the point on both lines)."""
    cells: list[tuple[str, float, dict[str, object]]] = []
    for errors in ("adversarial", "random"):
        cells += [("together", x, {**together(x, errors), "errors": errors})
                  for x in (0.0, 0.5, 1.0, 2.0, 3.0)]  # fmt: skip
        for key, levels in (
            ("position_error_m", (0.0, 0.5, 1.0, 2.0, 4.0)),
            ("speed_error_mps", (0.0, 0.5, 1.0, 2.0, 4.0)),
            ("latency_s", (0.0, 0.1, 0.2, 0.4, 0.8)),
        ):
            cells += [(key, x, {key: x, "errors": errors}) for x in levels]
        cells += [
            ("dropout_max_s", x,
             {"dropout_prob": 0.05 if x else 0.0, "dropout_max_s": x, "errors": errors})
            for x in (0.0, 0.25, 0.5, 1.0, 2.0)
        ]  # fmt: skip
        cells += [
            ("sight_distance_m", x, {"sight_distance_m": x or None, "errors": errors})
            for x in (0.0, 60.0, 40.0, 25.0)
        ]
    return cells


def guarantee(count: int, small: int, traffic: int) -> list[dict[str, object]]:
    # the trained adversary: the shipped paper policy, on the paper scene's six observations
    # (the certified policy's seventh, its go predictor's, is not in these scenes)
    trained = load_policy("shipped").act
    rows = []
    cases: list[tuple[str, dict[str, object], str, int, str | None]] = [
        ("every key, adversarial", EVERYTHING, "declared", count, None),
        ("larger bounds, random", {**LARGE, "errors": "random"}, "declared", small, None),
        ("larger bounds, adversarial", {**LARGE, "errors": "adversarial"}, "declared", small,
         None),
        ("every key, adversarial", EVERYTHING, "perfect", small, None),
    ]  # fmt: skip
    for preset in ("light", "medium", "heavy", "test"):
        cases.append(("every key, adversarial", EVERYTHING, "declared", traffic, preset))
    cases.append(("every key, adversarial", EVERYTHING, "perfect", traffic // 2, "medium"))
    for name, perception, assume, episodes, preset in cases:
        config = resolve_config(
            {"episode": {"learned_scope": "episode"}, "certified": {"perception": assume}},
            switching="certified", perception=perception,
        )  # fmt: skip
        task = build_task(None, config, traffic=preset)
        scenarios = task.scenario_set(SEED, episodes)
        families = {}
        adversaries = catalogue(task, episodes, seed=7, trained=None if preset else trained)
        for family, make in adversaries.items():
            result = rollout(task, scenarios, make())
            families[family] = {
                "episodes": episodes,
                "collisions": int(result.collision.sum()),
                "failures": int((result.collision | result.lost_control).sum()),
                "safety_activation_episodes": int((result.safety_steps > 0).sum()),
            }
        total = sum(f["episodes"] for f in families.values())
        failures = sum(f["failures"] for f in families.values())
        rows.append({"scene": preset or "paper's scene", "bounds": name,
                     "perception": perception, "certified_perception": assume,
                     "episodes": total, "failures": failures, "families": families})  # fmt: skip
        print(f"  {preset or 'paper':6s} certified ({assume:8s}) {name:28s} {failures:5d} "
              f"failures in {total:,} episodes over {len(families)} adversary families",
              file=sys.stderr)  # fmt: skip
    return rows


def speed(rounds: int, seconds: float) -> dict[str, object]:
    perception = dict(EVERYTHING)
    runs: dict[str, list[float]] = {}
    for _ in range(rounds):
        for switching in ("paper", "certified"):
            for on in (False, True):
                kwargs = {"perception": perception} if on else {}
                key = f"{switching}, perception {'on' if on else 'off'}"
                runs.setdefault(key, []).append(
                    vec_env_steps_per_s(4096, switching, seconds, **kwargs)
                )
    medians = {k: statistics.median(v) for k, v in runs.items()}
    return {
        "num_envs": 4096, "rounds": rounds, "median_steps_per_s": medians, "runs": runs,
        "ratio": {s: medians[f"{s}, perception on"] / medians[f"{s}, perception off"]
                  for s in ("paper", "certified")},
    }  # fmt: skip


def coverage() -> list[dict[str, object]]:
    rows = []
    for distribution in ("gaussian", "laplace"):
        for alpha in (0.05, 0.01):
            sensor = SensorModel(position_sigma_m=0.5, speed_sigma_mps=0.3,
                                 distribution=distribution)  # fmt: skip
            r = calibrate(*simulate_pairs(sensor, 100_000, seed=1), alpha=alpha, seed=1)
            rows.append({"distribution": distribution, "alpha": alpha,
                         "position_error_m": r.position_error_m,
                         "speed_error_mps": r.speed_error_mps,
                         "coverage_position": r.coverage_position,
                         "coverage_speed": r.coverage_speed, "coverage_both": r.coverage_both,
                         "holdout_pairs": r.holdout_pairs})  # fmt: skip
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=1000, help="scenarios per sweep cell")
    parser.add_argument(
        "--guarantee",
        type=int,
        default=11_200,
        help="scenarios per adversary family, main set (9 families)",
    )
    parser.add_argument(
        "--traffic",
        type=int,
        default=3_200,
        help="scenes per adversary family and traffic preset (8 × 4)",
    )
    parser.add_argument(
        "--traffic-episodes", type=int, default=300, help="scenes per cell of the traffic sweep"
    )
    parser.add_argument(
        "--parts", default=",".join(PARTS),
        help=f"which parts to run, comma-separated ({', '.join(PARTS)}); the others are kept "
        "from the results file",
    )  # fmt: skip
    parser.add_argument("--replot", action="store_true", help="redraw the figures only")
    args = parser.parse_args()
    torch.set_num_threads(1)
    parts = args.parts.split(",")
    unknown = sorted(set(parts) - set(PARTS))
    if unknown:
        parser.error(f"--parts: unknown {unknown} (known: {', '.join(PARTS)})")
    if args.replot:
        import json

        saved = json.loads(RESULTS.read_text())
        perception_figure(saved["sweeps"], FIGURE, PAPER_SCENE)
        perception_figure(saved["traffic_sweeps"], TRAFFIC_FIGURE, TRAFFIC_SCENE)
        return
    result: dict[str, object] = {}
    if set(parts) != set(PARTS):
        import json

        result = json.loads(RESULTS.read_text())
    log = lambda line: print(line, file=sys.stderr)  # noqa: E731
    result.update(machine=_common.machine(), torch_threads=1, seed=SEED)
    # Each part's own wall time (the parts not run keep theirs, with the date they ran).
    kept = result.get("wall_time_s")
    timings = {k: v for k, v in kept.items() if k in PARTS} if isinstance(kept, dict) else {}
    for part in PARTS:
        if part not in parts:
            continue
        began = time.perf_counter()
        if part == "sweeps":
            log("sweeps")
            result["episodes_per_cell"] = args.episodes
            result["sweeps"] = study(sweeps(), args.episodes, SEED, CONTROLLERS, log=log)
        elif part == "traffic":
            log("traffic sweeps")
            result["traffic_episodes_per_cell"] = args.traffic_episodes
            result["traffic_sweeps"] = study(
                sweeps(), args.traffic_episodes, SEED, TRAFFIC_CONTROLLERS, log=log
            )
        elif part == "guarantee":
            log("guarantee")
            result["guarantee"] = guarantee(args.guarantee, max(1000, args.guarantee // 5),
                                            args.traffic)  # fmt: skip
        elif part == "speed":
            log("speed")
            result["speed"] = speed(3, 1.5)
        else:
            result["calibration"] = coverage()
        timings[part] = {
            "seconds": round(time.perf_counter() - began, 1),
            "date": time.strftime("%Y-%m-%d"),
        }
    result["wall_time_s"] = timings
    _common.publish(result, RESULTS, as_json=False)
    perception_figure(result["sweeps"], FIGURE, PAPER_SCENE)  # type: ignore[arg-type]
    perception_figure(result["traffic_sweeps"], TRAFFIC_FIGURE, TRAFFIC_SCENE)  # type: ignore[arg-type]
    log(f"wrote {RESULTS}, {FIGURE} and {TRAFFIC_FIGURE}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
