"""``safeswitch reproduce``: the paper's Section VI experiments and our comparisons, end to end.

Every controller (the oracle, the rule-based system, the planner, and the PPO policies deployed
with the ``paper`` switching logic — the shipped one, trained from scratch with constraints, the
one warm-started from the planner and the paper's recipe as written —, without ``R_ADAS``, with
the ``certified`` logic and with none) is evaluated on the paper's three scenarios (traced tick
by tick: the figures) and on random scenarios (the comparison table). ``--quick`` uses the
shipped policies; without it, the six policies are first trained with the shipped
configurations. Each stage announces itself and reports its progress.

The report folder holds ``report.html`` (self-contained: figures, animations and tables embedded),
``report.md`` (the same, with the pictures beside it), ``summary.json`` and the per-episode CSVs
in ``raw/``. ``report.html`` is written last: a folder without it is incomplete.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from safeswitch.app.evaluate import controller_setup
from safeswitch.app.perception_study import REFERENCE, study, together
from safeswitch.app.train import kept_step
from safeswitch.evaluation.adversaries import constant
from safeswitch.evaluation.evaluate import (
    episodes_csv,
    run_controller,
    scenario_set,
    summary_against_oracle,
)
from safeswitch.evaluation.metrics import STOP_SPEED, summarize
from safeswitch.evaluation.oracle import OraclePlan, efficiency
from safeswitch.evaluation.rollout import rollout
from safeswitch.io import prepare_output_dir, write_atomic, write_bytes_atomic, write_json
from safeswitch.leftturn.config import SCENARIO_NAMES, LeftTurnConfig
from safeswitch.leftturn.task import OUTCOMES, LeftTurnTask
from safeswitch.report.document import comparison_text, render_html, render_markdown
from safeswitch.report.figures import (
    ComparisonRow,
    Trace,
    comparison_figure,
    episode_figure,
    frames_strip,
    perception_figure,
    traffic_figure,
)
from safeswitch.report.training import training_curves, training_story
from safeswitch.training.config import load_config
from safeswitch.training.policies import SHIPPED_DIR

#: Seed of the random evaluation scenarios (the same as the training runs' final evaluation,
#: never used in training).
EVAL_SEED = 1_000_003


@dataclass(frozen=True)
class Entry:
    """A controller of the comparison.

    Attributes:
        name: Short name (file names, tables).
        kind: ``learned``, ``rule``, ``planner`` or ``oracle``.
        policy: Shipped policy name (``--quick``) of a learned controller.
        label: What it is, for the tables.
    """

    name: str
    kind: str
    policy: str | None
    label: str


ENTRIES: tuple[Entry, ...] = (
    Entry("oracle", "oracle", None, "Oracle (minimum time, knows the north car's future)"),
    Entry("rule", "rule", None, "Rule-based: PID_th under the paper switching logic"),
    Entry(
        "planner", "planner", None, "Planner (ours): throttle only, plans around the paper logic"
    ),
    Entry(
        "ppo-paper",
        "learned",
        "paper",
        "PPO, paper switching, R_ADAS on, from scratch with constraints (ours; shipped)",
    ),
    Entry(
        "ppo-paper-warm",
        "learned",
        "paper_warm",
        "PPO, paper switching, R_ADAS on, warm-started from the planner, speed limiter (ours)",
    ),
    Entry(
        "ppo-paper-scratch",
        "learned",
        "paper_scratch",
        "PPO, paper switching, R_ADAS on, from scratch (the paper's recipe)",
    ),
    Entry("ppo-no-adas", "learned", "no_adas", "PPO, paper switching, R_ADAS off (ablation)"),
    Entry(
        "ppo-certified",
        "learned",
        "certified",
        "PPO, certified switching, R_ADAS on, from scratch with constraints (ours)",
    ),
    Entry("ppo-unshielded", "learned", "none", "PPO trained and run without switching logic"),
)


def train_policies(
    out: Path, timesteps: int | None, log: Callable[[str], None] = print
) -> dict[str, Path]:
    """Train the six policies with their shipped configurations, into
    ``out/runs/``; a finished run is reused and an interrupted one resumed."""
    from safeswitch.app.train import train_and_plot
    from safeswitch.io import complete_checkpoints

    learned = [e for e in ENTRIES if e.policy is not None]
    runs = {}
    for k, entry in enumerate(learned, 1):
        assert entry.policy is not None
        config = load_config(SHIPPED_DIR / entry.policy / "config.yaml")
        if timesteps is not None:
            config = replace(config, timesteps=timesteps)
        run = out / "runs" / entry.policy
        runs[entry.policy] = run
        if (run / "metrics.json").is_file():  # finished by an earlier, interrupted reproduce
            log(f"training {k}/{len(learned)}: reusing the finished run {run}")
            continue
        warm = (
            f"a warm start ({config.warm_start.episodes:,} episodes × "
            f"{config.warm_start.rounds + 1} rounds), then "
            if config.warm_start.episodes
            else ""
        )
        log(
            f"training {k}/{len(learned)}: {entry.name}: {warm}{config.timesteps:,} PPO steps "
            f"into {run}"
        )
        train_and_plot(config, run, resume=bool(complete_checkpoints(run)), progress_bar=True)
    return runs


def training_record(model_dir: str | Path) -> dict[str, Any]:
    """How a policy was made, from its run's ``config.yaml`` and ``metrics.json``: the method
    in words, switching, ``R_ADAS``, and its collisions in training (warm start included)."""
    folder = Path(model_dir)
    config = load_config(folder / "config.yaml")
    metrics = json.loads((folder / "metrics.json").read_text(encoding="utf-8"))
    warm = metrics.get("warm_start")
    steps = metrics["timesteps"]
    if config.warm_start.episodes:
        teacher = "the gap planner" if config.warm_start.teacher == "gap_planner" else "the planner"
        method = (
            f"warm start (behaviour cloning of {teacher}: {config.warm_start.episodes:,} "
            f"episodes, {config.warm_start.rounds} DAgger rounds), then PPO to {steps:,} steps"
        )
    else:
        method = f"PPO from a random initialisation, {steps:,} steps"
    if config.shaping.progress_shaping:
        method += (
            f", with progress shaping ({config.shaping.progress_shaping:g} per metre, "
            "potential-based, learning only)"
        )
    constrained = config.constraints.active()
    if constrained:
        method += f", constrained ({', '.join(constrained)}: Lagrange multipliers, learning only)"
    traffic = config.traffic_settings
    if traffic is not None:
        method = f"in traffic from every leg: {method}"
    go_model = traffic.go_model if traffic is not None else config.env.episode.go_model
    if go_model is not None:
        method += ", a learned go predictor in its observation"
    controllers = config.deployed_env.controllers
    if controllers.learned_brake:
        method += ", a learned brake"
    if controllers.learned_speed_limiter_kmh is not None:
        method += (
            f", its throttle through a speed limiter at {controllers.learned_speed_limiter_kmh:g} "
            "km/h"
        )
    if controllers.learned_curve_accel is not None:
        method += f" and a curve speed limiter ({controllers.learned_curve_accel:g} m/s² sideways)"
    if config.deployed_env.switching != config.env.switching:
        method += (
            f"; trained under {config.env.switching}, deployed under "
            f"{config.deployed_env.switching}"
        )
    guard, deployed = config.train_env.certified, config.deployed_env.certified
    if config.env.switching in ("certified", "guarded") and (
        guard.other_max_accel,
        guard.other_max_speed_kmh,
    ) != (deployed.other_max_accel, deployed.other_max_speed_kmh):
        method += (
            f"; its training filter assumed other vehicles at most {guard.other_max_accel:g} "
            f"m/s² and {guard.other_max_speed_kmh:g} km/h (the training scene's own)"
        )
    collisions = metrics["training"]["collisions"] + (warm["collisions"] if warm else 0)
    return {
        "method": method,
        "timesteps": steps,
        "warm_start": bool(config.warm_start.episodes),
        "switching": config.env.switching,
        "adas_penalty": config.env.adas_penalty,
        "seed": config.seed,
        "collisions": collisions,
    }


def _paper_findings(paper: dict[str, Any], ablation: dict[str, Any]) -> list[tuple[str, bool]]:
    """The paper's Section VI observations, checked on the traced paper scenarios."""
    cut, y1, y2 = (paper[name] for name in SCENARIO_NAMES)
    if any(paper[name]["collision"] for name in SCENARIO_NAMES):
        return [("the paper policy does not collide in the paper scenarios", False)]
    return [
        (
            "cut: the ego passes before the north car without a safety activation",
            cut["outcome"] == "cut" and cut["safety_steps"] == 0,
        ),
        (
            "yield1: the ego passes after the north car, without a stop or a safety activation",
            y1["outcome"] == "yield"
            and y1["safety_steps"] == 0
            and y1["min_speed_kmh"] > STOP_SPEED * 3.6,
        ),
        (
            "yield2: the ego slows further than in yield1, without a safety activation "
            f"(to {y2['min_speed_kmh']:.1f} km/h against {y1['min_speed_kmh']:.1f}; "
            + (
                "a full stop, as the paper's policy makes for a few milliseconds)"
                if y2["min_speed_kmh"] <= STOP_SPEED * 3.6
                else "the paper's policy stops for a few milliseconds, this one does not stop)"
            ),
            y2["outcome"] == "yield"
            and y2["safety_steps"] == 0
            and y2["min_speed_kmh"] < y1["min_speed_kmh"],
        ),
        (
            "ablation (no R_ADAS): the Safety controller acts in a yield scenario",
            ablation["yield1"]["safety_steps"] > 0 or ablation["yield2"]["safety_steps"] > 0,
        ),
    ]


