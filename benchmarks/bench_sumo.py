"""SUMO as a second simulator: speed, the certified logic's safety, and the shipped policies on
both simulators.

1. **Speed.** Steps per second of ``safeswitch/LeftTurnSumo-v0`` (one process, SUMO driving
   the north car) and of ``safeswitch/LeftTurn-v0`` (the embedded simulator, a batch of one),
   measured alternately in the same run, constant action, resets included; their ratio.
2. **Safety.** Every adversary drives whole episodes of random scenarios on SUMO under the
   certified logic (``--episodes`` scenarios × 8 adversaries): collisions by our footprint
   check and by SUMO's, and the episodes in which SUMO's north car broke the logic's
   assumptions (counted, not hidden); the paper logic's collisions in the same episodes.
3. **Cross-simulator.** The shipped policies and the rule-based controller on the same random
   scenarios, embedded vs SUMO: collisions, safety activations, time to clear, comfort.

``--traffic`` measures the same three in traffic from every leg instead (SUMO driving every
other vehicle): the single Env's speed in the ``heavy`` preset; every adversary under
``certified`` and ``paper`` at each density (light, medium, heavy and the test split; two
worker processes, one SUMO each), with SUMO's collisions and the episodes in which any of its
drivers broke the certified assumptions; the rule and the shipped ``paper`` policy under both
logics in medium traffic, embedded vs SUMO. It writes the ``traffic`` entry of the results
file and keeps the rest.

Run: ``python benchmarks/bench_sumo.py [--json] [--episodes N] [--compare N] [--traffic]
[--cross-only]``; writes ``benchmarks/results/sumo.json`` (``--cross-only`` re-measures 3.
alone, e.g. after a shipped policy was retrained, and keeps the rest; with ``--traffic``, the
traffic part's 3.). Needs ``pip install
'safeswitch[sumo]'``. The single-car run takes about 25 minutes, ``--traffic`` about 20 (two
cores).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

import _common
from safeswitch.app.evaluate import evaluate
from safeswitch.evaluation.adversaries import catalogue
from safeswitch.evaluation.rollout import rollout
from safeswitch.io import write_json
from safeswitch.leftturn import LeftTurnEnv
from safeswitch.sumo.task import LeftTurnSumoEnv, sumo_task

RESULTS = Path(__file__).parent / "results" / "sumo.json"
ADVERSARIES = ("uniform", "bang_bang", "full_throttle", "zero_throttle", "enter_then_stop",
               "creep", "nan_inf", "noisy_cruise")  # fmt: skip
COMPARED = (("learned", "shipped"), ("learned", "certified"), ("learned", "paper-scratch"),
            ("rule", None))  # fmt: skip
TRAFFIC_PRESETS = ("light", "medium", "heavy", "test")
KEYS = ("failures", "collisions", "lost_control_episodes", "safety_activation_episodes",
        "cleared_episodes", "mean_time_to_clear_s", "comfort_violation_fraction",
        "mean_efficiency")  # fmt: skip


def steps_per_s(env: Any, steps: int) -> float:
    """Steps per second of ``env`` at a constant action, resets included."""
    env.reset(seed=0)
    action = np.array([0.3], dtype=np.float32)
    began = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - began)


def speed(rounds: int = 3, steps: int = 3000, traffic: str | None = None) -> dict[str, float]:
    sumo, ours = LeftTurnSumoEnv(traffic=traffic), LeftTurnEnv(traffic=traffic)
    rates: dict[str, list[float]] = {"sumo": [], "embedded": []}
    for _ in range(rounds):
        rates["sumo"].append(steps_per_s(sumo, steps))
        rates["embedded"].append(steps_per_s(ours, steps))
    sumo.close()
    out = {name: float(np.median(values)) for name, values in rates.items()}
    out["sumo_to_embedded"] = out["sumo"] / out["embedded"]
    print(
        f"single env{'' if traffic is None else ' in ' + traffic + ' traffic'}: "
        f"SUMO {out['sumo']:,.0f} steps/s, embedded {out['embedded']:,.0f} steps/s "
        f"(ratio {out['sumo_to_embedded']:.2f})",
        file=sys.stderr,
    )
    return out


def safety_cell(
    switching: str, name: str, episodes: int, traffic: str | None = None
) -> dict[str, object]:
    """One adversary's episodes under one logic (a worker process may run it: it opens and
    closes its own SUMO)."""
    task = sumo_task({"episode": {"learned_scope": "episode"}}, traffic, switching=switching)
    row = {"switching": switching, "adversary": name, "episodes": episodes, "collisions": 0,
           "lost_control": 0, "sumo_collision_episodes": 0,
           "assumption_break_episodes": 0}  # fmt: skip
    if traffic is not None:
        row["traffic"] = traffic
    try:
        for k in range(episodes):
            scenario = task.draw_scenarios(2024, np.array([k]), np.zeros(1, int))
            result = rollout(task, scenario, catalogue(task, 1, k)[name]())
            row["collisions"] += int(result.collision[0])  # type: ignore[operator]
            row["lost_control"] += int(result.lost_control[0])  # type: ignore[operator]
            row["sumo_collision_episodes"] += int(task.sumo_collisions > 0)  # type: ignore[operator]
            row["assumption_break_episodes"] += int(task.assumption_breaks)  # type: ignore[operator]
    finally:
        task.close()
    return row


def safety(episodes: int) -> list[dict[str, object]]:
    rows = []
    for switching in ("certified", "paper"):
        for name in ADVERSARIES:
            rows.append(safety_cell(switching, name, episodes))
            print(f"  {switching:9} {name:16} {rows[-1]}", file=sys.stderr)
    return rows


def traffic_safety(episodes: int, workers: int = 2) -> list[dict[str, object]]:
    jobs = [(s, name, episodes, preset) for preset in TRAFFIC_PRESETS
            for s in ("certified", "paper") for name in ADVERSARIES]  # fmt: skip
    with _common.pool(workers) as pool:
        rows = list(pool.map(safety_cell, *zip(*jobs, strict=True)))
    for row in rows:
        print(f"  {row}", file=sys.stderr)
    return rows


def totals(rows: list[dict[str, object]]) -> dict[str, dict[str, int]]:
    keys = (
        "episodes",
        "collisions",
        "lost_control",
        "sumo_collision_episodes",
        "assumption_break_episodes",
    )
    return {
        s: {k: sum(int(r[k]) for r in rows if r["switching"] == s) for k in keys}  # type: ignore[call-overload]
        for s in ("certified", "paper")
    }


def cross(episodes: int, traffic: str | None = None) -> list[dict[str, object]]:
    rows = []
    compared = COMPARED
    if traffic is not None:  # the shipped paper policy under both logics, and the rule
        compared = (("learned", "shipped"), ("rule", None))
    for controller, model in compared:
        for switching in (None,) if traffic is None else ("paper", "certified"):
            for sim in ("embedded", "sumo"):
                summary = evaluate(controller, model, "random", episodes, 7, switching, None,
                                   sim=sim, traffic=traffic)  # fmt: skip
                row = {"controller": controller, "model": model, "sim": sim,
                       **{k: summary[k] for k in KEYS}}  # fmt: skip
                if traffic is not None:
                    row["traffic"], row["switching"] = traffic, switching
                if sim == "sumo":
                    row["sumo_collision_episodes"] = summary["sumo_collision_episodes"]
                    row["assumption_break_episodes"] = summary["assumption_break_episodes"]
                rows.append(row)
                print(f"  {row}", file=sys.stderr)
    return rows


def patience_check(episodes: int, traffic: str = "medium") -> list[dict[str, object]]:
    """The rule under ``paper`` on the embedded simulator with drivers who never stop giving
    way to a waiting ego (``patience_s`` 60 instead of 2): how much of the difference between
    the simulators under ``paper`` is our drivers' patience (SUMO's have none)."""
    from safeswitch.app.evaluate import controller_setup
    from safeswitch.evaluation.evaluate import run_controller, scenario_set
    from safeswitch.leftturn.make import build_task

    config, rule = controller_setup("rule", None, "paper")
    rows = []
    for patience in (2.0, 60.0):
        task = build_task(None, config, traffic={"preset": traffic, "patience_s": patience})
        scenes, _ = scenario_set(task, "random", episodes, 7)
        result, _ = run_controller(task, rule, scenes, trace=False)
        rows.append({"patience_s": patience, "collisions": int((result.collision > 0).sum()),
                     "lost_control": int(result.lost_control.sum()),
                     "cleared_episodes": int(np.isfinite(result.time_to_clear).sum())})  # fmt: skip
        print(f"  rule / paper, embedded, patience {patience:g} s: {rows[-1]}", file=sys.stderr)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument(
        "--episodes",
        type=int,
        default=None,
        help="per adversary and logic (default 250; in traffic 12 per density)",
    )
    parser.add_argument(
        "--compare",
        type=int,
        default=None,
        help="episodes per simulator (default 200; in traffic 100)",
    )
    parser.add_argument("--traffic", action="store_true", help="traffic from every leg")
    parser.add_argument(
        "--cross-only",
        action="store_true",
        help="re-measure only the cross-simulator comparison (3.; with --traffic, the traffic "
        "part's), keep the rest",
    )
    args = parser.parse_args()  # fmt: skip
    previous = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    if args.cross_only:
        part_name = "traffic" if args.traffic else "single-car"
        measured = previous.get("traffic", {}) if args.traffic else previous
        if "safety" not in measured:
            parser.error(f"--cross-only needs a results file with the {part_name} part")
        if args.traffic:
            crossed = {**measured, "cross_simulator": cross(args.compare or 100, "medium")}
            result = {**previous, "traffic": crossed}
        else:
            result = {**previous, "cross_simulator": cross(args.compare or 200)}
    elif args.traffic:
        episodes, compare = args.episodes or 12, args.compare or 100
        rows = traffic_safety(episodes)
        part: dict[str, object] = {
            "machine": _common.machine(),
            "speed": speed(steps=1500, traffic="heavy"),
            "safety": rows,
            "safety_totals": totals(rows),
            "safety_by_density": {
                p: totals([r for r in rows if r["traffic"] == p]) for p in TRAFFIC_PRESETS
            },
            "cross_simulator": cross(compare, "medium"),
            "patience": patience_check(compare),
        }
        print(json.dumps(part["safety_totals"]), file=sys.stderr)
        result = {**previous, "traffic": part}
    else:
        episodes, compare = args.episodes or 250, args.compare or 200
        result = {"machine": _common.machine(), "speed": speed()}
        rows = safety(episodes)
        result["safety"] = rows
        result["safety_totals"] = totals(rows)
        print(json.dumps(result["safety_totals"]), file=sys.stderr)
        result["cross_simulator"] = cross(compare)
        if "traffic" in previous:
            result["traffic"] = previous["traffic"]
    RESULTS.parent.mkdir(exist_ok=True)
    write_json(RESULTS, result)
    _common.emit(result, args.json)


if __name__ == "__main__":
    main()
