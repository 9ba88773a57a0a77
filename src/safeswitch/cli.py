"""The ``safeswitch`` command line."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace


def _train(args: argparse.Namespace) -> int:
    from safeswitch.app.train import train_and_plot
    from safeswitch.core.config import ConfigError
    from safeswitch.training.config import TrainConfig, load_config
    from safeswitch.training.run import RunDirectoryError

    try:
        config = load_config(args.config) if args.config else TrainConfig()
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
    except (ConfigError, RunDirectoryError, FileNotFoundError) as exc:
        print(f"safeswitch train: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    t, e = metrics["training"], metrics["evaluation"]
    print(
        f"trained {metrics['timesteps']:,} steps in {metrics['wall_time_s']:.0f} s "
        f"({metrics['steps_per_s']:,.0f} steps/s); collisions during training: "
        f"{t['collisions']}; safety activations: {t['safety_activation_episodes']} episodes"
    )
    if e.get("episodes"):
        print(
            f"evaluation on {e['episodes']} unseen scenarios: collisions {e['collisions']}, "
            f"safety activated in {e['safety_activation_episodes']} episodes, "
            f"full stops {e['stops']}, mean time to clear {e['mean_time_to_clear_s']:.2f} s"
        )
    print(f"run directory: {args.out}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from safeswitch.app.evaluate import evaluate
    from safeswitch.core.config import ConfigError

    try:
        summary = evaluate(
            args.controller,
            args.model,
            args.scenarios,
            args.episodes,
            args.seed,
            args.switching,
            args.out,
        )
    except (ConfigError, ValueError, FileNotFoundError) as exc:
        print(f"safeswitch evaluate: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(summary))
    else:
        for key, value in summary.items():
            print(f"{key:>28}: {value}")
    return 0


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
        print(
            f"safeswitch reproduce: error: --episodes must be >= 1, got {args.episodes}",
            file=sys.stderr,
        )
        return 2
    if args.timesteps is not None and args.timesteps < 1:
        print(
            f"safeswitch reproduce: error: --timesteps must be >= 1, got {args.timesteps}",
            file=sys.stderr,
        )
        return 2
    reproduce(args.out, quick=args.quick, episodes=args.episodes, timesteps=args.timesteps)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="safeswitch",
        description="Safe reinforcement learning with a rule-based Safety controller, a learned "
        "controller and a switching logic (Aksjonov & Kyrki), on an embedded simulator.",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    train = sub.add_parser("train", help="train a PPO policy with the switching logic in the loop")
    train.add_argument("--config", help="YAML training configuration (see configs/)")
    train.add_argument("--timesteps", type=int, help="environment ticks (default 1,200,000)")
    train.add_argument("--n-envs", type=int, help="environments stepped as one batch")
    train.add_argument("--switching", choices=("paper", "certified", "none"))
    train.add_argument(
        "--no-adas-penalty",
        action="store_true",
        help="leave R_ADAS out of the reward (the paper's ablation)",
    )
    train.add_argument("--seed", type=int, help="seed of PPO and of the training scenarios")
    train.add_argument("--torch-threads", type=int, help="CPU threads for torch (default 2)")
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
        help="run directory, or a shipped policy: shipped (the paper "
        "policy), paper, paper-scratch, no-adas, certified, none",
    )
    ev.add_argument(
        "--controller",
        choices=("learned", "rule", "planner", "oracle"),
        default="learned",
        help="learned: a trained policy (--model); rule: PID_th under the paper switching logic; "
        "planner: a throttle-only rule-based planner that avoids the paper logic's braking; "
        "oracle: the minimum-time crossing planned with knowledge of the north car",
    )
    ev.add_argument("--scenarios", choices=("paper", "random"), default="random")
    ev.add_argument("--episodes", type=int, default=1000, help="random scenarios")
    ev.add_argument("--seed", type=int, default=0, help="seed of the random scenarios")
    ev.add_argument(
        "--switching",
        choices=("paper", "certified", "none"),
        help="override the switching logic the policy was trained with",
    )
    ev.add_argument("--out", help="folder for episodes.csv and summary.json")
    ev.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ev.set_defaults(func=_evaluate)

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
        help="use the shipped policies (under 2 minutes) instead of training all five first",
    )
    rep.add_argument("--out", default="out/report", help="report folder (default: out/report)")
    rep.add_argument("--episodes", type=int, default=1000, help="random evaluation scenarios")
    rep.add_argument(
        "--timesteps", type=int, help="training steps per policy without --quick (default 1.2 M)"
    )
    rep.set_defaults(func=_reproduce)

    demo = sub.add_parser("demo", help="the same as reproduce --quick (the README's make demo)")
    demo.add_argument("--out", default="out/demo", help="report folder (default: out/demo)")
    demo.set_defaults(func=_reproduce, quick=True, episodes=1000, timesteps=None)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