def _training_curves(model_dir: str, label: str, folder: Path) -> dict[str, Any] | None:
    """The paper policy's training curves (the paper's Fig. 5) drawn from its run's
    ``progress.csv`` into the report's figures, with what the paper says of its own beside
    what these show; ``None`` if the policy has no training log."""
    progress = Path(model_dir) / "progress.csv"
    if not progress.is_file():
        return None
    figure = folder / "figures" / "training_curves.png"
    training_curves(progress, figure, selected=kept_step(Path(model_dir)))
    return {"label": label, "story": training_story(progress)}


def perception_section(episodes: int, folder: Path) -> dict[str, Any]:
    """The shipped controllers under every bounded perception error at once
    (:mod:`safeswitch.app.perception_study`), random and adversarial, at levels 0–3 of the
    reference bounds; the figure ``perception.png``."""
    cells = [("together", level, {**together(level, errors), "errors": errors})
             for errors in ("adversarial", "random") for level in (0.0, 1.0, 2.0, 3.0)]  # fmt: skip
    rows = study(cells, episodes, EVAL_SEED)
    perception_figure(
        rows, folder / "figures" / "perception.png", f"({episodes} scenarios per point)"
    )
    return {"episodes": episodes, "unit": REFERENCE, "rows": rows}


def _reckless(episodes: int) -> list[dict[str, Any]]:
    """A reckless learned controller (full throttle) under each switching logic."""
    rows = []
    for switching in ("none", "paper", "certified"):
        task = LeftTurnTask(LeftTurnConfig(switching=switching))
        batch, _ = scenario_set(task, "random", episodes, EVAL_SEED)
        summary = summarize(rollout(task, batch, constant(1.0)))
        rows.append({"switching": switching, **summary})
    return rows


