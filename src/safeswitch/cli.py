"""The ``safeswitch`` command line (``safeswitch --help``; also ``python -m safeswitch``)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from dataclasses import replace
from importlib import import_module
from pathlib import Path
from typing import Any, NoReturn

from safeswitch import __version__

#: The configuration ``safeswitch train`` uses without ``--config`` (kept in step with
#: :data:`safeswitch.training.config.DEFAULT_CONFIG`, which importing here would load numba).
DEFAULT_CONFIG = "paper_scratch"
LEFT_TURN = "safeswitch/LeftTurn-v0"


class UsageError(ValueError):
    """A combination of options that cannot work; the message says which."""


#: The largest seed (NumPy's legacy seeding, which SB3 uses, takes 32 bits).
SEED_MAX = 2**32 - 1


def seed_value(text: str) -> int:
    """An argparse type: a seed, an integer in ``[0, 2**32 - 1]`` (every command takes the same;
    a negative seed would otherwise be wrapped modulo 2**64 by one command and refused by
    another)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 0 <= value <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"{value} is not in [0, 2**32 - 1]")
    return value


def at_least(low: int) -> Callable[[str], int]:
    """An argparse type: an integer no smaller than ``low`` (checked before anything runs)."""

    def value(text: str) -> int:
        try:
            number = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if number < low:
            raise argparse.ArgumentTypeError(f"must be >= {low}, got {number}")
        return number

    value.__name__ = f"integer >= {low}"
    return value


