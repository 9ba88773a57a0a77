"""Seed robustness of a training recipe on any plant: train it with each seed and evaluate each run.

Trains ``--config`` (default ``experimental/scratch_annealed_noise``) once per ``--seeds``
value (optionally under another ``--switching``) into a temporary run directory, one torch
thread, and collects each run's ``metrics.json``. Every seed's row is reported (no seed is
picked over another), as JSON lines while the runs end and as one Markdown table at the end.

*The left turn* (a recipe without ``env_id``): training collisions and safety episodes, the
step of the policy the run selected on its validation set (if it validates), and the
deterministic evaluation on 1,000 unseen scenarios (``--seed 1000003``, under the logic the
recipe deploys its policy under — ``deploy_switching``, by default the one it trains with —
and with ``--deploy`` under another too): collisions, safety episodes, comfort,
full stops, cuts, cleared, efficiency. 2 to 4 minutes per seed on a two-core machine, by
recipe.

*Any other plant* (a recipe with ``env_id``, e.g. ``highway`` or a user's
``experiments/X.yaml``; ``--import MODULE`` first for a user's plant): failures (as the plant
declares them) and the Safety controller's steps in training; in the evaluation
(``eval_episodes`` episodes of ``eval_seed``) failures, the share of steps the Safety
controller acted on, the mean return and the steps on which each of the plant's costs was
incurred (and how many of them the Safety controller drove).

With ``--traffic-eval FAMILY ...`` (a left-turn recipe trained in traffic) each run is also
evaluated on 1,000 scenes of each traffic family named, as ``safeswitch evaluate --model RUN
--traffic FAMILY`` does.

With ``--collect DIR`` nothing is trained: the rows are read from the runs an earlier
``--keep DIR`` kept (``DIR/seed_<seed>/metrics.json``), e.g. to add a field this script now
reports to a table without training again; ``--deploy`` and ``--traffic-eval`` then evaluate
the kept runs' policies as after training.

Run: ``python benchmarks/train_seeds.py [--config NAME] [--seeds 1 2 3] [--switching S]
[--set KEY=VALUE ...] [--import MODULE ...] [--deploy LOGIC] [--parallel N] [--keep DIR |
--collect DIR] [--traffic-eval FAMILY ...] [--out FILE]``; writes
``benchmarks/results/train_seeds_<config>[_<switching>][_deployed_<logic>].json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import _common
from safeswitch.app.evaluate import evaluate
from safeswitch.core.config import ConfigError, with_settings
from safeswitch.core.registry import import_modules
from safeswitch.io import write_json
from safeswitch.training import train
from safeswitch.training.config import EnvTrainConfig, TrainConfig, comparable, load_any_config
from safeswitch.training.policies import load_policy
from safeswitch.training.run import evaluate_trained

RESULTS = Path(__file__).parent / "results"
#: Scenes per traffic family with ``--traffic-eval``.
TRAFFIC_EPISODES = 1000
#: What each evaluation reports (``safeswitch evaluate``'s fields).
EVALUATED = (
    "collisions", "safety_activation_episodes", "comfort_violation_fraction",
    "comfort_violation_episodes", "stops",
    "cut_episodes", "cleared_episodes", "mean_efficiency", "speeding_episodes", "max_speed_kmh",
    "faster_than_oracle_episodes", "faster_than_oracle_speeding", "faster_than_oracle_comfort",
    "faster_than_oracle_either",
)  # fmt: skip
#: What each evaluation of any other plant reports (``safeswitch evaluate --env``'s fields).
PLANT_EVALUATED = (
    "episodes", "failures", "steps", "safety_activation_episodes", "safety_activation_steps",
    "safety_share", "mean_return", "cost_steps", "safety_cost_steps",
)  # fmt: skip


def row(seed: int, metrics: dict[str, object]) -> dict[str, object]:
    """A run's row: the left turn's fields, or any other plant's (its ``metrics.json`` names
    its ``env_id``)."""
    t, e, warm = metrics["training"], metrics["evaluation"], metrics.get("warm_start")
    assert isinstance(t, dict) and isinstance(e, dict)
    selected = (metrics.get("selected") or {}).get("best_timesteps")
    if "env_id" in metrics:
        return {
            "seed": seed,
            "env_id": metrics["env_id"],
            "switching": metrics["switching"],
            "timesteps": metrics["timesteps"],
            "wall_time_s": metrics["wall_time_s"],
            "training_failures": t["failures"],
            "training_safety_steps": t["safety_activation_steps"],
            "training_episodes": t["episodes"],
            "training_steps": t["steps"],
            "constraints": metrics.get("constraints"),
            "selected_timesteps": selected,
            **{k: e.get(k) for k in PLANT_EVALUATED},
        }
    return {
        "seed": seed,
        # a cloning's collisions; a run started from a trained policy records none
        "warm_start_collisions": warm.get("collisions") if isinstance(warm, dict) else None,
        "timesteps": metrics["timesteps"],
        "wall_time_s": metrics["wall_time_s"],
        **_refined(metrics.get("refined")),
        "training_collision_episodes": t["collision_episodes"],
        "training_safety_episodes": t["safety_activation_episodes"],
        "constraints": metrics.get("constraints"),
        "training_episodes": t["episodes"],
        "selected_timesteps": selected,
        **{k: e.get(k) for k in EVALUATED},  # a run kept before a field was added: None
    }


def _refined(record: object) -> dict[str, object]:
    """A run's refinement stage in its row: its wall time (beside PPO's), the iteration it
    selected, which policy the run kept (``ppo``, ``search``, ``finetune``) and the step the
    fine-tune phase selected (nothing for a run without the stage)."""
    if not isinstance(record, dict):
        return {}
    return {
        "refine_wall_time_s": record["wall_time_s"],
        "refine_selected_iteration": record["selected_iteration"],
        "refine_kept": record["kept"],
        "refine_finetune_selected_timesteps": (record.get("finetune") or {}).get(
            "selected_timesteps"
        ),
    }


def one_seed(
    config: TrainConfig | EnvTrainConfig,
    seed: int,
    deploy: str | None,
    keep: Path | None = None,
    families: tuple[str, ...] = (),
    modules: tuple[str, ...] = (),
) -> dict[str, object]:
    """Train ``config`` with ``seed`` (one torch thread) in a temporary run directory (or in
    ``keep/seed_<seed>``) and return its row (with ``deploy``: also evaluated under that
    logic; with ``families``: also on 1,000 scenes of each of those traffic families, as
    ``safeswitch evaluate --model RUN --traffic FAMILY`` does; ``modules`` are imported
    first, in the worker too)."""
    import_modules(modules)
    with tempfile.TemporaryDirectory() as tmp:
        run = keep / f"seed_{seed}" if keep else Path(tmp)
        metrics = train(replace(config, seed=seed, torch_threads=1), run, progress_bar=False)
        result = row(seed, metrics)
        if keep:
            result["run"] = str(run)
        return {**result, **evaluated_further(config, run, deploy, families)}


def evaluated_further(
    config: TrainConfig | EnvTrainConfig, run: Path, deploy: str | None, families: tuple[str, ...]
) -> dict[str, object]:
    """The run's evaluations beyond its own: under ``deploy`` (``deployed``) and on 1,000
    scenes of each traffic family of ``families`` (``traffic``), as ``safeswitch evaluate
    --model RUN [--traffic FAMILY]`` does."""
    result: dict[str, object] = {}
    if deploy:
        assert isinstance(config, TrainConfig)  # main() refuses --deploy on another plant
        deployed = replace(config, deploy_switching=deploy)
        e = evaluate_trained(load_policy(run), deployed, config.eval_episodes,
                             config.eval_seed)  # fmt: skip
        result["deployed"] = {"switching": deploy, **{k: e[k] for k in EVALUATED}}
    if families:
        per_family = {}
        for family in families:
            e = evaluate("learned", str(run), "random", TRAFFIC_EPISODES, config.eval_seed,
                         None, None, traffic=family)  # fmt: skip
            per_family[family] = {k: e[k] for k in (*EVALUATED, "failures", "episodes")}
        result["traffic"] = per_family
    return result


def collected(
    run: Path, seed: int, config: TrainConfig | EnvTrainConfig | None = None
) -> dict[str, object]:
    """The row of a run kept earlier (``--keep``), from its ``metrics.json``.

    Raises:
        SystemExit: the run has no ``metrics.json``, was trained with another seed or (given
            ``config``) with another configuration than ``config`` with that seed.
    """
    path = run / "metrics.json"
    if not path.is_file():
        raise SystemExit(f"--collect: {path} does not exist (a run kept with --keep?)")
    metrics = json.loads(path.read_text(encoding="utf-8"))
    trained = load_any_config(run / "config.yaml")
    if trained.seed != seed:
        raise SystemExit(f"--collect: {run} was not trained with seed {seed}")
    # what --set may change of a kept run: how it is evaluated now, not how it was trained
    evaluation = {"eval_episodes": trained.eval_episodes, "eval_seed": trained.eval_seed}
    # a file a setting names (a go predictor) compares by its contents: the run has its copy
    if config is not None and comparable(trained) != comparable(
        replace(config, seed=seed, **evaluation)
    ):
        raise SystemExit(f"--collect: {run} was trained with another configuration than --config")
    return {**row(seed, metrics), "run": str(run)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="experimental/scratch_annealed_noise")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--switching", help="train (and evaluate) under this logic instead")
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE",
        help="change a setting of the recipe, as safeswitch train --set does (repeatable)",
    )  # fmt: skip
    parser.add_argument(
        "--import", dest="modules", action="append", default=[], metavar="MODULE",
        help="import MODULE first (repeatable): a user's plant, Safety controller or logic",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, help="the JSON file (default under results/)")
    parser.add_argument(
        "--deploy",
        help="also evaluate each run's policy under this logic (e.g. paper for a policy "
        "trained under guarded), on the same scenarios",
    )
    parser.add_argument(
        "--parallel", type=int, default=1,
        help="seeds trained at once, one process and one torch thread each (default 1: the "
        "wall times are then of a run alone on the machine)",
    )  # fmt: skip
    parser.add_argument(
        "--keep", type=Path,
        help="keep each run as KEEP/seed_<seed> (for a campaign: bench_campaign.py --model)",
    )  # fmt: skip
    parser.add_argument(
        "--traffic-eval", nargs="+", default=[], metavar="FAMILY",
        help="a recipe trained in traffic: also evaluate each run on 1,000 scenes of each of "
        "these traffic families (e.g. test light medium heavy)",
    )  # fmt: skip
    parser.add_argument(
        "--collect", type=Path, metavar="DIR",
        help="train nothing: read each seed's row from DIR/seed_<seed>/metrics.json (runs an "
        "earlier --keep DIR kept; with --deploy or --traffic-eval their policies are evaluated "
        "as after training)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    if args.collect and args.keep:
        parser.error("--collect reads kept runs: it trains nothing, so it takes no --keep")
    import_modules(args.modules)
    try:
        config = with_settings(load_any_config(args.config), args.set)
        if isinstance(config, EnvTrainConfig):
            for option, given in (("--deploy", args.deploy), ("--traffic-eval", args.traffic_eval)):
                if given:
                    parser.error(f"{option} is an option of the left turn, not of "
                                 f"{config.env_id} ({args.config!r})")  # fmt: skip
            if args.switching:
                config = replace(config, switching=args.switching)
        else:
            if args.traffic_eval and config.traffic_settings is None:
                parser.error(f"--traffic-eval needs a recipe trained in traffic; "
                             f"{args.config!r} is not")  # fmt: skip
            if args.switching:
                config = replace(config, env=replace(config.env, switching=args.switching),
                                 deploy_switching=None)  # fmt: skip
    except ConfigError as exc:
        parser.error(str(exc))
    if args.collect:
        rows = []
        for seed in args.seeds:
            run = args.collect / f"seed_{seed}"
            kept = collected(run, seed, config)  # refuses a missing or another run first
            rows.append({**kept, **evaluated_further(config, run, args.deploy,
                                                      tuple(args.traffic_eval))})  # fmt: skip
        for one in rows:
            print(json.dumps(one), flush=True)
    else:
        with _common.pool(args.parallel) as pool:
            futures = [
                pool.submit(
                    one_seed,
                    config,
                    seed,
                    args.deploy,
                    args.keep,
                    tuple(args.traffic_eval),
                    tuple(args.modules),
                )
                for seed in args.seeds
            ]
            rows = []
            for future in futures:
                rows.append(future.result())
                print(json.dumps(rows[-1]), flush=True)
    result = {
        "benchmark": "train_seeds",
        **_common.machine(),
        # how the kept runs were trained side by side is not in their metrics: not known here
        "parallel": None if args.collect else args.parallel,
        **({"collected_from": str(args.collect)} if args.collect else {}),
        "config": args.config,
        **({"settings": args.set} if args.set else {}),
        **plant_of(config),
        "runs": rows,
    }
    print(table(rows))
    given = Path(args.config)  # a file: its name; a packaged or experimental name as given
    name = given.stem if given.is_file() else args.config.replace("/", "_")
    suffix = f"_{args.switching}" if args.switching else ""
    suffix += f"_deployed_{args.deploy}" if args.deploy else ""
    out = args.out or RESULTS / f"train_seeds_{name}{suffix}.json"
    write_json(out, result)
    print(f"wrote {out}")
    return 0


def plant_of(config: TrainConfig | EnvTrainConfig) -> dict[str, object]:
    """What the runs trained and were evaluated under, for the results file."""
    if isinstance(config, EnvTrainConfig):
        return {"env_id": config.env_id, "switching": config.switching,
                "evaluated_under": config.switching}  # fmt: skip
    return {"switching": config.env.switching, "evaluated_under": config.deployed_env.switching}


def table(rows: list[dict[str, Any]]) -> str:
    """The rows as one Markdown table, a line per seed (the left turn's columns, or any other
    plant's; a field a kept run did not record: "not recorded")."""
    if rows and "env_id" in rows[0]:
        head = (
            "seed", "training: failures / episodes", "Safety controller, training steps",
            "evaluation: failures / episodes", "Safety controller, evaluation steps",
            "mean return", "costs, evaluation steps (the Safety controller's)", "wall s",
        )  # fmt: skip
        cells = [
            (
                r["seed"],
                f"{r['training_failures']} / {r['training_episodes']}",
                f"{r['training_safety_steps']:,} of {r['training_steps']:,}",
                f"{r['failures']} / {r['episodes']}",
                f"{_v(r['safety_share'], '.2%')} ({r['safety_activation_steps']} of "
                f"{_v(r['steps'], ',')})",
                _v(r["mean_return"], ".1f"),
                _costs(r["cost_steps"], r["safety_cost_steps"]),
                _v(r["wall_time_s"], ".0f"),
            )
            for r in rows
        ]
    else:
        head = (
            "seed", "training collisions", "evaluation collisions", "safety episodes",
            "comfort exceeded, ticks", "above 30 km/h", "cuts", "cleared", "efficiency",
            "faster than the oracle (speeding / comfort)", "wall s",
        )  # fmt: skip
        cells = [
            (
                r["seed"],
                r["training_collision_episodes"],
                _v(r["collisions"]),
                _v(r["safety_activation_episodes"]),
                _v(r["comfort_violation_fraction"], ".3%"),
                _v(r["speeding_episodes"]),
                _v(r["cut_episodes"]),
                _v(r["cleared_episodes"]),
                _v(r["mean_efficiency"], ".3f"),
                f"{_v(r['faster_than_oracle_episodes'])} "
                f"({_v(r['faster_than_oracle_speeding'])} / "
                f"{_v(r['faster_than_oracle_comfort'])})",
                _v(r["wall_time_s"], ".0f"),
            )
            for r in rows
        ]
    lines = [head, ("---",) * len(head), *cells]
    return "\n".join("| " + " | ".join(str(c) for c in line) + " |" for line in lines)


def _v(value: Any, spec: str = "") -> str:
    """``value`` formatted, or "not recorded" (a run kept before the field was reported)."""
    return "not recorded" if value is None else format(value, spec)


def _costs(steps: dict[str, int] | None, driven: dict[str, int] | None) -> str:
    """``name n (m)`` per cost: its steps in the evaluation, ``m`` of them the Safety
    controller's."""
    if steps is None:
        return "not recorded"
    return ", ".join(f"{k} {v} ({(driven or {}).get(k, '?')})" for k, v in sorted(steps.items()))


if __name__ == "__main__":
    sys.exit(main())