#: The traffic study: densities, the paper policy under each logic (it sees the paper's six
#: values; the other vehicles reach it only through the switching logic), the policies trained
#: in traffic (shipped; each under its own logic) and the oracle.
TRAFFIC_PRESETS = ("light", "medium", "heavy", "test")
TRAFFIC_CONTROLLERS = (
    ("ppo-paper", "paper"), ("ppo-paper", "certified"), ("ppo-traffic-paper", "paper"),
    ("ppo-traffic-certified", "certified"), ("clone-traffic-certified", "certified"),
    ("oracle", None),
)  # fmt: skip
#: The shipped policy behind each trained controller of the traffic study (the paper policy:
#: the one this report evaluates, trained or shipped).
TRAFFIC_POLICIES = {"ppo-traffic-paper": "traffic_paper",
                    "ppo-traffic-certified": "traffic_certified",
                    "clone-traffic-certified": "traffic_certified_clone"}  # fmt: skip
#: The controller the traffic animation shows (in medium traffic).
TRAFFIC_ANIMATED = ("ppo-traffic-certified", "certified")


def traffic_study(
    models: dict[str, str], episodes: int, folder: Path, log: Callable[[str], None]
) -> list[dict[str, Any]]:
    """The controllers of :data:`TRAFFIC_CONTROLLERS` in traffic from every leg at each density
    of :data:`TRAFFIC_PRESETS`; an animation of :data:`TRAFFIC_ANIMATED` in medium traffic.
    Rows: preset, controller, switching and the summary."""
    from safeswitch.app.evaluate import fit_observations, traffic_setup
    from safeswitch.evaluation.evaluate import summary_against_oracle
    from safeswitch.leftturn.make import build_task

    rows = []
    for preset in TRAFFIC_PRESETS:
        plan = None
        for name, switching in TRAFFIC_CONTROLLERS:
            kind = "learned" if name != "oracle" else "oracle"
            model = None
            if policy_of(name):
                shipped = TRAFFIC_POLICIES.get(name)
                model = models["paper"] if shipped is None else str(SHIPPED_DIR / shipped)
            config, policy = controller_setup(kind, model, switching)
            traffic, _ = traffic_setup(kind, model, preset)  # a policy keeps what it observes
            task = build_task(None, config, traffic=traffic)
            policy = fit_observations(policy, model, task)
            batch, _ = scenario_set(task, "random", episodes, EVAL_SEED)
            busiest = int(np.argmax(batch.traffic.active.sum(axis=1)))  # type: ignore[attr-defined]
            animate = preset == "medium" and (name, switching) == TRAFFIC_ANIMATED
            trace = Trace(task, animate=(busiest,)) if animate else None
            result, plan = run_controller(
                task, policy, batch, trace.on_tick if trace else None, plan=plan, trace=False
            )
            summary = summary_against_oracle(result, plan, task.config.episode.horizon_s)
            if not policy_of(name):  # its surrogate measures are not computed in traffic
                summary["ttc_conflict_episodes"] = summary["pet_below_1s_episodes"] = None
            rows.append({"preset": preset, "controller": name, "switching": switching, **summary})
            if trace is not None:
                write_bytes_atomic(folder / "figures" / "traffic_medium.gif", trace.gif(busiest))
            log(
                f"  traffic {preset:6s} {name} / {switching or '-'}: {summary['collisions']} "
                f"collisions, {summary['cleared_episodes']}/{episodes} cleared"
            )
    traffic_figure(rows, TRAFFIC_PRESETS, folder / "figures" / "traffic.png")
    return rows


