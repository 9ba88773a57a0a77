"""The ``safeswitch`` command line (``safeswitch --help``; also ``python -m safeswitch``)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from safeswitch import __version__

#: The configuration ``safeswitch train`` uses without ``--config``: the paper's recipe.
DEFAULT_CONFIG = "paper_scratch"
LEFT_TURN = "safeswitch/LeftTurn-v0"


class UsageError(ValueError):
    """A combination of options that cannot work; the message says which."""


def _errors() -> tuple[type[BaseException], ...]:
    """What a command reports as one line and exit code 2 (imported lazily: the heavy
    modules load only for the command that needs them)."""
    from safeswitch.app.distributed import DistributedError
    from safeswitch.core.config import ConfigError
    from safeswitch.core.switching import SwitchingError
    from safeswitch.io import OutputDirectoryError

    return (
        ConfigError, SwitchingError, OutputDirectoryError, DistributedError, ValueError,
        FileNotFoundError,
    )  # fmt: skip


def _run(command: str, body: Callable[[], int]) -> int:
    try:
        return body()
    except KeyboardInterrupt:
        return 130
    except Exception as exc:
        from safeswitch.training.run import RunDirectoryError

        if isinstance(exc, (*_errors(), RunDirectoryError)):
            print(f"safeswitch {command}: error: {exc}", file=sys.stderr)
            return 2
        raise


def _number(value: Any) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, float):
        return f"{value:,.4g}" if abs(value) < 1e4 else f"{value:,.0f}"
    return str(value)


def print_summary(summary: dict[str, Any]) -> None:
    """A summary as aligned ``name: value`` lines, numbers rounded (``--json`` has them all)."""
    width = max(len(k) for k in summary)
    for key, value in summary.items():
        if isinstance(value, dict):
            print(f"{key:>{width}}:")
            inner = max((len(k) for k in value), default=0)
            for name, v in value.items():
                print(f"{'':>{width}}  {name:>{inner}}: {_number(v)}")
        else:
            print(f"{key:>{width}}: {_number(value)}")


def _train(args: argparse.Namespace) -> int:
    from safeswitch.app.train import train_and_plot

    if args.env not in (None, LEFT_TURN):
        return _train_env(args)
    if args.resume and args.config:
        raise UsageError("--resume continues with the run's own config.yaml; drop --config")
    from safeswitch.training.config import load_config

    config = load_config(args.config or DEFAULT_CONFIG)
    overrides = {
        k: v
        for k, v in (
            ("timesteps", args.timesteps),
            ("n_envs", args.n_envs),
            ("seed", args.seed),
            ("torch_threads", args.torch_threads),
        )
        if v is not None
    }
    env = config.env
    if args.switching is not None:
        env = replace(env, switching=args.switching)
    if args.no_adas_penalty:
        env = replace(env, adas_penalty=False)
    config = replace(config, env=env, **overrides)
    metrics = train_and_plot(
        config, args.out, resume=args.resume, progress_bar=not args.no_progress
    )
    t, e = metrics["training"], metrics["evaluation"]
    print(
        f"trained {metrics['timesteps']:,} steps in {metrics['wall_time_s']:.0f} s "
        f"({metrics['steps_per_s']:,.0f} steps/s); collisions during training: "
        f"{t['collisions']}; safety activations: {t['safety_activation_episodes']} episodes"
    )
    if e.get("episodes"):
        clear = e["mean_time_to_clear_s"]
        print(
            f"evaluation on {e['episodes']} unseen scenarios: collisions {e['collisions']}, "
            f"safety activated in {e['safety_activation_episodes']} episodes, "
            f"full stops {e['stops']}, mean time to clear "
            + (f"{clear:.2f} s" if clear is not None else "– (never cleared)")
        )
    print(f"run directory: {args.out}")
    return 0


def _train_env(args: argparse.Namespace) -> int:
    from safeswitch.training.config import EnvTrainConfig, load_env_config
    from safeswitch.training.generic import train_env

    if args.no_adas_penalty:
        raise UsageError("--no-adas-penalty is for the left turn; set penalty: 0 in a config")
    base = load_env_config(args.config) if args.config else EnvTrainConfig(env_id=args.env)
    overrides = {
        k: v
        for k, v in (
            ("env_id", args.env),
            ("switching", args.switching),
            ("timesteps", args.timesteps),
            ("n_envs", args.n_envs),
            ("seed", args.seed),
            ("torch_threads", args.torch_threads),
        )
        if v is not None
    }
    config = replace(base, **overrides)
    metrics = train_env(config, args.out, resume=args.resume, progress_bar=not args.no_progress)
    t = metrics["training"]
    print(
        f"trained {metrics['timesteps']:,} steps on {config.env_id} in "
        f"{metrics['wall_time_s']:.0f} s; collisions during training: {t['collisions']} in "
        f"{t['episodes']:,} episodes; safety activations: {t['safety_activation_steps']:,} steps"
    )
    print(f"run directory: {args.out}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    if args.env not in (None, LEFT_TURN):
        summary = _evaluate_env(args)
    else:
        from safeswitch.app.evaluate import evaluate

        summary = evaluate(
            args.controller,
            args.model,
            args.scenarios,
            args.episodes,
            args.seed,
            args.switching,
            args.out,
            overwrite=args.overwrite,
            progress=not (args.no_progress or args.json),
            traffic=args.traffic,
            sim=args.sim,
        )
    if args.json:
        from safeswitch.io import to_json

        sys.stdout.write(to_json(summary))
    else:
        print_summary(summary)
    return 0


def _evaluate_env(args: argparse.Namespace) -> dict[str, Any]:
    from safeswitch.io import prepare_output_dir, write_json
    from safeswitch.training.generic import make_supervised_env, run_episodes
    from safeswitch.training.policies import load_policy

    if args.controller != "learned" or args.model is None:
        raise UsageError(f"--env {args.env} evaluates a trained policy: pass --model RUN")
    policy = load_policy(args.model)
    folder = prepare_output_dir(args.out, args.overwrite) if args.out else None
    env_config = policy.config
    switching = args.switching or getattr(env_config, "switching", None)
    env = make_supervised_env(
        args.env, switching, getattr(env_config, "penalty", None),
        **getattr(env_config, "env_kwargs", {}),
    )  # fmt: skip
    summary = {
        "env_id": args.env,
        "model": str(args.model),
        "switching": switching,
        "seed": args.seed,
        **run_episodes(env, policy.act_one, args.episodes, args.seed),
    }
    env.close()
    if folder is not None:
        write_json(folder / "summary.json", summary)
    return summary


def _bench(args: argparse.Namespace) -> int:
    from safeswitch.bench import quick_bench

    figures = quick_bench(args.seconds)
    if args.json:
        print(json.dumps(figures))
    else:
        for key, value in figures.items():
            print(f"{key:>38}: {value:,.0f}")
        print("(one core; benchmarks/ has the full scripts behind the README's figures)")
    return 0


def _reproduce(args: argparse.Namespace) -> int:
    from safeswitch.app.reproduce import reproduce

    if args.episodes < 1:
        raise UsageError(f"--episodes must be >= 1, got {args.episodes}")
    if args.timesteps is not None and args.timesteps < 1:
        raise UsageError(f"--timesteps must be >= 1, got {args.timesteps}")
    if args.quick and args.timesteps is not None:
        raise UsageError("--timesteps sets the training budget; --quick trains nothing")
    reproduce(
        args.out,
        quick=args.quick,
        episodes=args.episodes,
        timesteps=args.timesteps,
        overwrite=args.overwrite,
    )
    return 0


def _render(args: argparse.Namespace) -> int:
    from safeswitch.app.render import render

    path = render(
        args.controller,
        args.model,
        args.scenario,
        args.seed,
        args.switching,
        args.out,
        overwrite=args.overwrite,
        traffic=args.traffic,
    )
    print(f"wrote {path}")
    return 0


def _cells(args: argparse.Namespace) -> list[Any]:
    """The campaign's cells: every ``--controller`` × ``--model`` (learned only) ×
    ``--switching`` (``None``: each controller's own logic)."""
    from safeswitch.app.campaign import Cell

    models = args.model or [None]
    switchings = args.switching or [None]
    cells = []
    for controller in args.controller:
        for model in models if controller == "learned" else [None]:
            if controller == "learned" and model is None:
                raise UsageError("--controller learned needs --model")
            for switching in switchings:
                cells.append(Cell(controller, model, switching))
    return cells


def _campaign(args: argparse.Namespace) -> int:
    from safeswitch.app.campaign import Grid, Space, campaign

    if args.scenarios == "grid":
        grid = Grid.parse(args.grid or [])
        space = Space("grid", grid.size, args.seed, grid)
    elif args.grid:
        raise UsageError("--grid needs --scenarios grid")
    elif args.scenarios == "paper":
        space = Space("paper", 3, args.seed)
    else:
        if args.episodes < 1:
            raise UsageError(f"--episodes must be >= 1, got {args.episodes}")
        space = Space("random", args.episodes, args.seed)
    quiet = args.no_progress or args.json
    result = campaign(
        _cells(args), space, args.out, workers=args.workers, address=args.address,
        resume=args.resume, shard_size=args.shard_size, progress=not quiet,
    )  # fmt: skip
    if args.json:
        from safeswitch.io import to_json

        sys.stdout.write(to_json(result.summary))
    else:
        for key, cell in result.summary["cells"].items():
            print(f"{key}:")
            print_summary({k: v for k, v in cell.items() if k not in ("controller", "model")})
    for failure in result.failures:
        print(
            f"safeswitch campaign: shard {failure.shard} of {failure.cell} (episodes "
            f"{failure.episodes[0]}–{failure.episodes[1]}, seed {failure.seed}) failed: "
            f"{failure.error}",
            file=sys.stderr,
        )
    return 1 if result.failures else 0


def _sweep(args: argparse.Namespace) -> int:
    from safeswitch.app.sweep import sweep

    summary = sweep(
        args.config, args.seeds, args.set or [], args.out, workers=args.workers,
        address=args.address, timesteps=args.timesteps,
    )  # fmt: skip
    from safeswitch.app.sweep import table

    print(table(summary))
    return 1 if any("error" in r for r in summary["runs"].values()) else 0


def _falsify(args: argparse.Namespace) -> int:
    from safeswitch.app.falsify import Target, falsify

    summary = falsify(
        Target(args.controller, args.model, args.switching), args.out, budget=args.budget,
        generation=args.generation, seed=args.seed, failure=args.failure, workers=args.workers,
        address=args.address, overwrite=args.overwrite, progress=not args.no_progress,
    )  # fmt: skip
    for method, m in summary["methods"].items():
        print(
            f"{method:>14}: {m['failures']:,} {summary['failure']} failures in {m['episodes']:,} "
            f"episodes ({m['failures_per_1000']:.2f} per 1,000); smallest separation "
            f"{m['min_separation_m']:.3f} m"
        )
    ratio = summary["search_over_random"]
    print("search / random: " + (f"{ratio:.1f}×" if ratio is not None else "random found none"))
    print(f"folder: {args.out}")
    return 0


def _distributed(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--workers", type=int, default=2,
        help="CPUs of a local Ray cluster started for this run (0: no Ray, one process)",
    )  # fmt: skip
    parser.add_argument(
        "--address", help="join an existing Ray cluster at host:port instead of a local one"
    )


def build_parser() -> argparse.ArgumentParser:
    from safeswitch.core.registry import logic_names

    logics = logic_names()
    parser = argparse.ArgumentParser(
        prog="safeswitch",
        description="Safe reinforcement learning with a rule-based Safety controller, a learned "
        "controller and a switching logic (Aksjonov & Kyrki), on an embedded simulator.",
    )
    parser.add_argument("--version", action="version", version=f"safeswitch {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    train = sub.add_parser("train", help="train a PPO policy with the switching logic in the loop")
    train.add_argument(
        "--config",
        help=f"a YAML file, or a packaged configuration by name (default: {DEFAULT_CONFIG}, the "
        "paper's recipe; see safeswitch/configs/)",
    )
    train.add_argument(
        "--env",
        help=f"a Gymnasium id (default {LEFT_TURN}); others train through SafeSwitch",
    )
    train.add_argument("--timesteps", type=int, help="environment steps (default: the config's)")
    train.add_argument("--n-envs", type=int, help="environments stepped as one batch")
    train.add_argument("--switching", choices=logics, help="a registered switching logic")
    train.add_argument(
        "--no-adas-penalty",
        action="store_true",
        help="leave R_ADAS out of the reward (the paper's ablation)",
    )
    train.add_argument("--seed", type=int, help="seed of PPO and of the training scenarios")
    train.add_argument("--torch-threads", type=int, help="CPU threads for torch")
    train.add_argument("--out", required=True, help="run directory")
    train.add_argument(
        "--resume",
        action="store_true",
        help="continue the interrupted run in --out from its last checkpoint",
    )
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.set_defaults(func=_train)

    ev = sub.add_parser("evaluate", help="evaluate a controller on the paper's or random scenarios")
    ev.add_argument(
        "--model",
        help="a run directory, one of its checkpoints (run/checkpoints/step_…), or a shipped "
        "policy: shipped (the paper policy), paper, paper-scratch, no-adas, certified, none, "
        "traffic-paper, traffic-certified (in traffic)",
    )
    ev.add_argument(
        "--controller",
        choices=("learned", "rule", "planner", "gap_planner", "oracle"),
        default="learned",
        help="learned: a trained policy (--model); rule: PID_th under the paper switching logic; "
        "planner: a throttle-only rule-based planner that avoids the paper logic's braking; "
        "gap_planner: in traffic (--traffic), waits for a gap the certified filter accepts; "
        "oracle: the minimum-time crossing planned with knowledge of the north car",
    )
    ev.add_argument("--env", help=f"a Gymnasium id (default {LEFT_TURN})")
    ev.add_argument("--scenarios", choices=("paper", "random"), default="random")
    ev.add_argument("--episodes", type=int, default=1000, help="random scenarios (default 1000)")
    ev.add_argument("--seed", type=int, default=0, help="seed of the random scenarios")
    ev.add_argument(
        "--switching", choices=logics, help="override the switching logic it was trained with"
    )
    ev.add_argument(
        "--traffic",
        help="traffic from every leg: a preset (light, medium, heavy, train, test) or none "
        "(default: what the policy was trained in; none for the baselines)",
    )
    ev.add_argument(
        "--sim",
        choices=("embedded", "sumo"),
        default="embedded",
        help="the simulator: ours (batched), or SUMO driving the north car (extra "
        "safeswitch[sumo]; one episode after another)",
    )
    ev.add_argument("--out", help="folder for episodes.csv and summary.json")
    ev.add_argument("--overwrite", action="store_true", help="replace files in a non-empty --out")
    ev.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ev.add_argument("--no-progress", action="store_true", help="no progress bar or lines")
    ev.set_defaults(func=_evaluate)

    render = sub.add_parser("render", help="animate one episode of a controller as a GIF")
    render.add_argument("--model", help="a trained policy (as for evaluate)")
    render.add_argument(
        "--controller", choices=("learned", "rule", "planner", "gap_planner"), default="learned"
    )
    render.add_argument(
        "--scenario",
        default="cut",
        help="cut, yield1, yield2 (the paper's) or random:K (random scenario K of --seed)",
    )
    render.add_argument("--seed", type=int, default=0, help="seed of random:K scenarios")
    render.add_argument("--switching", choices=logics, help="override the switching logic")
    render.add_argument("--traffic", help="a traffic preset or none (as for evaluate)")
    render.add_argument("--out", required=True, help="the GIF to write (e.g. episode.gif)")
    render.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    render.set_defaults(func=_render)

    camp = sub.add_parser(
        "campaign", help="an evaluation campaign in shards on Ray (local or a cluster)"
    )
    camp.add_argument(
        "--controller", nargs="+", default=["learned"],
        choices=("learned", "rule", "planner", "oracle"), help="one or more controllers",
    )  # fmt: skip
    camp.add_argument("--model", nargs="+", help="trained policies (for --controller learned)")
    camp.add_argument("--switching", nargs="+", choices=logics, help="logics (default: each's own)")
    camp.add_argument("--scenarios", choices=("random", "grid", "paper"), default="random")
    camp.add_argument("--episodes", type=int, default=100_000, help="random scenarios")
    camp.add_argument("--seed", type=int, default=0, help="seed of the random scenarios")
    camp.add_argument(
        "--grid", nargs="+", metavar="NAME=SPEC",
        help="grid axes: arrival_offset_s=-3:5:0.25 north_speed_kmh=20,26,32 "
        "ego_speed_kmh=18:25:1 ego_start_distance_m=36 (stop included)",
    )  # fmt: skip
    camp.add_argument("--shard-size", type=int, default=10_000, help="episodes per Ray task")
    camp.add_argument("--out", required=True, help="campaign folder")
    camp.add_argument("--resume", action="store_true", help="skip the shards already done")
    camp.add_argument("--json", action="store_true", help="print the summary as JSON")
    camp.add_argument("--no-progress", action="store_true", help="no progress bar or lines")
    _distributed(camp)
    camp.set_defaults(func=_campaign)

    swp = sub.add_parser("sweep", help="train several seeds or settings of a config on Ray")
    swp.add_argument("--config", default=DEFAULT_CONFIG, help="a configuration (name or file)")
    swp.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    swp.add_argument(
        "--set", nargs="+", metavar="KEY=V1,V2", help="vary a key, e.g. ppo.gamma=0.99,0.995"
    )
    swp.add_argument("--timesteps", type=int, help="override the config's training steps")
    swp.add_argument("--out", required=True, help="folder of the runs")
    _distributed(swp)
    swp.set_defaults(func=_sweep)

    fal = sub.add_parser(
        "falsify", help="search the scenario space for failures (cross-entropy, on Ray)"
    )
    fal.add_argument(
        "--controller", default="rule",
        help="rule, planner, learned (with --model) or adversary:NAME (e.g. adversary:creep)",
    )  # fmt: skip
    fal.add_argument("--model", help="a trained policy (for --controller learned)")
    fal.add_argument("--switching", choices=logics, help="the logic (default: the controller's)")
    fal.add_argument("--failure", choices=("collision", "safety"), default="collision")
    fal.add_argument("--budget", type=int, default=20_000, help="episodes per method")
    fal.add_argument("--generation", type=int, default=500, help="episodes per generation")
    fal.add_argument("--seed", type=int, default=0)
    fal.add_argument("--out", required=True, help="output folder")
    fal.add_argument("--overwrite", action="store_true", help="replace files in a used --out")
    fal.add_argument("--no-progress", action="store_true", help="no progress bar or lines")
    _distributed(fal)
    fal.set_defaults(func=_falsify)

    bench = sub.add_parser("bench", help="throughput figures of the simulator and environments")
    bench.add_argument("--json", action="store_true", help="print one JSON object")
    bench.add_argument("--seconds", type=float, default=0.5, help="timing per figure")
    bench.set_defaults(func=_bench)

    rep = sub.add_parser(
        "reproduce",
        help="the paper's experiments end to end: figures, comparison table, report.html",
    )
    rep.add_argument(
        "--quick",
        action="store_true",
        help="use the shipped policies (about a minute) instead of training all six first",
    )
    rep.add_argument("--out", default="out/report", help="report folder (default: out/report)")
    rep.add_argument("--episodes", type=int, default=1000, help="random evaluation scenarios")
    rep.add_argument(
        "--timesteps",
        type=int,
        help="PPO steps per policy without --quick (default: each config's 1.2 M); a "
        "configuration's warm start keeps its own size",
    )
    rep.add_argument("--overwrite", action="store_true", help="replace an existing report")
    rep.set_defaults(func=_reproduce)

    demo = sub.add_parser("demo", help="the same as reproduce --quick (the README's make demo)")
    demo.add_argument("--out", default="out/demo", help="report folder (default: out/demo)")
    demo.set_defaults(func=_reproduce, quick=True, episodes=1000, timesteps=None, overwrite=True)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    return _run(args.command, lambda: int(args.func(args)))


if __name__ == "__main__":
    sys.exit(main())
