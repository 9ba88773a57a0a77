"""``safeswitch reproduce``: the paper's Section VI experiments and our comparisons, end to end.

Every controller (the oracle, the rule-based system, the planner, and the PPO policies trained
with the ``paper`` switching logic — warm-started from the planner, and from scratch — without
``R_ADAS``, with the ``certified`` logic and with none) is evaluated on the paper's three
scenarios (traced tick by tick: the figures) and on random scenarios (the comparison table).
``--quick`` uses the shipped policies; without it, the five policies are first trained with the
shipped configurations.

The report folder holds ``report.html`` (self-contained: figures, animations and tables embedded),
``report.md`` (the same, with the pictures beside it), ``summary.json`` and the per-episode CSVs
in ``raw/``. ``report.html`` is written last: a folder without it is incomplete.
"""

from __future__ import annotations

import base64
import html
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from safeswitch.app.evaluate import controller_setup
from safeswitch.evaluation.adversaries import constant
from safeswitch.evaluation.evaluate import (
    episodes_csv,
    run_controller,
    scenario_set,
    summary_against_oracle,
)
from safeswitch.evaluation.metrics import summarize
from safeswitch.evaluation.oracle import OraclePlan, efficiency
from safeswitch.evaluation.rollout import rollout
from safeswitch.io import write_atomic
from safeswitch.leftturn.config import SCENARIO_NAMES, LeftTurnConfig
from safeswitch.leftturn.task import OUTCOMES, LeftTurnTask
from safeswitch.report.figures import Trace, comparison_figure, episode_figure, frames_strip
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
        "PPO, paper switching, R_ADAS on, warm-started from the planner (shipped)",
    ),
    Entry(
        "ppo-paper-scratch",
        "learned",
        "paper_scratch",
        "PPO, paper switching, R_ADAS on, from scratch (the paper's recipe)",
    ),
    Entry("ppo-no-adas", "learned", "no_adas", "PPO, paper switching, R_ADAS off (ablation)"),
    Entry("ppo-certified", "learned", "certified", "PPO, certified switching"),
    Entry("ppo-unshielded", "learned", "none", "PPO trained and run without switching logic"),
)

#: Columns of the comparison table: (summary key, header, format).
TABLE = (
    ("collisions", "collisions", "{:d}"),
    ("safety_activation_episodes", "safety episodes", "{:d}"),
    ("comfort_violation_fraction", "comfort viol. ticks", "{:.2%}"),
    ("stops", "full stops", "{:d}"),
    ("cut_episodes", "cut", "{:d}"),
    ("yield_episodes", "yield", "{:d}"),
    ("mean_time_to_clear_s", "time to clear [s]", "{:.2f}"),
    ("mean_efficiency", "oracle time / time", "{:.3f}"),
    ("mean_return", "return", "{:.0f}"),
)


def train_policies(out: Path, timesteps: int | None) -> dict[str, Path]:
    """Train the five policies with their shipped configurations, into
    ``out/runs/``; a finished run is reused and an interrupted one resumed."""
    from safeswitch.app.train import train_and_plot
    from safeswitch.training.run import complete_checkpoints

    runs = {}
    for entry in ENTRIES:
        if entry.policy is None:
            continue
        config = load_config(SHIPPED_DIR / entry.policy / "config.yaml")
        if timesteps is not None:
            config = replace(config, timesteps=timesteps)
        run = out / "runs" / entry.policy
        runs[entry.policy] = run
        if (run / "metrics.json").is_file():  # finished by an earlier, interrupted reproduce
            print(f"reusing the finished run {run}", flush=True)
            continue
        print(f"training {entry.name} ({config.timesteps:,} steps) into {run}", flush=True)
        train_and_plot(config, run, resume=bool(complete_checkpoints(run)), progress_bar=False)
    return runs