#: The cross-simulator comparison: controllers (name, kind, shipped policy).
SUMO_CONTROLLERS = (("ppo-paper", "learned", "paper"), ("ppo-certified", "learned", "certified"),
                    ("rule", "rule", None))  # fmt: skip
#: ... and in traffic from every leg (SUMO driving every vehicle): (name, kind, policy, logic,
#: preset) — the shipped paper policy under the certified logic, as in the traffic study.
SUMO_TRAFFIC = (("ppo-paper", "learned", "paper", "certified", "medium"),)


def sumo_study(
    episodes: int, log: Callable[[str], None], traffic_episodes: int | None = None
) -> dict[str, Any]:
    """The shipped paper and certified policies and the rule-based controller on the same
    random scenarios on both simulators (SUMO driving the north car), then
    :data:`SUMO_TRAFFIC` in traffic (SUMO driving every other vehicle; ``traffic_episodes``
    scenes, default ``episodes``: a 30 s episode in traffic runs about a second on SUMO);
    ``available`` is false (and there are no rows) without the ``safeswitch[sumo]`` extra."""
    from safeswitch.app.evaluate import evaluate
    from safeswitch.sumo.network import SumoMissingError, sumo_home

    try:
        sumo_home()
        import libsumo  # noqa: F401
    except (SumoMissingError, ImportError) as exc:
        log(f"  SUMO: skipped ({exc})")
        return {"available": False, "episodes": episodes, "rows": [], "reason": str(exc)}
    rows = []
    runs = [(name, kind, policy, None, None) for name, kind, policy in SUMO_CONTROLLERS]
    for name, kind, policy, switching, traffic in [*runs, *SUMO_TRAFFIC]:
        model = str(SHIPPED_DIR / policy) if policy else None
        count = episodes if traffic is None else (traffic_episodes or episodes)
        for sim in ("embedded", "sumo"):
            summary = evaluate(kind, model, "random", count, EVAL_SEED, switching, None,
                               sim=sim, traffic=traffic)  # fmt: skip
            label = name if switching is None else f"{name} / {switching}"
            scene = "paper's scene" if traffic is None else f"{traffic} traffic"
            rows.append({**summary, "controller": label, "scene": scene})
        log(
            f"  SUMO: {rows[-1]['controller']} ({rows[-1]['scene']}): "
            f"{rows[-1]['collisions']} collisions on SUMO, {rows[-2]['collisions']} embedded"
        )
    return {
        "available": True,
        "episodes": episodes,
        "traffic_episodes": traffic_episodes or episodes,
        "rows": rows,
    }


