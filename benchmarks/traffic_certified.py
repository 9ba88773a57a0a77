"""Driving in traffic from every leg: who clears, how often the safety action is needed, who
collides — the shipped traffic policies beside the gap planner and the rule.

On the same random scenes (seed 1000003, the README's) of the ``train`` and ``test`` traffic
families: the gap planner (``--controller gap_planner``, under ``certified``, with the filter's
default zones, with the zones of the shipped ``traffic-certified`` policy's recipe, and in that
recipe's whole scene: its zones, limiters and decision rate — there also with a braked approach,
``gap_planner.approach=brake`` at 2 m/s², as the recipe's learned brake allows), the
rule-based system (``PID_th`` proposing throughout) under ``certified`` and under ``paper``, the
shipped ``traffic-certified`` (PPO from a random start), ``traffic-certified-clone`` (the clone
of the gap planner shipped before it) and ``traffic-paper`` policies (each under the logic it
was trained with) and any trained runs given with ``--model``; and the shipped
``traffic-certified`` policy in ``light``, ``medium`` and ``heavy`` traffic too. Every row is
``safeswitch evaluate``'s summary, cut to the fields the README quotes.

Run: ``python benchmarks/traffic_certified.py [--episodes N] [--model RUN ...] [--json]``
(about nine minutes at the default 1,000 scenes per family, one core); writes
``benchmarks/results/traffic_certified.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import _common
from safeswitch.app.evaluate import evaluate
from safeswitch.app.reproduce import EVAL_SEED
from safeswitch.io import write_json
from safeswitch.training.config import load_config

RESULTS = Path(__file__).parent / "results" / "traffic_certified.json"
FAMILIES = ("train", "test")
#: The densities the shipped certified policy is also measured at.
DENSITIES = ("light", "medium", "heavy")
FIELDS = (
    "switching", "episodes", "collisions", "failures", "safety_activation_episodes",
    "cleared_episodes", "stops", "comfort_violation_fraction", "comfort_violation_episodes",
    "speeding_episodes", "max_speed_kmh", "mean_efficiency", "mean_time_to_clear_s",
)  # fmt: skip


#: The gap planner's wait braked to its stop (``GapPlannerConfig.approach``), at the best of
#: ``experiments/probe_traffic_approach.py``'s approaches.
BRAKED_APPROACH = ("gap_planner.approach=brake", "gap_planner.coast_decel=2.0")


def recipe_zones() -> tuple[str, ...]:
    """The certified filter's zones of the shipped ``traffic-certified`` recipe
    (``configs/traffic_certified.yaml``: narrower than the default, sound behind the speed
    limiter its policy drives with), as ``--set`` settings."""
    zones = load_config("traffic_certified").env.certified
    return (f"env.certified.ego_max_lateral_m={zones.ego_max_lateral_m}",
            f"env.certified.zone_margin_m={zones.zone_margin_m}")  # fmt: skip


def recipe_scene() -> tuple[str, ...]:
    """The shipped ``traffic-certified`` recipe's scene, as ``--set`` settings: its zones
    (:func:`recipe_zones`), each learned action held for ``episode.decision_interval`` ticks
    (the gap planner rechecks its go decision every 0.1 s, the policy decides every 0.3 s),
    and the speed and curve limiters and the learned brake its policy drives with (a throttle
    held 0.3 s would otherwise overshoot the speed limit: 30.7 km/h)."""
    env = load_config("traffic_certified").env
    c = env.controllers
    return (*recipe_zones(), f"env.episode.decision_interval={env.episode.decision_interval}",
            f"env.controllers.learned_speed_limiter_kmh={c.learned_speed_limiter_kmh}",
            f"env.controllers.learned_curve_accel={c.learned_curve_accel}",
            f"env.controllers.learned_curve_decel={c.learned_curve_decel}",
            f"env.controllers.learned_brake={str(c.learned_brake).lower()}")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument(
        "--model", nargs="*", default=[], help="trained runs to add (rows named by directory)"
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    shipped = ("learned:traffic-certified", "learned", "traffic-certified", None, ())
    runs: list[tuple[str, str, str | None, str | None, tuple[str, ...]]] = [
        ("gap_planner", "gap_planner", None, None, ()),
        ("gap_planner (narrower zones)", "gap_planner", None, None, recipe_zones()),
        ("gap_planner (the recipe's scene)", "gap_planner", None, None, recipe_scene()),
        (
            "gap_planner (the recipe's scene, braked approach)",
            "gap_planner",
            None,
            None,
            (*recipe_scene(), *BRAKED_APPROACH),
        ),
        ("rule", "rule", None, "certified", ()),
        ("rule", "rule", None, "paper", ()),
        shipped,
        ("learned:traffic-certified-clone", "learned", "traffic-certified-clone", None, ()),
        ("learned:traffic-paper", "learned", "traffic-paper", None, ()),
        *((f"learned:{Path(m).name}", "learned", m, None, ()) for m in args.model),
    ]
    # every family for every controller; the shipped certified policy at every density too
    cells = [(family, run) for family in FAMILIES for run in runs]
    cells += [(preset, shipped) for preset in DENSITIES]
    rows = []
    for family, (name, controller, model, switching, settings) in cells:
        began = time.perf_counter()
        summary = evaluate(controller, model, "random", args.episodes, EVAL_SEED, switching,
                           None, traffic=family, settings=settings)  # fmt: skip
        row = {"controller": name, "traffic": family, **{k: summary[k] for k in FIELDS}}
        row["wall_time_s"] = round(time.perf_counter() - began, 1)
        rows.append(row)
        print(row, file=sys.stderr, flush=True)
    result = {"benchmark": "traffic_certified", **_common.machine(), "seed": EVAL_SEED,
              "rows": rows}  # fmt: skip
    write_json(RESULTS, result)
    _common.emit(result, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
