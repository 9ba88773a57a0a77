"""``safeswitch falsify``: search the scenario space for the scenarios where a controller and a
switching logic fail — a collision, or (``--failure safety``) a safety action.

The search is the cross-entropy method (Rubinstein 1999; for falsification of automated
driving see e.g. Corso et al., *A Survey of Algorithms for Black-Box Safety Validation*, 2021):
scenarios are drawn from a Gaussian over the normalised scenario parameters (ego start distance
and speed, north speed, arrival offset, each within the configured range), every generation
is simulated in one batch per shard — the shards spread over Ray workers —, the most dangerous
3 % refit the Gaussian, and a tenth of each generation stays uniform so that other failure
regions can still be found. "Most dangerous" is tiered: collisions first, then episodes in which
the Safety controller acted (the logic judged the moment critical), then the smallest footprint
separation; and once a tier above the last holds a handful of episodes — in this generation
or kept from earlier ones —, the elite is drawn from it alone (:func:`_elite`). By separation
alone the search went to near misses far from where a trained policy's rare failures lie.
With the same budget, uniform random sampling of the same space runs alongside, so the report
can say how much better the search finds failures (failures per 1,000 simulated episodes).

The output folder holds ``summary.json`` (counts, the most dangerous scenarios with their
margins), ``scenarios.csv`` (every simulated scenario, its margin and the method that drew it)
and ``falsification.png`` (the failure regions).
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from safeswitch.app.distributed import check_reachable, cluster
from safeswitch.io import prepare_output_dir, replacing, write_json
from safeswitch.progress import Progress

#: The searched parameters, in the order of the normalised vector.
PARAMETERS = ("ego_start_distance_m", "ego_speed_kmh", "north_speed_kmh", "arrival_offset_s")
ELITE = 0.03
MIN_TIER = 5  # episodes a tier needs before the elite is drawn from it alone (see _elite)
UNIFORM_SHARE = 0.1
SMOOTHING = 0.7  # weight of the new elite statistics in the refit


@dataclass(frozen=True)
class Target:
    """What is being falsified: a baseline (``rule``, ``planner``), a trained policy
    (``learned`` with ``model``) or an adversary of the catalogue (``adversary:NAME``, driving
    the whole episode), under ``switching``."""

    controller: str
    model: str | None
    switching: str | None


def _setup(target: Target, batch: int, seed: int) -> tuple[Any, Any]:
    from safeswitch.app.evaluate import controller_setup
    from safeswitch.evaluation.adversaries import catalogue
    from safeswitch.leftturn.config import resolve_config
    from safeswitch.leftturn.task import LeftTurnTask

    if target.controller.startswith("adversary:"):
        name = target.controller.split(":", 1)[1]
        config = resolve_config(
            {"episode": {"learned_scope": "episode"}}, switching=target.switching or "paper"
        )
        task = LeftTurnTask(config)
        adversaries = catalogue(task, batch, seed)
        if name not in adversaries:
            raise ValueError(f"adversary {name!r} is not one of {', '.join(sorted(adversaries))}")
        return task, adversaries[name]()
    config, policy = controller_setup(target.controller, target.model, target.switching)
    if policy is None:
        raise ValueError("the oracle cannot fail: it plans with the north car's future")
    return LeftTurnTask(config), policy


def target_setup(target: Target, batch: int, seed: int) -> tuple[Any, Any]:
    """The task and the policy of a falsification target (adversaries drawn with ``seed``)."""
    return _setup(target, batch, seed)


def scenarios_of(values: np.ndarray) -> Any:
    """Scenarios from rows of :data:`PARAMETERS` values (km/h speeds) ``[N, 4]``."""
    from safeswitch.leftturn.scenarios import Scenarios

    return Scenarios(
        ego_start_distance=values[:, 0],
        ego_speed=values[:, 1] / 3.6,
        north_speed=values[:, 2] / 3.6,
        arrival_offset=values[:, 3],
    )


def simulate(target: Target, unit: np.ndarray, seed: int) -> np.ndarray:
    """Per scenario (rows of ``unit`` ``[N, 4]`` in [0, 1]): min separation [m], collision,
    safety ticks (a task, run in a worker)."""
    import torch

    from safeswitch.evaluation.rollout import rollout

    torch.set_num_threads(1)
    task, policy = _setup(target, unit.shape[0], seed)
    ranges = _ranges(task.config.scenarios)
    values = ranges[:, 0] + unit * (ranges[:, 1] - ranges[:, 0])
    scenarios = scenarios_of(values)
    result = rollout(task, scenarios, policy)
    return np.stack(
        [result.min_separation, result.collision.astype(float), result.safety_steps], axis=1
    )


def _ranges(config: Any) -> np.ndarray:
    return np.array(
        [config.ego_start_distance_m, config.ego_speed_kmh, config.north_speed_kmh,
         config.arrival_offset_s]
    )  # fmt: skip


def falsify(
    target: Target,
    out: str | Path,
    budget: int = 20_000,
    generation: int = 2_000,
    seed: int = 0,
    failure: str = "collision",
    workers: int = 2,
    address: str | None = None,
    overwrite: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Run the search and random sampling with the same budget; write the folder; return the
    summary.

    Raises:
        ValueError: A budget below one generation, an unknown failure kind or adversary.
    """
    if failure not in ("collision", "safety"):
        raise ValueError(f"--failure must be 'collision' or 'safety', got {failure!r}")
    if generation < 20 or budget < generation:
        raise ValueError(
            f"--budget ({budget}) must hold at least one --generation ({generation} >= 20)"
        )
    _setup(target, 2, seed)  # fail early on a bad controller, model or adversary
    if address is not None:
        check_reachable(address)  # before the folder is written
    folder = prepare_output_dir(out, overwrite)
    rng = np.random.default_rng(seed)
    generations = budget // generation
    shards = max(1, min(8, generation // 250))
    began = time.perf_counter()
    rows: list[tuple[str, int, np.ndarray, np.ndarray]] = []
    bar = Progress(2 * generations * generation, "falsify", enabled=progress)
    mean, std = np.full(4, 0.5), np.full(4, 0.3)
    kept_units, kept_outcome = np.empty((0, 4)), np.empty((0, 3))
    with cluster(workers, address) as where:

        def run(unit: np.ndarray, tag: int) -> np.ndarray:
            parts = np.array_split(unit, shards)
            results: list[np.ndarray | None] = [None] * len(parts)

            def keep(i: int, value: np.ndarray) -> None:
                results[i] = value

            def fail(i: int, error: BaseException) -> None:
                raise error

            args = [(target, part, seed + 7919 * tag + i) for i, part in enumerate(parts)]
            where.map(simulate, args, keep, fail)
            return np.concatenate([r for r in results if r is not None])

        for g in range(generations):
            uniform = rng.random((generation, 4))
            rows.append(("random", g, uniform, run(uniform, 2 * g)))
            bar.update(generation)
            searched = np.clip(rng.normal(mean, std, (generation, 4)), 0.0, 1.0)
            fresh = int(UNIFORM_SHARE * generation)
            searched[:fresh] = rng.random((fresh, 4))
            outcome = run(searched, 2 * g + 1)
            rows.append(("cross-entropy", g, searched, outcome))
            bar.update(generation)
            # the elite comes from this generation and every critical episode searched before
            pool_units = np.concatenate([searched, kept_units])
            pool_outcome = np.concatenate([outcome, kept_outcome])
            elite = pool_units[_elite(pool_outcome, failure, max(2, int(ELITE * generation)))]
            critical = _tier(outcome, failure) >= 1
            kept_units = np.concatenate([kept_units, searched[critical]])
            kept_outcome = np.concatenate([kept_outcome, outcome[critical]])
            mean = (1 - SMOOTHING) * mean + SMOOTHING * elite.mean(axis=0)
            std = np.maximum((1 - SMOOTHING) * std + SMOOTHING * elite.std(axis=0), 0.02)
        startup = where.startup_s
    bar.close()
    summary = _summarise(target, rows, failure, budget, generation, seed)
    summary["ray_startup_s"] = round(startup, 2)
    summary["wall_time_s"] = round(time.perf_counter() - began, 2)
    _write_scenarios(folder / "scenarios.csv", target, rows)
    write_json(folder / "summary.json", summary)
    from safeswitch.report.figures import falsification_figure

    falsification_figure(
        [(method, units, outcome) for method, _, units, outcome in rows],
        _ranges(_setup(target, 2, seed)[0].config.scenarios),
        failure,
        folder / "falsification.png",
    )
    return summary


def _danger(outcome: np.ndarray, failure: str) -> np.ndarray:
    """Smaller is more dangerous: the separation, or for safety failures the negated number of
    safety ticks (ties broken by the separation)."""
    if failure == "collision":
        return outcome[:, 0]
    return -outcome[:, 2] + 1e-3 * outcome[:, 0]


def _tier(outcome: np.ndarray, failure: str) -> np.ndarray:
    """How bad an episode was, coarsely: 2 a collision (when collisions are searched for), 1 a
    safety action (the logic itself judged the moment critical), 0 neither."""
    tier = (outcome[:, 2] > 0).astype(int)
    if failure == "collision":
        tier[outcome[:, 1] > 0] = 2
    return tier


def _elite(outcome: np.ndarray, failure: str, size: int) -> np.ndarray:
    """Indices of the generation's elite: the ``size`` most dangerous episodes (by tier, then
    by :func:`_danger`), but only from the highest tier that has at least ``MIN_TIER`` members
    when that tier is above 0. Ranked by separation alone, the search settles on near misses
    that are nowhere near where a policy's rare failures lie (its safety actions and collisions
    sit on the boundary between crossing first and giving way); seeded with the few episodes
    the logic judged critical, it goes there."""
    tier = _tier(outcome, failure)
    order = np.lexsort((_danger(outcome, failure), -tier))[:size]
    for level in (2, 1):
        if np.count_nonzero(tier >= level) >= MIN_TIER:
            return order[tier[order] >= level]
    return order


def _failed(outcome: np.ndarray, failure: str) -> np.ndarray:
    return outcome[:, 1] > 0 if failure == "collision" else outcome[:, 2] > 0


def _summarise(
    target: Target,
    rows: list[tuple[str, int, np.ndarray, np.ndarray]],
    failure: str,
    budget: int,
    generation: int,
    seed: int,
) -> dict[str, Any]:
    task, _ = _setup(target, 2, seed)
    ranges = _ranges(task.config.scenarios)
    methods: dict[str, Any] = {}
    for method in ("random", "cross-entropy"):
        units = np.concatenate([u for m, _, u, _ in rows if m == method])
        outcome = np.concatenate([o for m, _, _, o in rows if m == method])
        failed = _failed(outcome, failure)
        order = np.argsort(_danger(outcome, failure))[:10]
        span = np.ptp(ranges, axis=1)
        dangerous = []
        for i in order:
            values = ranges[:, 0] + units[i] * span
            dangerous.append(
                {
                    **dict(zip(PARAMETERS, map(float, values), strict=True)),
                    "min_separation_m": float(outcome[i, 0]),
                    "collision": bool(outcome[i, 1] > 0),
                    "safety_ticks": int(outcome[i, 2]),
                }
            )
        methods[method] = {
            "episodes": int(units.shape[0]),
            "failures": int(failed.sum()),
            "failures_per_1000": 1000.0 * float(failed.mean()),
            "min_separation_m": float(outcome[:, 0].min()),
            "most_dangerous": dangerous,
        }
    random_rate = methods["random"]["failures_per_1000"]
    search_rate = methods["cross-entropy"]["failures_per_1000"]
    return {
        "controller": target.controller,
        "model": target.model,
        "switching": task.config.switching,
        "failure": failure,
        "budget_per_method": budget,
        "generation": generation,
        "seed": seed,
        "methods": methods,
        "search_over_random": (search_rate / random_rate) if random_rate > 0 else None,
    }


def _write_scenarios(
    path: Path, target: Target, rows: list[tuple[str, int, np.ndarray, np.ndarray]]
) -> None:
    task, _ = _setup(target, 2, 0)
    ranges = _ranges(task.config.scenarios)
    with replacing(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(["method", "generation", *PARAMETERS, "min_separation_m", "collision",
                         "safety_ticks"])  # fmt: skip
        for method, g, units, outcome in rows:
            values = ranges[:, 0] + units * np.ptp(ranges, axis=1)
            for v, o in zip(values, outcome, strict=True):
                # every digit of the parameters: a counterexample must replay exactly
                writer.writerow([method, g, *(repr(float(x)) for x in v), f"{o[0]:.4f}",
                                 int(o[1]), int(o[2])])  # fmt: skip