def policy_of(name: str) -> bool:
    """Whether a controller of the traffic study is a trained policy."""
    return name != "oracle"


def reproduce(
    out: str | Path,
    quick: bool = True,
    episodes: int = 1000,
    timesteps: int | None = None,
    overwrite: bool = False,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Run the experiments and write the report folder; returns the summary.

    Raises:
        OutputDirectoryError: ``out`` is a file, or holds files and ``overwrite`` is off (a
            folder with an unfinished ``reproduce`` — training runs but no report — is resumed).
    """
    began = time.perf_counter()
    folder = Path(out)
    resuming = (folder / "runs").is_dir() and not (folder / "report.html").exists()
    prepare_output_dir(folder, overwrite or (resuming and not quick))
    (folder / "raw").mkdir(exist_ok=True)
    (folder / "figures").mkdir(exist_ok=True)
    models: dict[str, str] = {}
    stages = 2 if quick else 3
    if quick:
        models = {e.policy: str(SHIPPED_DIR / e.policy) for e in ENTRIES if e.policy}
    else:
        log(f"stage 1/{stages}: training the six policies (PPO; progress per run)")
        models = {k: str(v) for k, v in train_policies(folder, timesteps, log).items()}
    log(
        f"stage {stages - 1}/{stages}: evaluating {len(ENTRIES)} controllers on the paper's "
        f"3 scenarios and {episodes:,} random ones"
    )

    results: dict[str, Any] = {}
    rows: list[ComparisonRow] = []
    offsets = None
    oracle_random = None
    horizon_s = LeftTurnConfig().episode.horizon_s
    # The oracle's plans depend on neither the switching logic, R_ADAS nor who drives: one
    # plan per remaining configuration and scenario set serves every controller.
    plans: dict[tuple[LeftTurnConfig, str], OraclePlan] = {}
    for k, entry in enumerate(ENTRIES, 1):
        model = models.get(entry.policy) if entry.policy else None
        config, policy = controller_setup(entry.kind, model, None)
        task = LeftTurnTask(config)
        dt = config.episode.dt
        paper_batch, names = scenario_set(task, "paper", 3, 0)
        trace = Trace(task, animate=(0, 1, 2) if entry.name == "ppo-paper" else ())
        world = replace(
            config,
            switching="none",
            adas_penalty=False,
            episode=replace(config.episode, learned_scope="never"),
        )
        paper_result, paper_plan = run_controller(
            task, policy, paper_batch, trace.on_tick, plans.get((world, "paper"))
        )
        random_batch, random_names = scenario_set(task, "random", episodes, EVAL_SEED)
        random_result, random_plan = run_controller(
            task, policy, random_batch, plan=plans.get((world, "random"))
        )
        plans[world, "paper"], plans[world, "random"] = paper_plan, random_plan
        horizon_s = config.episode.horizon_s
        ratio = efficiency(random_plan.time_to_clear, random_result.time_to_clear, horizon_s)
        offsets, oracle_random = random_batch.arrival_offset, random_plan.time_to_clear
        summary = summary_against_oracle(random_result, random_plan, horizon_s)
        per_scenario = {}
        for i, name in enumerate(names):
            crashed = bool(paper_result.collision[i])
            clear = float(paper_result.time_to_clear[i])
            oracle = float(paper_plan.time_to_clear[i])
            per_scenario[name] = {
                "outcome": OUTCOMES[int(paper_result.outcome[i])],
                "collision": crashed,
                "collision_time_s": float(paper_result.ticks[i] * dt) if crashed else None,
                "safety_steps": int(paper_result.safety_steps[i]),
                "min_speed_kmh": float(paper_result.min_speed[i] * 3.6),
                "time_to_clear_s": clear if np.isfinite(clear) else None,
                "oracle_time_to_clear_s": oracle if np.isfinite(oracle) else None,
                "comfort_violation_steps": int(paper_result.comfort_violation_steps[i]),
            }
        results[entry.name] = {
            "label": entry.label,
            "model": model,
            "switching": config.switching if policy is not None else None,
            "training": training_record(model) if model is not None else None,
            "random": summary,
            "paper": per_scenario,
        }
        write_atomic(
            folder / "raw" / f"{entry.name}_random.csv",
            episodes_csv(random_names, random_batch, random_result, random_plan.time_to_clear),
        )
        write_atomic(
            folder / "raw" / f"{entry.name}_paper.csv",
            episodes_csv(names, paper_batch, paper_result, paper_plan.time_to_clear),
        )
        if policy is not None:
            rows.append(
                ComparisonRow(
                    entry.name, random_result.time_to_clear, random_result.collision,
                    random_result.outcome, ratio, random_result.lost_control,
                    random_result.speeding_steps > 0,
                )
            )  # fmt: skip
            for i, name in enumerate(names):
                per_scenario[name]["figure"] = episode_figure(
                    trace,
                    i,
                    f"{entry.label} — scenario {name}",
                    folder / "figures" / f"{entry.name}_{name}.png",
                    oracle_speed=paper_plan.speed[i],
                )
        for i in trace.frames:
            write_bytes_atomic(folder / "figures" / f"{entry.name}_{names[i]}.gif", trace.gif(i))
            frames_strip(trace, i).save(folder / "figures" / f"{entry.name}_{names[i]}_strip.png")
        log(
            f"  {k}/{len(ENTRIES)} {entry.name:17s} evaluated: {summary['collisions']} "
            f"collisions ({time.perf_counter() - began:.0f} s)"
        )

    assert offsets is not None and oracle_random is not None
    traffic_episodes = max(50, episodes // 10)
    log(f"  traffic from every leg: {traffic_episodes} random scenarios per density")
    traffic = traffic_study(models, traffic_episodes, folder, log)
    sumo_episodes = max(20, episodes // 50)
    log(
        f"  SUMO as a second simulator: {sumo_episodes} random scenarios per controller "
        f"({max(10, episodes // 100)} in traffic)"
    )
    sumo = sumo_study(sumo_episodes, log, max(10, episodes // 100))
    perception_episodes = max(100, episodes // 5)
    log(f"  perception errors: {perception_episodes} random scenarios per level")
    perception = perception_section(perception_episodes, folder)
    log(f"stage {stages}/{stages}: figures and the report")
    comparison_figure(
        rows, oracle_random, offsets, horizon_s, folder / "figures" / "comparison.png"
    )
    findings = _paper_findings(results["ppo-paper"]["paper"], results["ppo-no-adas"]["paper"])
    curves = _training_curves(models["paper"], results["ppo-paper"]["label"], folder)
    reckless = _reckless(episodes)
    defaults = LeftTurnConfig()
    summary = {
        "quick": quick,
        "episodes": episodes,
        "seed": EVAL_SEED,
        "limits": {
            "lon": defaults.rewards.comfort_accel_lon,
            "lat": defaults.rewards.comfort_accel_lat,
            "horizon": defaults.episode.horizon_s,
            "tolerated_kmh": defaults.rewards.tolerated_speed * 3.6,
        },
        "controllers": results,
        "paper_findings": [{"finding": f, "reproduced": ok} for f, ok in findings],
        "training_curves": curves,
        "reckless_full_throttle": reckless,
        "traffic": {
            "episodes": traffic_episodes,
            "rows": traffic,
            "policies": {
                name: {"switching": logic, "training": training_record(SHIPPED_DIR / shipped)}
                for name, logic in TRAFFIC_CONTROLLERS
                if (shipped := TRAFFIC_POLICIES.get(name)) is not None
            },
        },
        "sumo": sumo,
        "perception": perception,
        "wall_time_s": round(time.perf_counter() - began, 1),
    }
    write_json(folder / "summary.json", summary)
    write_atomic(folder / "report.md", render_markdown(summary))
    write_atomic(folder / "report.html", render_html(summary, folder))
    log(comparison_text(summary))
    log(f"report: {folder / 'report.html'} ({summary['wall_time_s']} s)")
    return summary