def penalty_value(text: str) -> float:
    """An argparse type: a finite reward <= 0 (a bonus for needing the Safety controller would
    teach the policy to need it)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (value <= 0 and value > -float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number <= 0, got {text}")
    return value


def imported_modules(argv: list[str]) -> list[tuple[str, str]]:
    """``(option, module)`` for each module named by ``--import MODULE`` (or
    ``--import=MODULE``), by ``--env MODULE:EnvId`` and by the ``env_id: MODULE:EnvId`` of a
    ``--config`` file anywhere in ``argv``: imported before the parser is built, so that what
    they register (environments, Safety controllers, switching logics) is known to ``--env``
    and ``--switching``."""
    names: list[tuple[str, str]] = []
    for i, flag in enumerate(argv):
        value = argv[i + 1] if i + 1 < len(argv) else ""
        for option in ("--import", "--env", "--config"):
            if flag.startswith(option + "="):
                flag, value = option, flag.removeprefix(option + "=")
        if flag == "--config":  # a configuration file's env_id: MODULE:EnvId
            value = _env_id_of(Path(value))
        if flag == "--import" and value:
            names.append((flag, value))
        elif flag in ("--env", "--config") and ":" in value:
            names.append((flag, value.partition(":")[0]))
    return names


def _env_id_of(path: Path) -> str:
    """The ``env_id`` a configuration file names (``""`` if it is not a readable file naming
    one: whatever is wrong with it is reported where the file is loaded)."""
    if not path.is_file():
        return ""
    import yaml

    from safeswitch.core.config import ConfigError
    from safeswitch.training.config import read_config

    try:
        env_id = read_config(path).get("env_id", "")
    except (ConfigError, OSError, yaml.YAMLError, AttributeError):
        return ""  # reported, with the file's name, where the configuration is loaded
    return env_id if isinstance(env_id, str) else ""


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (``safeswitch train: error: …``, exit 2),
    like every other error of the command line, instead of the usage block and the error."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


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
        if isinstance(value, dict) and all(isinstance(v, int | float) for v in value.values()):
            counts = ", ".join(f"{name} {_number(v)}" for name, v in value.items())
            print(f"{key:>{width}}: {counts or '—'}")  # a count per name, on one line
        elif isinstance(value, dict):
            print(f"{key:>{width}}:")
            inner = max((len(k) for k in value), default=0)
            for name, v in value.items():
                print(f"{'':>{width}}  {name:>{inner}}: {_number(v)}")
        else:
            print(f"{key:>{width}}: {_number(value)}")


def _training_counts(training: dict[str, Any]) -> str:
    """What training met, for the train command's summary line; a count over no finished
    episode is never printed as 0."""
    episodes = int(training.get("episodes", 0))
    if episodes == 0:
        return "no training episode finished (no collision or safety counts to report)"
    steps = training.get("safety_activation_steps")
    per_episode = training.get("safety_activation_episodes")
    safety = f"{per_episode:,} episodes" if per_episode is not None else f"{steps:,} steps"
    if "failures" in training and "collisions" not in training:  # any plant: what it declares
        met = f"{training['failures']:,} failures"
    else:
        met = f"{training['collisions']:,} collisions"
    return f"{met} in {episodes:,} training episodes; safety activations: {safety}"


def _names_env(config: str | None) -> bool:
    """The configuration ``config`` is one for a Gymnasium environment (it names ``env_id``;
    a path that does not exist names none)."""
    if config is None or (config.endswith("config.yaml") and not Path(config).is_file()):
        return False
    from safeswitch.training.config import config_path, read_config

    return "env_id" in read_config(config_path(config))


def _resume_takes_no_changes(args: argparse.Namespace) -> None:
    """``--resume`` continues with the run's own configuration: a file or settings given with it
    would be silently ignored."""
    if args.resume and args.config:
        raise UsageError("--resume continues with the run's own config.yaml; drop --config")
    if args.resume and args.set:
        raise UsageError("--resume continues with the run's own config.yaml; drop --set")


def _train(args: argparse.Namespace) -> int:
    from safeswitch.app.train import train_and_plot

    resumed = f"{args.out}/config.yaml" if args.resume and args.config is None else None
    if args.env not in (None, LEFT_TURN) or (
        args.env is None and _names_env(args.config or resumed)
    ):
        return _train_env(args)
    _resume_takes_no_changes(args)
    from safeswitch.core.config import with_settings
    from safeswitch.training.config import load_config

    config = with_settings(load_config(args.config or DEFAULT_CONFIG), args.set or [])
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
    if args.penalty is not None:
        env = replace(env, rewards=replace(env.rewards, adas_penalty=args.penalty))
    if args.no_adas_penalty:
        env = replace(env, adas_penalty=False)
    config = replace(config, env=env, **overrides)
    metrics = train_and_plot(
        config, args.out, resume=args.resume, progress_bar=not args.no_progress
    )
    t, e = metrics["training"], metrics["evaluation"]
    print(
        f"trained {metrics['timesteps']:,} steps in {metrics['wall_time_s']:.0f} s "
        f"({metrics['steps_per_s']:,.0f} steps/s); " + _training_counts(t)
    )
    refined = metrics.get("refined")
    if refined:
        chosen, of = refined["selected_iteration"], refined["iterations"]
        tuned = refined.get("finetune")
        if tuned is not None:
            what = (
                f"iteration {chosen} of {of} fine-tuned by PPO "
                f"(selected at {tuned['selected_timesteps']:,} steps), "
                + ("kept" if refined["kept"] == "finetune" else "not better than PPO's")
            )
        elif chosen:
            what = f"iteration {chosen} of {of} selected"
        else:
            what = f"none of {of} iterations beat PPO's policy"
        print(f"refined in {refined['wall_time_s']:.0f} s: {what} (refine.csv)")
    if e.get("episodes"):
        from safeswitch.evaluation.verdict import headline

        print(f"evaluation on {e['episodes']:,} unseen scenarios (full stops {e['stops']:,}):")
        for line in headline(e):
            print(f"  {line}")
    print(f"run directory: {args.out}")
    return 0


def _train_env(args: argparse.Namespace) -> int:
    from safeswitch.app.train import train_and_plot
    from safeswitch.core.config import with_settings
    from safeswitch.training.config import EnvTrainConfig, load_env_config

    if args.no_adas_penalty:
        raise UsageError("--no-adas-penalty is for the left turn; set penalty: 0 in a config")
    _resume_takes_no_changes(args)
    if args.resume:  # the run's own configuration (train reads it again)
        base = load_env_config(Path(args.out) / "config.yaml")
    else:
        base = load_env_config(args.config) if args.config else EnvTrainConfig(env_id=args.env)
        base = with_settings(base, args.set or [])
    overrides = {
        k: v
        for k, v in (
            ("env_id", args.env),
            ("switching", args.switching),
            ("penalty", args.penalty),
            ("timesteps", args.timesteps),
            ("n_envs", args.n_envs),
            ("seed", args.seed),
            ("torch_threads", args.torch_threads),
        )
        if v is not None
    }
    config = replace(base, **overrides)
    metrics = train_and_plot(
        config, args.out, resume=args.resume, progress_bar=not args.no_progress
    )
    t = metrics["training"]
    print(
        f"trained {metrics['timesteps']:,} steps on {config.env_id} in "
        f"{metrics['wall_time_s']:.0f} s; " + _training_counts(t)
    )
    print(f"run directory: {args.out}")
    return 0


#: ``evaluate``'s defaults of the options that have a default only where they apply (``None``
#: in the parser, so that an option given where it does not apply can be refused).
EVALUATE_DEFAULTS = {"controller": "learned", "scenarios": "random", "episodes": 1000,
                     "sim": "embedded"}  # fmt: skip


def _evaluate_options(args: argparse.Namespace) -> None:
    """Refuse every option that would be silently ignored, then fill in the defaults."""
    given = {k for k in EVALUATE_DEFAULTS if getattr(args, k) is not None}
    if args.env not in (None, LEFT_TURN):
        for option in ("scenarios", "sim"):
            if option in given:
                raise UsageError(
                    f"--{option} is an option of the left turn; --env {args.env} runs its own "
                    "episodes (--episodes, --seed)"
                )
        if args.traffic is not None:
            raise UsageError(f"--traffic is an option of the left turn, not of --env {args.env}")
        if args.set:
            raise UsageError(
                f"--set changes the left turn's scene; --env {args.env} is evaluated as its "
                "run was trained"
            )
    controller = args.controller or EVALUATE_DEFAULTS["controller"]
    if controller == "oracle" and args.switching is not None:
        raise UsageError(
            "--switching does not apply to --controller oracle: the oracle plans the "
            "minimum-time crossing with full knowledge, under no switching logic"
        )
    if args.scenarios == "paper" and "episodes" in given:
        raise UsageError(
            "--episodes counts random scenarios; --scenarios paper runs the paper's three "
            "(cut, yield1, yield2)"
        )
    if args.scenarios is not None and args.scenarios.startswith("openscenario:"):
        for option in ("episodes", "traffic"):
            if getattr(args, option) is not None:
                raise UsageError(
                    f"--{option} does not apply to --scenarios openscenario:PATH: the files "
                    "say which scenarios (the paper's scene)"
                )
    for key, value in EVALUATE_DEFAULTS.items():
        if getattr(args, key) is None:
            setattr(args, key, value)


def _evaluate(args: argparse.Namespace) -> int:
    _evaluate_options(args)
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
            progress=not args.no_progress,
            traffic=args.traffic,
            sim=args.sim,
            settings=args.set or (),
        )
    _note_missing_targets(args.model)
    if args.json:
        from safeswitch.io import to_json

        sys.stdout.write(to_json(summary))
    else:
        print_left_turn_summary(summary)
    return 0


def _note_missing_targets(model: str | None) -> None:
    """Say on stderr when a shipped policy evaluated is known to miss its targets."""
    from safeswitch.training.shipped import missing_targets

    why = missing_targets(model)
    if why is not None:
        print(f"note: the shipped policy {model!r} misses its targets: {why}", file=sys.stderr)


def print_left_turn_summary(summary: dict[str, Any]) -> None:
    """A left-turn summary for a person: the headline (failures, safety action, speeding,
    comfort, efficiency, cut + yield = cleared, each marked ✔/✘) and then every field."""
    if "speeding_episodes" in summary and summary.get("episodes"):
        from safeswitch.evaluation.verdict import headline

        for line in headline(summary):
            print(line)
        print()
    print_summary(summary)


def _evaluate_env(args: argparse.Namespace) -> dict[str, Any]:
    from safeswitch.core.registry import failure_of, plain_env_id
    from safeswitch.io import prepare_output_dir, write_json
    from safeswitch.training.config import EnvTrainConfig
    from safeswitch.training.generic import make_supervised_env, run_episodes
    from safeswitch.training.policies import check_fits, load_policy, trained_env_id

    if args.controller != "learned" or args.model is None:
        raise UsageError(f"--env {args.env} evaluates a trained policy: pass --model RUN")
    policy = load_policy(args.model)
    trained_on = trained_env_id(policy)
    if plain_env_id(trained_on) != plain_env_id(args.env):
        raise UsageError(
            f"the policy in {policy.path} was trained on {trained_on}, not {args.env}"
            + ("; evaluate it without --env" if not isinstance(policy.config, EnvTrainConfig)
               else f"; evaluate it with --env {trained_on}")
        )  # fmt: skip
    env_config = policy.config
    switching = args.switching or getattr(env_config, "switching", None)
    env = make_supervised_env(
        args.env, switching, getattr(env_config, "penalty", None),
        **getattr(env_config, "env_kwargs", {}),
    )  # fmt: skip
    try:
        check_fits(policy, args.env, env.observation_space, env.action_space)
        folder = prepare_output_dir(args.out, args.overwrite) if args.out else None
    except BaseException:
        env.close()
        raise
    summary = {
        "env_id": args.env,
        "model": str(args.model),
        "switching": switching,
        "seed": args.seed,
        **run_episodes(
            env, policy.act_one, args.episodes, args.seed, failure_of(plain_env_id(args.env))
        ),
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
    if args.model and "learned" not in args.controller:
        raise UsageError(
            f"--model is a trained policy for --controller learned; --controller "
            f"{' '.join(args.controller)} uses none (drop --model or add learned)"
        )
    cells = []
    for controller in args.controller:
        for model in models if controller == "learned" else [None]:
            if controller == "learned" and model is None:
                raise UsageError("--controller learned needs --model")
            for switching in switchings:
                cells.append(Cell(controller, model, switching, tuple(args.set or ())))
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
        space = Space("random", args.episodes, args.seed)
    result = campaign(
        _cells(args), space, args.out, workers=args.workers, address=args.address,
        resume=args.resume, shard_size=args.shard_size, progress=not args.no_progress,
    )  # fmt: skip
    for model in args.model or ():
        _note_missing_targets(model)
    if args.json:
        from safeswitch.io import to_json

        sys.stdout.write(to_json(result.summary))
    else:
        for key, cell in result.summary["cells"].items():
            print(f"{key}:")
            print_left_turn_summary(
                {k: v for k, v in cell.items() if k not in ("controller", "model")}
            )
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


def _deploy_module(name: str) -> Any:
    """A module of :mod:`safeswitch.deploy`, or a one-line error naming the extra it needs."""
    try:
        return import_module(f"safeswitch.deploy.{name}")
    except ModuleNotFoundError as exc:
        raise ValueError(
            f"{exc.name} is not installed: the deployment commands need the deploy extra "
            "(pip install 'safeswitch[deploy]')"
        ) from exc


def _adapt(args: argparse.Namespace) -> int:
    from safeswitch.app.adapt import adapt

    summary = adapt(
        args.model, args.out, switching=args.switching, settings=args.set or (),
        episodes=args.episodes, block=args.block, n_envs=args.n_envs, seed=args.seed,
        eval_episodes=args.eval_episodes, noise=args.noise, noise_decay=args.noise_decay,
        rehearsal=args.rehearsal, rollback=args.rollback, settle=args.settle,
        resume=args.resume, progress=not args.no_progress,
    )  # fmt: skip
    last = summary["blocks"][-1]
    for where in ("shifted", "original"):
        frozen, adapted = summary[where]["frozen"], summary[where]["adapted"]
        print(
            f"{where:>8}: safety action in {frozen['safety_activation_episodes']:,} → "
            f"{adapted['safety_activation_episodes']:,} of {adapted['episodes']:,} episodes; "
            f"efficiency {frozen['mean_efficiency']:.3f} → {adapted['mean_efficiency']:.3f}"
        )
    print(
        f"deployed {sum(b['episodes'] for b in summary['blocks']):,} episodes: "
        f"{summary['collisions']:,} collisions, {summary['failures']:,} failures; last block: "
        f"safety action in {last['safety_activation_episodes']:,} of {last['episodes']:,}"
    )
    settled = sum(b["settled"] for b in summary["blocks"])
    if settled:
        print(f"learning paused in {settled} of {len(summary['blocks'])} blocks: the selected "
              "policy met every target, deployed without noise")  # fmt: skip
    chosen = summary["selected_block"]
    which = f"after block {chosen}" if chosen else "the frozen one: no block ranked above it"
    print(f"adapted policy ({which}): {args.out} (safeswitch evaluate --model {args.out})")
    return 0


def _export(args: argparse.Namespace) -> int:
    deploy = _deploy_module("export")
    result = deploy.export(
        args.model, args.out, switching=args.switching, observations=args.observations,
        overwrite=args.overwrite,
    )  # fmt: skip
    print(deploy.main_summary(result))
    return 0


def _export_scenario(args: argparse.Namespace) -> int:
    _deploy_module("openscenario")  # the extra's check
    from safeswitch.app.export_scenario import export_scenarios

    index = export_scenarios(
        args.out, args.scenarios, args.episodes, args.seed, args.controller, args.model,
        args.switching, overwrite=args.overwrite, progress=not args.no_progress,
        traffic=args.traffic,
    )  # fmt: skip
    entries = index["scenarios"]
    collisions = sum(e["collision"] for e in entries)
    print(
        f"wrote {len(entries):,} OpenSCENARIO {index['openscenario']} files (schema-valid) and "
        f"{index['road']} to {args.out}; {collisions:,} of them end in a collision under "
        f"{index['source']['controller']} ({index['source']['switching']} logic)"
    )
    return 0


def _calibrate_perception(args: argparse.Namespace) -> int:
    from safeswitch.app.calibrate import calibrate_perception

    result = calibrate_perception(
        args.out, pairs=args.pairs, sensor=args.simulate, alpha=args.alpha, count=args.count,
        seed=args.seed, holdout=args.holdout, overwrite=args.overwrite,
    )  # fmt: skip
    print(
        f"bounds for 1 - alpha = {1 - args.alpha:g}: position {result.position_error_m:.4g} m, "
        f"speed {result.speed_error_mps:.4g} m/s (from {result.calibration_pairs:,} pairs); "
        f"held-out coverage {result.coverage_position:.4f} / {result.coverage_speed:.4f} "
        f"(both {result.coverage_both:.4f}, {result.holdout_pairs:,} pairs); wrote "
        f"{args.out}/perception.yaml (use it with --perception)"
    )
    return 0


def perception_file(text: str) -> str:
    """``--perception FILE``: a YAML file with a ``perception:`` block (as
    ``calibrate-perception`` writes) or its keys alone, checked now and turned into the setting
    ``env.perception=…`` (it joins ``--set``, in order: a later ``--set`` can change a key)."""
    import json

    import yaml

    from safeswitch.core.config import ConfigError, from_dict, to_dict
    from safeswitch.leftturn.config import PerceptionConfig

    try:
        with open(text, encoding="utf-8") as handle:
            data = yaml.safe_load(handle)
    except (OSError, yaml.YAMLError) as exc:
        raise argparse.ArgumentTypeError(f"cannot read {text}: {exc}") from None
    if isinstance(data, dict) and set(data) == {"perception"}:
        data = data["perception"]
    try:
        block = to_dict(from_dict(PerceptionConfig, data, where="perception"))
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(f"{text}: {exc}") from None
    return "env.perception=" + json.dumps(block)


def _perception(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--perception", dest="set", action="append", type=perception_file, metavar="FILE",
        help="how the ego sees the north car: a YAML perception block (e.g. from "
        "calibrate-perception); the same as --set env.perception.KEY=VALUE for each key",
    )  # fmt: skip


def scenarios_value(text: str) -> str:
    """``--scenarios``: ``paper``, ``random`` or ``openscenario:PATH``."""
    if text in ("paper", "random") or (text.startswith("openscenario:") and len(text) > 13):
        return text
    raise argparse.ArgumentTypeError(
        f"expected paper, random or openscenario:PATH (a .xosc file or a folder), got {text!r}"
    )


def _distributed(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--workers", type=at_least(0), default=2,
        help="CPUs of a local Ray cluster started for this run (0: no Ray, one process)",
    )  # fmt: skip
    parser.add_argument(
        "--address", help="join an existing Ray cluster at host:port instead of a local one"
    )


def build_parser() -> argparse.ArgumentParser:
    from safeswitch.core.registry import logic_names
    from safeswitch.training.shipped import SHIPPED

    logics = logic_names()
    parser = _Parser(
        prog="safeswitch",
        description="Safe reinforcement learning with a rule-based Safety controller, a learned "
        "controller and a switching logic (Aksjonov & Kyrki), on an embedded simulator.",
    )
    parser.add_argument("--version", action="version", version=f"safeswitch {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

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
    train.add_argument(
        "--timesteps", type=at_least(1), help="environment steps (default: the config's)"
    )
    train.add_argument("--n-envs", type=at_least(1), help="environments stepped as one batch")
    train.add_argument("--switching", choices=logics, help="a registered switching logic")
    train.add_argument(
        "--penalty",
        type=penalty_value,
        help="reward on a step the Safety controller acted (<= 0; the paper's R_ADAS: -25)",
    )
    train.add_argument(
        "--no-adas-penalty",
        action="store_true",
        help="leave R_ADAS out of the reward (the paper's ablation)",
    )
    train.add_argument("--seed", type=seed_value, help="seed of PPO and of the training scenarios")
    train.add_argument(
        "--set", action="append", metavar="KEY=VALUE",
        help="change one configuration setting (repeatable): a dotted key and a YAML value, "
        "e.g. env.scenarios.north_speed_kmh=[30,44] or ppo.gamma=0.995; checked like a file",
    )  # fmt: skip
    _perception(train)
    train.add_argument("--torch-threads", type=at_least(1), help="CPU threads for torch")
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
        help="a run directory (or its model.zip), one of its checkpoints "
        "(run/checkpoints/step_…), or a shipped policy: "
        + ", ".join(SHIPPED)
        + " (shipped is the paper policy; traffic-* were trained in traffic; highway-* on "
        "safeswitch/Highway-v0: evaluate them with --env)",
    )
    ev.add_argument(
        "--controller",
        choices=("learned", "rule", "planner", "gap_planner", "oracle"),
        help="learned: a trained policy (--model); rule: PID_th under the paper switching logic; "
        "planner: a throttle-only rule-based planner that avoids the paper logic's braking; "
        "gap_planner: in traffic (--traffic), waits for a gap the certified filter accepts; "
        "oracle: the minimum-time crossing planned with knowledge of the north car",
    )
    ev.add_argument("--env", help=f"a Gymnasium id (default {LEFT_TURN})")
    ev.add_argument(
        "--set", action="append", metavar="KEY=VALUE",
        help="change the scene (repeatable): env.KEY=VALUE with a dotted key of the left "
        "turn's configuration and a YAML value, e.g. env.scenarios.north_speed_kmh=[30,44]; "
        "gap_planner.KEY=VALUE tunes --controller gap_planner, e.g. gap_planner.approach=brake",
    )  # fmt: skip
    _perception(ev)
    ev.add_argument(
        "--scenarios", type=scenarios_value, metavar="{paper,random,openscenario:PATH}",
        help="the paper's three (cut, yield1, yield2), random ones (default), or the scenarios "
        "of OpenSCENARIO files written by export-scenario (a .xosc file or a folder)",
    )  # fmt: skip
    ev.add_argument("--episodes", type=at_least(1), help="random scenarios (default 1000)")
    ev.add_argument("--seed", type=seed_value, default=0, help="seed of the random scenarios")
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
        help="the simulator: ours (batched), or SUMO driving the north car (extra "
        "safeswitch[sumo]; one episode after another)",
    )
    ev.add_argument("--out", help="folder for episodes.csv and summary.json")
    ev.add_argument("--overwrite", action="store_true", help="replace files in a non-empty --out")
    ev.add_argument(
        "--json", action="store_true",
        help="print the summary as one JSON object on stdout (progress still goes to stderr)",
    )  # fmt: skip
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
    render.add_argument("--seed", type=seed_value, default=0, help="seed of random:K scenarios")
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
    camp.add_argument(
        "--set", action="append", metavar="KEY=VALUE",
        help="change the scene of every cell (repeatable): env.KEY=VALUE, e.g. "
        "env.scenarios.north_speed_kmh=[30,44]",
    )  # fmt: skip
    _perception(camp)
    camp.add_argument("--episodes", type=at_least(1), default=100_000, help="random scenarios")
    camp.add_argument("--seed", type=seed_value, default=0, help="seed of the random scenarios")
    camp.add_argument(
        "--grid", nargs="+", metavar="NAME=SPEC",
        help="grid axes: arrival_offset_s=-3:5:0.25 north_speed_kmh=20,26,32 "
        "ego_speed_kmh=18:25:1 ego_start_distance_m=36 (stop included)",
    )  # fmt: skip
    camp.add_argument(
        "--shard-size", type=at_least(1), default=10_000, help="episodes per Ray task"
    )
    camp.add_argument("--out", required=True, help="campaign folder")
    camp.add_argument("--resume", action="store_true", help="skip the shards already done")
    camp.add_argument(
        "--json", action="store_true",
        help="print the summary as JSON on stdout (the plan and progress still go to stderr)",
    )  # fmt: skip
    camp.add_argument(
        "--no-progress", action="store_true", help="no plan line, progress bar or lines"
    )
    _distributed(camp)
    camp.set_defaults(func=_campaign)

    swp = sub.add_parser("sweep", help="train several seeds or settings of a config on Ray")
    swp.add_argument("--config", default=DEFAULT_CONFIG, help="a configuration (name or file)")
    swp.add_argument("--seeds", type=seed_value, nargs="+", default=[1, 2, 3])
    swp.add_argument(
        "--set", nargs="+", metavar="KEY=V1,V2", help="vary a key, e.g. ppo.gamma=0.99,0.995"
    )
    swp.add_argument("--timesteps", type=at_least(1), help="override the config's training steps")
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
    fal.add_argument("--budget", type=at_least(1), default=20_000, help="episodes per method")
    fal.add_argument("--generation", type=at_least(1), default=500, help="episodes per generation")
    fal.add_argument("--seed", type=seed_value, default=0, help="seed of the search")
    fal.add_argument("--out", required=True, help="output folder")
    fal.add_argument("--overwrite", action="store_true", help="replace files in a used --out")
    fal.add_argument("--no-progress", action="store_true", help="no progress bar or lines")
    _distributed(fal)
    fal.set_defaults(func=_falsify)

    adp = sub.add_parser(
        "adapt", help="keep a trained policy learning in deployment, the switch authoritative"
    )
    adp.add_argument("--model", required=True, help="a run directory or a shipped policy")
    adp.add_argument("--out", required=True, help="output folder (the adapted policy's run)")
    adp.add_argument(
        "--switching", choices=logics, default="certified",
        help="the logic it is deployed under (default: certified)",
    )  # fmt: skip
    adp.add_argument(
        "--set", action="append", metavar="KEY=VALUE",
        help="the shift (repeatable): env.KEY=VALUE, e.g. env.scenarios.north_speed_kmh=[38,44]",
    )  # fmt: skip
    _perception(adp)
    adp.add_argument("--episodes", type=at_least(1), default=10_000, help="deployment episodes")
    adp.add_argument("--block", type=at_least(1), default=1_000, help="episodes per block")
    adp.add_argument("--n-envs", type=at_least(1), default=16, help="environments at once")
    adp.add_argument("--seed", type=seed_value, default=0, help="seed of the deployment")
    adp.add_argument(
        "--eval-episodes", type=at_least(1), default=2_000,
        help="held-out scenarios of each evaluation (frozen, each block, adapted)",
    )  # fmt: skip
    adp.add_argument(
        "--noise", type=float, default=None, metavar="STD",
        help="standard deviation of the exploration noise while deployed (default: the size "
             "its training ended with)",
    )  # fmt: skip
    adp.add_argument(
        "--noise-decay", type=float, default=None, metavar="SHARE",
        help="the noise at the last deployed episode as a share of the first's (default: a "
             "quarter; 1: constant)",
    )  # fmt: skip
    adp.add_argument(
        "--rollback", action=argparse.BooleanOptionalAction, default=True,
        help="after a block whose policy the held-out evaluation ranks below the selected "
             "one, go on learning from the selected policy (default; --no-rollback: learn on "
             "from where the block left it)",
    )  # fmt: skip
    adp.add_argument(
        "--settle", action=argparse.BooleanOptionalAction, default=True,
        help="while the selected policy meets every target on the held-out scenarios, deploy "
             "it without noise and pause learning until a deployed block needs the safety "
             "action in more than 2 %% of its episodes (default; --no-settle: learn on)",
    )  # fmt: skip
    adp.add_argument(
        "--rehearsal", type=float, default=None, metavar="SHARE",
        help="share of the learner's environments replaying the original scenarios, the guard "
             "against forgetting (default: a quarter; 0: none)",
    )  # fmt: skip
    adp.add_argument("--resume", action="store_true", help="continue after the last block")
    adp.add_argument("--no-progress", action="store_true", help="no progress bar")
    adp.set_defaults(func=_adapt)

    exp = sub.add_parser(
        "export",
        help="a trained policy as ONNX with its switch's parameters, checked against torch",
    )
    exp.add_argument(
        "--model", required=True, help=f"a run directory or a shipped policy ({', '.join(SHIPPED)})"
    )
    exp.add_argument("--out", required=True, help="export folder")
    exp.add_argument(
        "--switching", choices=logics, help="the logic to deploy under (default: the run's)"
    )
    exp.add_argument(
        "--observations", type=at_least(1), default=100_000,
        help="observations of the parity check, from the policy's own evaluation episodes",
    )  # fmt: skip
    exp.add_argument("--overwrite", action="store_true", help="replace files in a used --out")
    exp.set_defaults(func=_export)

    xsc = sub.add_parser(
        "export-scenario",
        help="scenarios as OpenSCENARIO 1.0 + OpenDRIVE, with the trajectories of a run",
    )
    xsc.add_argument(
        "--scenarios", default="paper",
        help="paper (default), random (--episodes, --seed) or falsify:FOLDER (every "
        "counterexample of a safeswitch falsify run, replayed under its controller)",
    )  # fmt: skip
    xsc.add_argument("--episodes", type=at_least(1), default=1000, help="random scenarios")
    xsc.add_argument("--seed", type=seed_value, default=0, help="seed of the random scenarios")
    xsc.add_argument(
        "--controller", choices=("learned", "rule", "planner"),
        help="who drives the run whose trajectories are written (default: rule; learned with "
        "--model)",
    )  # fmt: skip
    xsc.add_argument("--model", help="a trained policy (for --controller learned)")
    xsc.add_argument(
        "--traffic", help="traffic from every leg: a preset (light, medium, heavy, train, test)"
    )
    xsc.add_argument("--switching", choices=logics, help="the logic (default: the controller's)")
    xsc.add_argument("--out", required=True, help="output folder")
    xsc.add_argument("--overwrite", action="store_true", help="replace files in a used --out")
    xsc.add_argument("--no-progress", action="store_true", help="no progress bar")
    xsc.set_defaults(func=_export_scenario)

    cal = sub.add_parser(
        "calibrate-perception",
        help="perception bounds that hold with probability 1 - alpha (split conformal)",
    )
    source = cal.add_mutually_exclusive_group(required=True)
    source.add_argument(
        "--pairs", metavar="CSV",
        help="logged pairs: columns seen_position_m, true_position_m, seen_speed_mps, "
        "true_speed_mps (positions along the vehicle's path)",
    )  # fmt: skip
    source.add_argument(
        "--simulate", metavar="YAML",
        help="a sensor model to simulate: position_sigma_m, speed_sigma_mps, distribution "
        "(gaussian|laplace), and latency_s, dropout_prob, dropout_max_s, sight_distance_m "
        "carried as declared",
    )  # fmt: skip
    cal.add_argument("--alpha", type=float, default=0.05, help="miscoverage (default 0.05)")
    cal.add_argument("--holdout", type=float, default=0.5, help="share of pairs held out")
    cal.add_argument("--count", type=at_least(10), default=100_000, help="simulated pairs")
    cal.add_argument("--seed", type=seed_value, default=0, help="seed of the split and sensor")
    cal.add_argument("--out", required=True, help="output folder")
    cal.add_argument("--overwrite", action="store_true", help="replace files in a used --out")
    cal.set_defaults(func=_calibrate_perception)

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
    rep.add_argument(
        "--episodes", type=at_least(1), default=1000, help="random evaluation scenarios"
    )
    rep.add_argument(
        "--timesteps",
        type=at_least(1),
        help="PPO steps per policy without --quick (default: each config's 1.2 M); a "
        "configuration's warm start keeps its own size",
    )
    rep.add_argument("--overwrite", action="store_true", help="replace an existing report")
    rep.set_defaults(func=_reproduce)

    demo = sub.add_parser("demo", help="the same as reproduce --quick (the README's make demo)")
    demo.add_argument("--out", default="out/demo", help="report folder (default: out/demo)")
    demo.set_defaults(func=_reproduce, quick=True, episodes=1000, timesteps=None, overwrite=True)
    for command in (parser, *sub.choices.values()):
        command.add_argument(
            "--import",
            dest="imports",
            action="append",
            metavar="MODULE",
            help="import MODULE first (repeatable): its environments, Safety controllers and "
            "switching logics become known to --env and --switching",
        )
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    modules = imported_modules(argv)
    if modules:
        from safeswitch.core.registry import import_modules

        for option, module in modules:
            try:
                import_modules([module])
            except ModuleNotFoundError as exc:
                print(f"safeswitch: error: {option}: {exc}", file=sys.stderr)
                return 2
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # a usage error (one line already printed) returns its code
        if exc.code in (0, None):
            raise
        return int(exc.code) if isinstance(exc.code, int) else 2
    if args.command is None:
        parser.print_help()
        return 0
    return _run(args.command, lambda: int(args.func(args)))


if __name__ == "__main__":
    sys.exit(main())
