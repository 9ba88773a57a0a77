"""Learning on every plant: issue #39's targets against what the benchmarks measured.

Reads the results the training benchmarks wrote (it trains nothing) and prints one row per
plant and method: the figures per training seed, the target and whether every seed meets it.
Each row names the script that measured it; re-run that script to re-measure the row.

With ``--shipped`` only each plant's own recipe is listed (the one its shipped policies or the
pipeline's defaults come from): the README's table. Every row carries ``shipped`` in ``--json``.

Run: ``python benchmarks/plants.py [--brief] [--shipped] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from safeswitch.leftturn.config import CertifiedConfig
from safeswitch.training.config import EnvPolicyConfig, load_config

RESULTS = Path(__file__).parent / "results"

Row = dict[str, Any]


def _load(name: str) -> dict[str, Any] | None:
    path = RESULTS / name
    return json.loads(path.read_text()) if path.exists() else None


def _col(runs: list[dict[str, Any]], key: str | Callable[[dict[str, Any]], Any], spec: str = "",
         unit: str = "") -> str:  # fmt: skip
    """One figure per training seed, ``a / b / c``: ``key`` of each run (or ``key(run)``)."""
    get = key if callable(key) else (lambda run: run[key])

    def one(value: Any) -> str:
        if isinstance(value, float) and value != value:  # NaN: the run did not record it
            return "not recorded"
        return format(value, spec) + unit

    return " / ".join(one(get(run)) for run in runs)


def left_turn(
    config: str,
    scenarios: int = 1000,
    logic: str | None = None,
    method: str | None = None,
    before: str | None = None,
) -> Row | None:
    """The left turn's recipe ``config`` (``train_seeds.py``), 1,000 unseen scenarios, against
    the targets of ``logic``'s row (default: the recipe's own name); ``method`` names a
    variant (an experimental recipe: not the shipped one), ``before`` the command that makes
    what it needs."""
    stem = config.replace("/", "_")
    data = _load(f"train_seeds_{stem}.json")
    if data is None:
        return None
    runs = sorted(data["runs"], key=lambda r: r["seed"])
    logic = logic or config
    paper = logic == "paper"
    checks = {
        "0 collisions in training and evaluation": all(
            r["training_collision_episodes"] == 0 and r["collisions"] == 0 for r in runs
        ),
        "never above 30 km/h": all(r["speeding_episodes"] == 0 for r in runs),
        "efficiency ≥ 0.85": all(r["mean_efficiency"] >= 0.85 for r in runs),
    }
    if paper:
        checks["safety action ≤ 2 % of episodes"] = all(
            r["safety_activation_episodes"] <= 0.02 * scenarios for r in runs
        )
        checks["comfort exceeded ≤ 0.5 % of ticks"] = all(
            r["comfort_violation_fraction"] <= 0.005 for r in runs
        )
        checks["crosses first ≥ 20 %"] = all(r["cut_episodes"] >= 0.2 * scenarios for r in runs)
    else:
        checks["clears ≥ 99 %"] = all(r["cleared_episodes"] >= 0.99 * scenarios for r in runs)
    comfort = _col(runs, lambda r: 100 * r["comfort_violation_fraction"], ".2f", " %")
    measured = (
        f"training collisions {_col(runs, 'training_collision_episodes')}; collisions "
        f"{_col(runs, 'collisions')}; safety action {_col(runs, 'safety_activation_episodes')} "
        f"episodes; comfort {comfort}; "
        f"top {_col(runs, 'max_speed_kmh', '.1f')} km/h; cuts {_col(runs, 'cut_episodes')}; "
        f"cleared {_col(runs, 'cleared_episodes')}; efficiency "
        f"{_col(runs, 'mean_efficiency', '.3f')}"
    )
    source = (
        f"{before}; " if before else ""
    ) + f"python benchmarks/train_seeds.py --config {config}"
    timing = _load(f"train_time_{stem}.json")  # bench_train.py: the recipe alone on the machine
    if timing is not None:
        checks["≤ 5 min to train on one torch thread"] = (
            timing["wall_time_s"] <= 300 and timing["torch_threads"] == 1
        )
        when = ", ".join(str(timing[k]) for k in ("cpu", "date") if k in timing)
        measured += f"; {timing['wall_time_s']:.0f} s to train, alone on one torch thread" + (
            f" ({when})" if when else ""
        )
        source += (
            f"; python benchmarks/bench_train.py --config {config} "
            f"--out benchmarks/results/train_time_{stem}.json"
        )
    return {
        "plant": f"left turn, `{logic}`",
        "method": method or f"PPO with R_ADAS from a random start, `configs/{config}.yaml`",
        "seeds": [r["seed"] for r in runs],
        "measured": measured,
        "checks": checks,
        "shipped": method is None,
        "source": source,
    }


#: The left turn's variants (not shipped): the recipe, the logic whose row's targets it is
#: held to, its method, and the command that makes what it needs.
LEFT_TURN_VARIANTS = (
    (
        "experimental/certified_go_plain",
        "certified",
        "PPO with R_ADAS from a random start and a go predictor fitted on the training scene, "
        "3 M steps (`experiments/certified_go_plain.yaml`)",
        "python experiments/go_leftturn.py --out experiments/go_model_leftturn_plain.npz",
    ),
    (
        "experimental/certified_go_4m",
        "certified",
        "PPO with R_ADAS from a random start and a go predictor fitted on the training scene, "
        "4 M steps (the recipe shipped earlier on 2026-12-05; frozen, it needs the filter in "
        "740 of 2,000 scenarios with the north car at 38-44 km/h, benchmarks/shifts.py; "
        "`experiments/certified_go_4m.yaml`)",
        "python experiments/go_leftturn.py --out experiments/go_model_leftturn_plain.npz",
    ),
    (
        "experimental/certified_go_wide",
        "certified",
        "PPO with R_ADAS from a random start and a go predictor fitted on the shifts' wider "
        "ranges, every training episode from the training scene "
        "(`experiments/certified_go_wide.yaml`)",
        "python experiments/go_leftturn.py --config experimental/go_leftturn_wide_scene "
        "--out experiments/go_model_leftturn_wide.npz",
    ),
    (
        "experimental/certified_go_wide_train",
        "certified",
        "PPO with R_ADAS from a random start, trained on the shifts' wider ranges, with their "
        "go predictor (`experiments/certified_go_wide_train.yaml`)",
        "python experiments/go_leftturn.py --config experimental/go_leftturn_wide_scene "
        "--out experiments/go_model_leftturn_wide.npz",
    ),
    (
        "experimental/certified_go_annealed_e6_5m_slow",
        "certified",
        "PPO with R_ADAS from a random start, the wide go predictor, half of its training scenes "
        "wide, the exploration noise annealed, 6 epochs, 5 M steps, selected on slow oncoming "
        "cars too, the throttle alone (the recipe shipped earlier on 2026-12-06, "
        "`experiments/certified_go_annealed_e6_5m_slow.yaml`)",
        None,
    ),
    (
        "experimental/certified_go_wide_mix",
        "certified",
        "PPO with R_ADAS from a random start, the wide go predictor, half of its training scenes "
        "wide, the exploration noise learned, 8 epochs, 4 M steps (the recipe shipped from "
        "2026-12-05 to 2026-12-06, `experiments/certified_go_wide_mix.yaml`)",
        None,
    ),
    (
        "experimental/certified_ablate_noise",
        "certified",
        "PPO with R_ADAS from a random start without the go predictor, 3 M steps (the recipe "
        "shipped from 2026-12-01 to 2026-12-05, `experiments/certified_ablate_noise.yaml`)",
        None,
    ),
)


#: The densities a traffic recipe's safety target holds at (``train_seeds.py --traffic-eval``).
TRAFFIC_FAMILIES = ("test", "light", "medium", "heavy")


def traffic(config: str = "traffic_certified", shipped: bool = True) -> Row | None:
    """Traffic from every leg under ``certified`` (``train_seeds.py --traffic-eval``), against
    the gap planner under the same filter (``traffic_certified.py``); ``shipped``: the recipe
    of the shipped ``traffic-certified`` policy (else a recipe shipped beside it)."""
    data, planners = _load(f"train_seeds_{config}.json"), _load("traffic_certified.json")
    if data is None or planners is None:
        return None
    runs = sorted(data["runs"], key=lambda r: r["seed"])
    recipe = load_config(config)
    narrow = recipe.env.certified.ego_max_lateral_m < CertifiedConfig().ego_max_lateral_m
    planner_name = "gap_planner (narrower zones)" if narrow else "gap_planner"
    planner = next(r for r in planners["rows"]
                   if r["controller"] == planner_name and r["traffic"] == "test")  # fmt: skip
    families = [f for f in TRAFFIC_FAMILIES if all(f in r.get("traffic", {}) for r in runs)]

    def test(key: str) -> Callable[[dict[str, Any]], Any]:
        return lambda run: run["traffic"]["test"][key]

    checks = {
        "from a random start (no demonstrations)": all(
            r["warm_start_collisions"] is None for r in runs
        ),
        "0 collisions in training and on 1,000 `test` scenes": all(
            r["training_collision_episodes"] == 0
            and not r["warm_start_collisions"]
            and r["traffic"]["test"]["failures"] == 0
            for r in runs
        ),
        "safety action ≤ 5 % of episodes at every density": len(families) == 4
        and all(
            r["traffic"][f]["safety_activation_episodes"] <= 0.05 * r["traffic"][f]["episodes"]
            for r in runs
            for f in families
        ),
        f"efficiency ≥ the gap planner's ({planner['mean_efficiency']:.3f} on `test`, "
        "the same filter)": all(
            test("mean_efficiency")(r) >= planner["mean_efficiency"] for r in runs
        ),
    }
    safety = "; ".join(
        f"{f} {_col(runs, lambda r, f=f: r['traffic'][f]['safety_activation_episodes'])}"
        for f in families
    )
    measured = (
        f"collisions: warm start {_col(runs, lambda r: r['warm_start_collisions'] or 0)}, "
        f"training {_col(runs, 'training_collision_episodes')}, `test` "
        f"{_col(runs, test('failures'))}; safety action in episodes of 1,000: {safety}; "
        f"`test`: cleared {_col(runs, test('cleared_episodes'))}, efficiency "
        f"{_col(runs, test('mean_efficiency'), '.3f')}, top "
        f"{_col(runs, test('max_speed_kmh'), '.1f')} km/h (the gap planner: cleared "
        f"{planner['cleared_episodes']}, {planner['mean_efficiency']:.3f})"
    )
    taught = recipe.warm_start.episodes > 0
    method = (
        f"a clone of the {recipe.warm_start.teacher.replace('_', ' ')} "
        f"({recipe.warm_start.rounds} DAgger rounds), then PPO with R_ADAS"
        if taught
        else "PPO with R_ADAS from a random start"
    )
    if recipe.constraints.active() and recipe.validation.every:
        method += " (constrained, its policy chosen on validation scenes)"
    return {
        "plant": "traffic from every leg, `certified`",
        "method": f"{method}, `configs/{config}.yaml`",
        "seeds": [r["seed"] for r in runs],
        "measured": measured,
        "checks": checks,
        "shipped": shipped,
        "source": f"python benchmarks/train_seeds.py --config {config} --parallel 2 "
        f"--traffic-eval {' '.join(TRAFFIC_FAMILIES)}; python benchmarks/traffic_certified.py",
    }


def _comfort_share(evaluation: dict[str, Any]) -> float:
    """The evaluation steps beyond the comfort limits, as a share (NaN: not recorded)."""
    costs = evaluation.get("cost_steps")
    return costs["comfort"] / evaluation["steps"] if costs else float("nan")


def _learned_comfort_share(evaluation: dict[str, Any]) -> float:
    """The evaluation steps the *learned* controller drove beyond the comfort limits, as a
    share (the Safety controller may sacrifice comfort; NaN: not recorded)."""
    costs, by_safety = evaluation.get("cost_steps"), evaluation.get("safety_cost_steps")
    if not costs or by_safety is None:
        return float("nan")
    return (costs["comfort"] - by_safety["comfort"]) / evaluation["steps"]


def _speeding(evaluation: dict[str, Any]) -> float:
    costs = evaluation.get("cost_steps")
    return costs["speeding"] if costs else float("nan")


#: highway_switch.py's results: file → (the recipe, its command's options, the weight of the
#: recipe's own fit toward the interventions or ``None``).
#: The result of the recipe the shipped highway-env policies come from.
HIGHWAY_SHIPPED = "highway_recipe.json"
HIGHWAY_RESULTS: dict[str, tuple[str, str, float | None]] = {
    "highway.json": ("PPO as Table II on highway-env's full steering", "", None),
    "highway_comfort.json": (
        "the `highway` recipe with Table II's PPO, as shipped until 2026-11-30 (learned "
        "steering ±0.025 rad, comfort a constraint",
        " --config experimental/highway_table2 --timesteps 100000 "
        "--out benchmarks/results/highway_comfort.json --figure docs/highway_training_comfort.png",
        1.0,
    ),
    "highway_recipe.json": (
        "the `highway` recipe as shipped (a plant's default PPO, learned steering ±0.025 rad, "
        "comfort a constraint",
        " --config highway --timesteps 100000 --out benchmarks/results/highway_recipe.json "
        "--figure docs/highway_training_recipe.png",
        1.0,
    ),
}


def _highway_method(recipe: str, own: float | None, imitation: float) -> str:
    """The recipe as a run trained it: with its own fit toward the interventions or without."""
    if own is None:
        return recipe + (f", + intervention imitation {imitation:g}" if imitation else "")
    if imitation == own:
        return f"{recipe}, the fit toward the interventions with weight {imitation:g})"
    if not imitation:
        return f"{recipe}; R_ADAS alone, without its fit toward the interventions)"
    return f"{recipe}; the fit toward the interventions with weight {imitation:g}, not {own:g})"


def highway() -> list[Row]:
    """highway-env under each logic against PPO without one (``highway_switch.py``), each
    recipe it measured."""
    return [row for name in HIGHWAY_RESULTS for row in _highway(name)]


def _highway(name: str) -> list[Row]:
    data = _load(name)
    if data is None:
        return []
    recipe, options, own = HIGHWAY_RESULTS[name]
    runs = data["runs"]

    def comfort(run: dict[str, Any]) -> float:
        return 100 * _comfort_share(run["evaluation"])

    def learned_comfort(run: dict[str, Any]) -> float:
        return 100 * _learned_comfort_share(run["evaluation"])

    none = {r["seed"]: r for r in runs if r["switching"] == "none" and not r["imitation"]}
    floors = {f["switching"]: f for f in data.get("idm_driver", [])}
    rows = []
    methods = {(r["switching"], r["imitation"]) for r in runs} - {("none", 0.0)}
    for logic, imitation in sorted(methods):
        mine = sorted(
            (r for r in runs if (r["switching"], r["imitation"]) == (logic, imitation)),
            key=lambda r: r["seed"],
        )
        floor = floors.get(logic, {}).get("safety_share")
        share_bound = max(0.005, floor) if floor is not None else 0.005
        ratios = [
            r["evaluation"]["mean_return"] / none[r["seed"]]["evaluation"]["mean_return"]
            if r["seed"] in none
            else float("nan")
            for r in mine
        ]
        checks = {
            "0 crashes and 0 off road in training": all(
                r["crashes"] == 0 and r["off_road"] == 0 for r in mine
            ),
            "0 crashes in evaluation": all(r["evaluation"]["failures"] == 0 for r in mine),
            f"Safety controller ≤ {100 * share_bound:.2f} % of steps (0.5 % or the IDM floor)": (
                all(r["evaluation"]["safety_share"] <= share_bound for r in mine)
            ),
            "return ≥ 95 % of PPO without the switch": all(q >= 0.95 for q in ratios),
            "the learned controller beyond comfort ≤ 1 % of evaluation steps, never above "
            "30 m/s": all(
                _learned_comfort_share(r["evaluation"]) <= 0.01 and _speeding(r["evaluation"]) == 0
                for r in mine
            ),
        }
        floor_text = "—" if floor is None else format(100 * floor, ".2f") + " %"
        measured = (
            f"training crashes / off road {_col(mine, lambda r: (r['crashes'], r['off_road']))}"
            f" in {_col(mine, 'episodes')} episodes; evaluation crashes "
            f"{_col(mine, lambda r: r['evaluation']['failures'])}; Safety controller "
            f"{_col(mine, lambda r: 100 * r['evaluation']['safety_share'], '.2f', ' %')} of "
            f"steps (IDM/MOBIL driver: {floor_text}); return "
            f"{' / '.join(format(q, '.3f') for q in ratios)} of PPO's without the switch; "
            f"comfort exceeded on {_col(mine, comfort, '.2f', ' %')} of steps, by the learned "
            f"controller on {_col(mine, learned_comfort, '.2f', ' %')} (PPO without the "
            f"switch: {_col([none[s] for s in sorted(none)], comfort, '.2f', ' %')})"
        )
        rows.append(
            {
                "plant": "highway-env",
                "method": f"PPO with R_ADAS = −1 under `{logic}`, "
                f"{_highway_method(recipe, own, imitation)}, {data['timesteps']:,} steps",
                "seeds": [r["seed"] for r in mine],
                "measured": measured,
                "checks": checks,
                "shipped": name == HIGHWAY_SHIPPED and imitation == own,
                "source": f"python benchmarks/highway_switch.py --logics {logic} none{options}"
                + (f" --imitation {imitation:g}" if imitation else "")
                + (" --imitation-only" if imitation and (logic, 0.0) not in methods else ""),
            }
        )
    return rows


#: The generic recipe's weight of the fit toward the interventions (``EnvPolicyConfig``).
DEFAULT_FIT = EnvPolicyConfig().intervention_imitation


def own_plant(name: str, label: str, command: str) -> list[Row]:
    """A plant registered as a user registers one (``interventions.py``), penalty alone and
    with the fit toward the executed safety action."""
    data = _load(f"interventions_{name}.json")
    if data is None:
        return []
    rows = []
    section = ", ".join(data.get("settings") or []) or "a plant's defaults"
    for weight in sorted({r["intervention_imitation"] for r in data["runs"]}):
        mine = sorted(
            (r for r in data["runs"] if r["intervention_imitation"] == weight),
            key=lambda r: r["seed"],
        )
        how = (
            "penalty alone (the paper's R_ADAS)"
            if weight == 0
            else f"penalty + intervention imitation {weight:g}"
            + (" (the default)" if weight == DEFAULT_FIT else "")
        )
        rows.append(
            {
                "plant": label,
                "method": f"PPO ({section}), {how}, {mine[0]['timesteps']:,} steps",
                "seeds": [r["seed"] for r in mine],
                "measured": (
                    "failures (training, evaluation) "
                    f"{_col(mine, lambda r: (r['training_failures'], r['failures']))}; "
                    "Safety controller "
                    f"{_col(mine, lambda r: 100 * r['safety_share'], '.2f', ' %')} of steps"
                ),
                "shipped": weight == DEFAULT_FIT,
                "checks": {
                    "0 failures": all(
                        r["training_failures"] == 0 and r["failures"] == 0 for r in mine
                    ),
                    "Safety controller ≤ 2 % of evaluation steps": all(
                        r["safety_share"] <= 0.02 for r in mine
                    ),
                },
                "source": command,
            }
        )
    return rows


def variants() -> list[Row]:
    """The rows of :data:`LEFT_TURN_VARIANTS` that have results."""
    found = (left_turn(c, logic=logic, method=m, before=b) for c, logic, m, b in LEFT_TURN_VARIANTS)
    return [row for row in found if row]


def rows() -> list[Row]:
    sources: list[Callable[[], list[Row]]] = [
        lambda: [
            r
            for r in (
                left_turn("paper"),
                left_turn("certified"),
                traffic(),
                traffic("traffic_certified_clone", shipped=False),
            )
            if r
        ],
        variants,
        highway,
        lambda: own_plant(
            "Follow-v0_100k",
            "car following (`tests/core/follow_plant.py`, the README's plant)",
            "python benchmarks/interventions.py --env tests.core.follow_plant:Follow-v0 "
            "--switching braking-envelope --timesteps 100000 "
            "--out benchmarks/results/interventions_Follow-v0_100k.json",
        ),
        lambda: own_plant(
            "UserWall-v0_100k",
            "a user's plant via `--import` (`tests/core/user_plant.py`)",
            "python benchmarks/interventions.py --timesteps 100000 "
            "--out benchmarks/results/interventions_UserWall-v0_100k.json",
        ),
    ]
    return [row for source in sources for row in source()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--brief", action="store_true", help="leave out the measured figures")
    parser.add_argument(
        "--shipped", action="store_true", help="only each plant's own recipe (the README's rows)"
    )
    args = parser.parse_args(argv)
    table = [row for row in rows() if row["shipped"] or not args.shipped]
    for row in table:  # issue #39 asks every target of training seeds 1, 2 and 3
        missing = sorted({1, 2, 3} - set(row["seeds"]))
        if missing:
            label = "seed" + "s" * (len(missing) > 1) + " " + ", ".join(map(str, missing))
            row["checks"][f"training {label} not measured yet"] = False
    if args.json:
        print(json.dumps(table, indent=2))
        return 0
    columns = ["plant", "method", "measured (training seeds in order)", "targets missed",
               "reproduce"]  # fmt: skip
    if args.brief:
        columns.remove("measured (training seeds in order)")
    print("| " + " | ".join(columns) + " |")
    print("|" + " --- |" * len(columns))
    for row in table:
        missed = [name for name, ok in row["checks"].items() if not ok]
        verdict = "none" if not missed else "**" + "; ".join(missed) + "**"
        seeds = ("seed " if len(row["seeds"]) == 1 else "seeds ") + ", ".join(
            str(s) for s in row["seeds"]
        )
        cells = [row["plant"], f"{row['method']} ({seeds})", row["measured"], verdict,
                 f"`{row['source']}`"]  # fmt: skip
        if args.brief:
            del cells[2]
        print("| " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