def _paper_findings(paper: dict[str, Any], ablation: dict[str, Any]) -> list[tuple[str, bool]]:
    """The paper's Section VI observations, checked on the traced paper scenarios."""
    cut, y1, y2 = (paper[name] for name in SCENARIO_NAMES)
    return [
        (
            "cut: the ego passes before the north car without a safety activation",
            cut["outcome"] == "cut" and cut["safety_steps"] == 0,
        ),
        (
            "yield1: the ego passes after the north car, without a stop or a safety activation",
            y1["outcome"] == "yield" and y1["safety_steps"] == 0 and y1["min_speed_kmh"] > 0.36,
        ),
        (
            "yield2: the ego slows further than in yield1",
            y2["outcome"] == "yield" and y2["min_speed_kmh"] < y1["min_speed_kmh"],
        ),
        (
            "ablation (no R_ADAS): the Safety controller acts in a yield scenario",
            ablation["yield1"]["safety_steps"] > 0 or ablation["yield2"]["safety_steps"] > 0,
        ),
    ]


def _reckless(episodes: int) -> list[dict[str, Any]]:
    """A reckless learned controller (full throttle) under each switching logic."""
    rows = []
    for switching in ("none", "paper", "certified"):
        task = LeftTurnTask(LeftTurnConfig(switching=switching))
        batch, _ = scenario_set(task, "random", episodes, EVAL_SEED)
        summary = summarize(rollout(task, batch, constant(1.0)))
        rows.append({"switching": switching, **summary})
    return rows


