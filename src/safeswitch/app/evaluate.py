"""``safeswitch evaluate``: any controller × any switching logic × a set of scenarios."""

from __future__ import annotations

import sys
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import take_rows
from safeswitch.core.config import ConfigError, with_settings
from safeswitch.evaluation.evaluate import (
    BASELINES,
    EpisodeCSV,
    baseline_setup,
    run_controller,
    scenario_chunks,
)
from safeswitch.evaluation.metrics import SummaryAccumulator
from safeswitch.evaluation.oracle import Oracle
from safeswitch.evaluation.planner_config import GapPlannerConfig
from safeswitch.evaluation.rollout import Policy
from safeswitch.evaluation.traffic_planner import UnboundGapPlanner
from safeswitch.io import prepare_output_dir, write_json
from safeswitch.leftturn.config import (
    SCENARIO_NAMES,
    LeftTurnConfig,
    TrafficConfig,
    observed_as,
    traffic_config,
)
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.scenarios import Scenarios
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.progress import Progress, format_duration
from safeswitch.training.config import TrainConfig

#: Prefix of ``--scenarios`` naming OpenSCENARIO files (``safeswitch export-scenario``).
OPENSCENARIO = "openscenario:"

#: Prefix of the ``--set`` settings that tune the gap planner.
GAP_PLANNER = "gap_planner."

#: Every ``--sim``.
SIMULATORS = ("embedded", "sumo")

#: Episodes per second of each controller in the paper's scene, one process on this project's
#: two-core reference machine (``safeswitch campaign --workers 0``, 20,000 episodes, the
#: shipped policy for ``learned``): what the time estimates of a long evaluation or campaign
#: assume.
NOMINAL_RATE = {"rule": 1_800.0, "planner": 220.0, "oracle": 1_350.0, "learned": 1_150.0}
#: Throughput of ``N`` workers as a share of ``N`` single processes (two workers on two cores
#: ran a campaign of the rule at 2,154 episodes/s, against 1,800 for one process).
PARALLEL_EFFICIENCY = 0.6
#: A job estimated to run longer than this gets a warning before it starts [s].
LONG_PLAN_S = 3600.0

#: Every ``--controller``.
CONTROLLERS: tuple[str, ...] = ("learned", *BASELINES)


def scene_settings(config: LeftTurnConfig, specs: Sequence[str]) -> LeftTurnConfig:
    """``config`` with ``--set env.KEY=VALUE`` settings (``KEY``: a dotted key of the left
    turn's configuration), validated as a file is.

    Raises:
        ConfigError: A setting outside ``env.``, an unknown key or a bad value.
    """
    scene = []
    for spec in specs:
        if not spec.startswith("env."):
            raise ConfigError(
                f"--set {spec!r}: this command changes the scene the controller drives in: "
                "env.KEY=VALUE (the gap planner's tuning: gap_planner.KEY=VALUE; training "
                "settings are train's)"
            )
        scene.append(spec[len("env.") :])
    return with_settings(config, scene, prefix="env.")


def controller_setup(
    controller: str,
    model: str | None,
    switching: str | None,
    settings: Sequence[str] = (),
) -> tuple[LeftTurnConfig, Policy | None]:
    """The task configuration and policy of a controller (``None`` for the oracle, which
    plans instead of acting): a trained policy (``learned``, from ``model``) with the
    environment it was trained in, or a baseline (see
    :func:`~safeswitch.evaluation.evaluate.baseline_setup`); ``switching`` overrides the
    logic, ``settings`` (``env.KEY=VALUE``) change the scene (:func:`scene_settings`), and
    for the gap planner ``gap_planner.KEY=VALUE`` its tuning
    (:class:`~safeswitch.evaluation.planner_config.GapPlannerConfig`).

    Raises:
        ConfigError: A bad setting (named), or ``gap_planner.`` for another controller.
    """
    tuning = [spec[len(GAP_PLANNER) :] for spec in settings if spec.startswith(GAP_PLANNER)]
    scene = [spec for spec in settings if not spec.startswith(GAP_PLANNER)]
    config, policy = _controller_setup(controller, model, switching)
    if tuning:
        if controller != "gap_planner":
            raise ConfigError(
                f"--set {GAP_PLANNER + tuning[0]!r} tunes --controller gap_planner, not "
                f"--controller {controller}"
            )
        policy = UnboundGapPlanner(with_settings(GapPlannerConfig(), tuning, prefix=GAP_PLANNER))
    return scene_settings(config, scene), policy