def reproduce(
    out: str | Path,
    quick: bool = True,
    episodes: int = 1000,
    timesteps: int | None = None,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Run the experiments and write the report folder; returns the summary."""
    began = time.perf_counter()
    folder = Path(out)
    (folder / "raw").mkdir(parents=True, exist_ok=True)
    (folder / "figures").mkdir(exist_ok=True)
    models: dict[str, str] = {}
    if quick:
        models = {e.policy: str(SHIPPED_DIR / e.policy) for e in ENTRIES if e.policy}
    else:
        models = {k: str(v) for k, v in train_policies(folder, timesteps).items()}

    results: dict[str, Any] = {}
    random_rows = []
    offsets = None
    oracle_random = None
    # The oracle's plans depend on neither the switching logic, R_ADAS nor who drives: one
    # plan per remaining configuration and scenario set serves every controller.
    plans: dict[tuple[LeftTurnConfig, str], OraclePlan] = {}
    for entry in ENTRIES:
        model = models.get(entry.policy) if entry.policy else None
        config, policy = controller_setup(entry.kind, model, None)
        task = LeftTurnTask(config)
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
            per_scenario[name] = {
                "outcome": OUTCOMES[int(paper_result.outcome[i])],
                "safety_steps": int(paper_result.safety_steps[i]),
                "min_speed_kmh": float(paper_result.min_speed[i] * 3.6),
                "time_to_clear_s": float(paper_result.time_to_clear[i]),
                "oracle_time_to_clear_s": float(paper_plan.time_to_clear[i]),
                "comfort_violation_steps": int(paper_result.comfort_violation_steps[i]),
                "collision": bool(paper_result.collision[i]),
            }
        results[entry.name] = {
            "label": entry.label,
            "model": model,
            "switching": config.switching if policy is not None else None,
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
            random_rows.append((entry.name, random_result.time_to_clear, ratio))
            for i, name in enumerate(names):
                episode_figure(
                    trace,
                    i,
                    f"{entry.label} — scenario {name}",
                    folder / "figures" / f"{entry.name}_{name}.png",
                    oracle_speed=paper_plan.speed[i],
                )
        for i in trace.frames:
            (folder / "figures" / f"{entry.name}_{names[i]}.gif").write_bytes(trace.gif(i))
            frames_strip(trace, i).save(folder / "figures" / f"{entry.name}_{names[i]}_strip.png")
        log(f"  {entry.name:15s} evaluated ({time.perf_counter() - began:.0f} s)")

    assert offsets is not None and oracle_random is not None
    comparison_figure(random_rows, oracle_random, offsets, folder / "figures" / "comparison.png")
    findings = _paper_findings(results["ppo-paper"]["paper"], results["ppo-no-adas"]["paper"])
    reckless = _reckless(episodes)
    summary = {
        "quick": quick,
        "episodes": episodes,
        "seed": EVAL_SEED,
        "controllers": results,
        "paper_findings": [{"finding": f, "reproduced": ok} for f, ok in findings],
        "reckless_full_throttle": reckless,
        "wall_time_s": round(time.perf_counter() - began, 1),
    }
    write_atomic(folder / "summary.json", json.dumps(summary, indent=2))
    markdown = render_markdown(summary)
    write_atomic(folder / "report.md", markdown)
    write_atomic(folder / "report.html", render_html(summary, folder))
    log(comparison_text(summary))
    log(f"report: {folder / 'report.html'} ({summary['wall_time_s']} s)")
    return summary


# -- rendering ------------------------------------------------------------------------------


def _format(result: dict[str, Any], key: str, fmt: str) -> str:
    value = result[key]
    if isinstance(value, float) and not np.isfinite(value):
        return "never" if key == "mean_time_to_clear_s" else "–"
    return fmt.format(value)


def _cells(summary: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    header = ["controller", *(h for _, h, _ in TABLE)]
    rows = []
    for name, result in summary["controllers"].items():
        r = result["random"]
        rows.append([name, *(_format(r, key, fmt) for key, _, fmt in TABLE)])
    return header, rows


def _paper_cells(summary: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    header = ["controller", *SCENARIO_NAMES]
    rows = []
    for name, result in summary["controllers"].items():
        row = [name]
        for scenario in SCENARIO_NAMES:
            s = result["paper"][scenario]
            row.append(
                f"{s['outcome']}, {s['time_to_clear_s']:.2f} s "
                f"(oracle {s['oracle_time_to_clear_s']:.2f}), min {s['min_speed_kmh']:.1f} km/h, "
                f"safety {s['safety_steps']} ticks"
            )
        rows.append(row)
    return header, rows


def _reckless_cells(summary: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    header = ["switching logic", "collisions", "safety episodes"]
    rows = [
        [r["switching"], str(r["collisions"]), str(r["safety_activation_episodes"])]
        for r in summary["reckless_full_throttle"]
    ]
    return header, rows


def _markdown_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def comparison_text(summary: dict[str, Any]) -> str:
    """The comparison table as aligned text (printed at the end of a run)."""
    header, rows = _cells(summary)
    widths = [max(len(x) for x in col) for col in zip(header, *rows, strict=True)]
    lines = [
        f"{summary['episodes']} random scenarios (seed {summary['seed']}):",
        "  ".join(h.rjust(w) for h, w in zip(header, widths, strict=True)),
    ]
    lines += ["  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in rows]
    lines.append("Paper findings (the paper policy in the paper scenarios):")
    lines += [
        f"  [{'x' if f['reproduced'] else ' '}] {f['finding']}" for f in summary["paper_findings"]
    ]
    return "\n".join(lines)


def _figure_list(summary: dict[str, Any]) -> list[tuple[str, str]]:
    """The report's PNG figures in order, as (file stem, caption)."""
    out = [("comparison", "Time to clear against the north car's arrival; mean efficiency")]
    for name, result in summary["controllers"].items():
        if name == "oracle":
            continue
        for scenario in SCENARIO_NAMES:
            out.append((f"{name}_{scenario}", f"{result['label']}, scenario {scenario}"))
    return out


_INTRO = (
    "Reproduction of the experiments of Aksjonov & Kyrki (Section VI) on safeswitch's embedded "
    "simulator, with the baselines and the oracle the paper did not have. Efficiency is the "
    "oracle's time to clear the conflict zone divided by the controller's, per scenario "
    "(an episode that never clears counts with the whole 12 s horizon). The oracle is a point "
    "mass planned within the speed limit plus tolerated speeding, the comfort limits and "
    "without sharing the conflict zone; it has no actuator lags, so it bounds every controller "
    "that keeps the same limits."
)


def render_markdown(summary: dict[str, Any]) -> str:
    parts = [
        "# safeswitch: reproduction report",
        "",
        _INTRO,
        "",
        f"Policies: {'shipped (--quick)' if summary['quick'] else 'trained from scratch'}. "
        f"Wall time {summary['wall_time_s']} s.",
        "",
        f"## Comparison on {summary['episodes']} random scenarios (seed {summary['seed']})",
        "",
        _markdown_table(*_cells(summary)),
        "",
        "![comparison](figures/comparison.png)",
        "",
        "## The paper's scenarios",
        "",
        _markdown_table(*_paper_cells(summary)),
        "",
        "### Paper findings",
        "",
        *(
            f"- {'reproduced' if f['reproduced'] else '**not reproduced**'}: {f['finding']}"
            for f in summary["paper_findings"]
        ),
        "",
        "### Animations (the paper policy)",
        "",
        *(
            f"![{s}](figures/ppo-paper_{s}.gif)  \n![{s} strip](figures/ppo-paper_{s}_strip.png)"
            for s in SCENARIO_NAMES
        ),
        "",
        "## A reckless learned controller (full throttle)",
        "",
        _markdown_table(*_reckless_cells(summary)),
        "",
        "## Episode figures (Figs. 8–11 of the paper)",
        "",
        "Control signals, speeds, longitudinal and lateral acceleration (comfort limits dashed); "
        "grey: both cars at the intersection; red: safety action executed; dotted: the ego "
        "leaves the conflict zone; dashed grey speed: the oracle.",
        "",
        *(f"![{cap}](figures/{stem}.png)" for stem, cap in _figure_list(summary)[1:]),
        "",
    ]
    return "\n".join(parts)


def _html_table(header: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _embed(path: Path, alt: str) -> str:
    mime = "image/gif" if path.suffix == ".gif" else "image/png"
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<figure><img alt="{html.escape(alt)}" src="data:{mime};base64,{data}"/>' + (
        f"<figcaption>{html.escape(alt)}</figcaption></figure>"
    )


def render_html(summary: dict[str, Any], folder: Path) -> str:
    """The report as one self-contained HTML page (every picture embedded as a data URI)."""
    figures = folder / "figures"
    findings = "".join(
        f"<li>{'✔ reproduced' if f['reproduced'] else '✘ not reproduced'}: "
        f"{html.escape(f['finding'])}</li>"
        for f in summary["paper_findings"]
    )
    gifs = "".join(
        _embed(figures / f"ppo-paper_{s}.gif", f"paper policy, {s}") for s in SCENARIO_NAMES
    )
    episode_figs = "".join(
        _embed(figures / f"{stem}.png", caption) for stem, caption in _figure_list(summary)[1:]
    )
    style = (
        "body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em}"
        "table{border-collapse:collapse;font-size:13px;margin:1em 0}"
        "td,th{border:1px solid #bbb;padding:3px 6px;text-align:right}"
        "td:first-child,th:first-child{text-align:left}"
        "figure{display:inline-block;margin:0.5em}figcaption{font-size:12px;color:#444}"
        "img{max-width:100%}"
    )
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>safeswitch reproduction report</title>
<style>{style}</style></head><body>
<h1>safeswitch: reproduction report</h1>
<p>{html.escape(_INTRO)}</p>
<p>Policies: {"shipped (--quick)" if summary["quick"] else "trained from scratch"}.
Wall time {summary["wall_time_s"]} s.</p>
<h2>Comparison on {summary["episodes"]} random scenarios (seed {summary["seed"]})</h2>
{_html_table(*_cells(summary))}
{_embed(figures / "comparison.png", "time to clear against the north car's arrival")}
<h2>The paper's scenarios</h2>
{_html_table(*_paper_cells(summary))}
<h3>Paper findings</h3><ul>{findings}</ul>
<h3>Animations (the paper policy, twice real time)</h3>{gifs}
<h2>A reckless learned controller (full throttle)</h2>
{_html_table(*_reckless_cells(summary))}
<h2>Episode figures (Figs. 8–11 of the paper)</h2>
<p>Control signals, speeds, longitudinal and lateral acceleration (comfort limits dashed);
grey: both cars at the intersection; red: safety action executed; dotted: the ego leaves the
conflict zone; dashed grey speed: the oracle.</p>
{episode_figs}
</body></html>
"""