def _controller_setup(
    controller: str, model: str | None, switching: str | None
) -> tuple[LeftTurnConfig, Policy | None]:
    if controller == "learned":
        if model is None:
            raise ValueError("--controller learned needs --model (a run directory or 'shipped')")
        from safeswitch.training.policies import load_policy  # torch: only for a policy

        trained = load_policy(model)
        if not isinstance(trained.config, TrainConfig):
            raise ValueError(
                f"the policy in {trained.path} was trained on {trained.config.env_id}; "
                f"evaluate it with --env {trained.config.env_id}"
            )
        env_config = trained.config.deployed_env
        if switching is not None:
            env_config = replace(env_config, switching=switching)
        return replace(env_config, scenario=None), trained.as_policy()
    if controller not in BASELINES:
        raise ValueError(
            f"--controller must be one of {', '.join(CONTROLLERS)}, got {controller!r}"
        )
    if model is not None:
        raise ValueError(
            f"--model {model} is a trained policy, but --controller {controller} does not use "
            "one; drop --model or use --controller learned"
        )
    return baseline_setup(controller, switching)


def traffic_setup(
    controller: str, model: str | None, traffic: str | None
) -> tuple[TrafficConfig | None, str | None]:
    """The traffic to evaluate in and its label: ``traffic`` (a preset's name, or ``none`` for
    the paper's scene), else the traffic a trained policy was trained in (none for the
    baselines). A policy trained in traffic keeps what it observes
    (:data:`~safeswitch.leftturn.config.POLICY_OBSERVATION`) in any other traffic: the
    observation belongs to the policy, not to the scene."""
    trained = None
    if controller == "learned" and model is not None:
        from safeswitch.training.policies import load_policy

        config = load_policy(model).config
        if isinstance(config, TrainConfig) and config.traffic is not None:
            trained = config
    if traffic is not None:
        settings = None if traffic == "none" else traffic_config(traffic)
        if settings is not None and trained is not None:
            seen = trained.traffic_settings
            assert seen is not None
            settings = observed_as(settings, seen)
        return settings, None if settings is None else traffic
    if trained is not None:
        return trained.traffic_settings, str(trained.traffic)
    return None, None


def fit_observations(policy: Policy | None, model: str | None, task: LeftTurnTask) -> Policy | None:
    """A trained policy's observations cut to what it was trained on: a policy trained in the
    paper's scene sees the paper's six values of a scene with traffic (the other vehicles
    reach it only through the switching logic). The gap planner is bound to ``task`` here.

    Raises:
        ValueError: The policy expects more than the task observes (trained in traffic,
            evaluated without, or with fewer observed vehicles).
    """
    if isinstance(policy, UnboundGapPlanner):
        return policy.bind(task)
    if policy is None or model is None:
        return policy
    from safeswitch.training.policies import load_policy

    expected = int(np.prod(load_policy(model).model.observation_space.shape or (6,)))
    observed = int(task.observation_bounds[0].shape[0])
    if expected == observed:
        return policy
    if expected > observed:
        raise ValueError(
            f"the policy {model} observes {expected} values but this task gives {observed}: it "
            "was trained in traffic; evaluate it with --traffic (and the same observed count)"
        )

    def cut(obs: NDArray[np.float32], state: Any, tick: int) -> NDArray[np.float64]:
        return policy(obs[:, :expected], state, tick)

    return cut


def evaluate(
    controller: str,
    model: str | None,
    scenarios: str,
    episodes: int,
    seed: int,
    switching: str | None,
    out: str | Path | None,
    overwrite: bool = False,
    progress: bool = False,
    traffic: str | None = None,
    sim: str = "embedded",
    settings: Sequence[str] = (),
) -> dict[str, Any]:
    """Run the evaluation and return its summary (see :mod:`safeswitch.evaluation.metrics` for
    the fields); with ``out``, write ``episodes.csv`` (row by row, as chunks finish) and
    ``summary.json`` there. Episodes run in chunks of
    :data:`~safeswitch.evaluation.evaluate.CHUNK`, so memory stays bounded whatever
    ``episodes`` is. ``traffic``: see :func:`traffic_setup`. ``sim="sumo"``: on SUMO
    (:mod:`safeswitch.sumo`), one episode after another; the summary adds the episodes in which
    SUMO reported a collision and those in which its north car broke the certified logic's
    assumptions.

    Raises:
        OutputDirectoryError: ``out`` is a file, or holds files and ``overwrite`` is off.
    """
    if sim not in SIMULATORS:
        raise ValueError(f"--sim must be one of {', '.join(SIMULATORS)}, got {sim!r}")
    env_config, policy = controller_setup(controller, model, switching, settings)
    traffic_settings, traffic_label = traffic_setup(controller, model, traffic)
    task = build_task(None, env_config, traffic=traffic_settings)
    on_sumo = None
    if sim == "sumo":
        from safeswitch.sumo.task import sumo_task

        task = on_sumo = sumo_task(env_config, traffic_settings)
    policy = fit_observations(policy, model if controller == "learned" else None, task)
    if scenarios.startswith(OPENSCENARIO):
        read = _openscenario(scenarios, task)
        chunks: Iterator[tuple[list[str], Scenarios]] = iter([read])
        total = len(read[0])
    else:
        chunks = scenario_chunks(task, scenarios, episodes, seed)  # validates the arguments
        total = len(SCENARIO_NAMES) if scenarios == "paper" else episodes
    folder = prepare_output_dir(out, overwrite) if out is not None else None
    accumulator = SummaryAccumulator()
    writer = EpisodeCSV(folder / "episodes.csv") if folder is not None else None
    bar = Progress(total, f"evaluate {controller}", enabled=progress)
    if progress:
        seconds = total / NOMINAL_RATE.get(controller, 1_000.0)
        if sim == "sumo":
            seconds *= 20.0  # one SUMO scene at a time
        if seconds > LONG_PLAN_S:
            print(
                f"warning: {total:,} episodes would take about {format_duration(seconds)} on "
                "one core; Ctrl-C stops the evaluation, or ask for fewer --episodes",
                file=sys.stderr,
                flush=True,
            )
    sumo = {"sumo_collision_episodes": 0, "assumption_break_episodes": 0}
    try:
        for names, batch in chunks:
            # SUMO runs scene by scene; in traffic the oracle plans on the embedded twin, so
            # it is planned once for the whole chunk (one batch).
            whole = None
            if on_sumo is not None and on_sumo.embedded is not on_sumo:
                whole = Oracle(task).plan(batch, full=False)
            for k, (part, scenes) in enumerate(_one_by_one(names, batch, on_sumo is not None)):
                given = None if whole is None else take_rows(whole, np.array([k]))
                result, plan = run_controller(task, policy, scenes, plan=given, trace=False)
                accumulator.add(result, plan.time_to_clear, task.config.episode.horizon_s)
                if writer is not None:
                    writer.write(part, scenes, result, plan.time_to_clear)
                if on_sumo is not None:
                    sumo["sumo_collision_episodes"] += int(on_sumo.sumo_collisions > 0)
                    sumo["assumption_break_episodes"] += int(on_sumo.assumption_breaks)
                bar.update(len(part))
    except BaseException:
        if writer is not None:
            writer.abandon()
        raise
    finally:
        bar.close()
        if on_sumo is not None:
            on_sumo.close()
    if writer is not None:
        writer.close()
    summary = {
        "controller": controller,
        "model": str(model) if model else None,
        "switching": env_config.switching if policy is not None else None,
        "scenarios": scenarios,
        "traffic": traffic_label,
        "settings": list(settings),
        "sim": sim,
        "seed": seed,
        **accumulator.summary(),
        **(sumo if sim == "sumo" else {}),
    }
    if folder is not None:
        write_json(folder / "summary.json", summary)
    return summary


def _openscenario(scenarios: str, task: LeftTurnTask) -> tuple[list[str], Scenarios]:
    """The scenarios of ``openscenario:PATH`` and their names (the paper's scene only)."""
    if task.crossing_zones().shape[0] > 0:
        raise ValueError(
            "--scenarios openscenario: the files hold the paper's scene (one oncoming car); "
            "evaluate them without --traffic"
        )
    from safeswitch.deploy.openscenario import read_scenarios

    batch, names = read_scenarios(scenarios[len(OPENSCENARIO) :], task)
    return names, batch


def _one_by_one(
    names: list[str], batch: Scenarios, single: bool
) -> Iterator[tuple[list[str], Scenarios]]:
    """The chunk as it is, or (``single``: SUMO runs one scene per process) scene by scene."""
    if not single:
        yield names, batch
        return
    for i, name in enumerate(names):
        yield [name], take_rows(batch, np.array([i]))
