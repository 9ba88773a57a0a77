"""``safeswitch campaign``: an evaluation campaign over a scenario space × controllers ×
switching logics, split into shards that run as Ray tasks.

A *cell* is one controller (a baseline or a trained policy) under one switching logic; every
cell runs the same scenarios: random draws (a pure function of ``--seed`` and the scenario's
index), a grid over the scenario parameters, or the paper's three. Each cell's scenarios are cut
into shards of ``--shard-size`` episodes; a shard is one task: it simulates its episodes in
chunks on the batched task, writes one row per episode (Parquet with pyarrow, else CSV) and its
summary accumulator, each into a temporary file renamed into place — so a shard is on disk
whole or not at all. The summaries merge in shard order into the fields of ``safeswitch
evaluate`` (``summary.json``); they depend only on the seed and the shard size, never on how
many workers ran them. ``--resume`` skips the shards already on disk; a shard that fails is
reported with its cell and episode range, and the rest are kept.

Folder::

    campaign.json             what was asked (a resume must ask the same)
    shards/<cell>/<i>.parquet  the episodes of shard i (or .csv)
    shards/<cell>/<i>.json     its summary accumulator (written last)
    summary.json              per cell, and the failures
"""

from __future__ import annotations

import itertools
import json
import math
import sys
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from safeswitch.app.distributed import DistributedError, check_reachable, cluster
from safeswitch.app.evaluate import LONG_PLAN_S, NOMINAL_RATE, PARALLEL_EFFICIENCY
from safeswitch.io import replacing, write_atomic, write_json
from safeswitch.progress import Progress, format_duration

#: Scenario parameters a grid may span, with their unit conversion to the task's SI values.
GRID_PARAMETERS = {
    "ego_start_distance_m": ("ego_start_distance", 1.0),
    "ego_speed_kmh": ("ego_speed", 1 / 3.6),
    "north_speed_kmh": ("north_speed", 1 / 3.6),
    "arrival_offset_s": ("arrival_offset", 1.0),
}
#: Defaults of the parameters a grid leaves out (the paper's scenarios' values).
GRID_DEFAULTS = {
    "ego_start_distance_m": 36.0,
    "ego_speed_kmh": 25.0,
    "north_speed_kmh": 29.0,
    "arrival_offset_s": 0.0,
}
#: The largest grid accepted (episodes).
MAX_GRID = 100_000_000


class CampaignError(ValueError):
    """A campaign cannot run as asked; the message names the problem."""


@dataclass(frozen=True)
class Grid:
    """A grid over the scenario parameters, generated lazily by index.

    Attributes:
        axes: Parameter name → its values (see :data:`GRID_PARAMETERS`), in order.
    """

    axes: tuple[tuple[str, tuple[float, ...]], ...]

    @classmethod
    def parse(cls, specs: list[str]) -> Grid:
        """From ``name=start:stop:step`` (stop included), ``name=a,b,c`` or ``name=value``.

        Raises:
            CampaignError: An unknown parameter, a malformed range, an empty or too large grid.
        """
        axes: dict[str, tuple[float, ...]] = {}
        for spec in specs:
            name, _, values = spec.partition("=")
            if name not in GRID_PARAMETERS:
                raise CampaignError(
                    f"grid parameter {name!r} is not one of {', '.join(GRID_PARAMETERS)}"
                )
            try:
                if ":" in values:
                    start, stop, step = (float(v) for v in values.split(":"))
                    if step <= 0:
                        raise ValueError
                    count = math.floor((stop - start) / step + 1e-9) + 1
                    axes[name] = tuple(start + step * np.arange(max(count, 0)))
                else:
                    axes[name] = tuple(float(v) for v in values.split(","))
            except ValueError:
                raise CampaignError(
                    f"grid {spec!r}: expected name=start:stop:step (step > 0), name=a,b,c or "
                    "name=value"
                ) from None
        for name, default in GRID_DEFAULTS.items():
            axes.setdefault(name, (default,))
        grid = cls(tuple((name, axes[name]) for name in GRID_PARAMETERS))
        if grid.size == 0:
            empty = [n for n, v in grid.axes if not v]
            raise CampaignError(f"the grid is empty (no values for {', '.join(empty)})")
        if grid.size > MAX_GRID:
            raise CampaignError(
                f"the grid has {grid.size:,} scenarios, more than the {MAX_GRID:,} a campaign "
                "takes; use coarser steps"
            )
        return grid

    @property
    def size(self) -> int:
        return math.prod(len(v) for _, v in self.axes)

    def scenarios(self, start: int, stop: int) -> Any:
        """Scenarios ``start`` to ``stop`` of the grid (row-major over :attr:`axes`)."""
        from safeswitch.leftturn.scenarios import Scenarios

        index = np.unravel_index(np.arange(start, stop), [len(v) for _, v in self.axes])
        values = {
            GRID_PARAMETERS[name][0]: np.asarray(axis)[i] * GRID_PARAMETERS[name][1]
            for (name, axis), i in zip(self.axes, index, strict=True)
        }
        return Scenarios(**values)


@dataclass(frozen=True)
class Space:
    """The scenarios every cell runs.

    Attributes:
        kind: ``random``, ``grid`` or ``paper``.
        episodes: How many (random); the grid's size; 3 for the paper's.
        seed: Seed of the random scenarios.
        grid: The grid (``kind == "grid"``).
    """

    kind: str
    episodes: int
    seed: int
    grid: Grid | None = None

    def chunk(self, task: Any, start: int, stop: int) -> tuple[list[str], Any]:
        from safeswitch.evaluation.evaluate import scenario_set

        if self.kind == "random":
            ids = np.arange(start, stop)
            return [f"random-{i}" for i in ids], task.draw_scenarios(
                self.seed, ids, np.zeros(ids.size, dtype=int)
            )
        if self.kind == "grid":
            assert self.grid is not None
            return [f"grid-{i}" for i in range(start, stop)], self.grid.scenarios(start, stop)
        scenarios, names = scenario_set(task, "paper", 3, 0)
        return names[start:stop], scenarios.take(np.arange(start, stop))


@dataclass(frozen=True)
class Cell:
    """One controller under one switching logic (``switching=None``: its own), in the scene
    as ``settings`` (``env.KEY=VALUE``, see :func:`~safeswitch.app.evaluate.scene_settings`)
    change it."""

    controller: str
    model: str | None = None
    switching: str | None = None
    settings: tuple[str, ...] = ()

    def record(self) -> dict[str, Any]:
        """The cell as ``campaign.json`` keeps it (no ``settings`` when there are none: a
        campaign written before settings existed resumes)."""
        return {k: v for k, v in asdict(self).items() if k != "settings" or v}

    @property
    def key(self) -> str:
        parts = [self.controller]
        if self.model:
            parts.append(Path(self.model).name or self.model)
        if self.switching:
            parts.append(self.switching)
        return "-".join(p.replace("/", "_") for p in parts)


@dataclass(frozen=True)
class Shard:
    cell: Cell
    index: int
    start: int
    stop: int


@dataclass
class Failure:
    cell: str
    shard: int
    episodes: tuple[int, int]
    seed: int
    error: str


@dataclass
class CampaignResult:
    summary: dict[str, Any]
    failures: list[Failure] = field(default_factory=list)


def run_shard(shard: Shard, space: Space, folder: str) -> dict[str, Any]:
    """Evaluate one shard (in a worker): its episodes' rows and its accumulator, each written
    whole; returns the accumulator's state."""
    from safeswitch.app.evaluate import controller_setup
    from safeswitch.evaluation.evaluate import CHUNK, CSV_COLUMNS, episode_rows, run_controller
    from safeswitch.evaluation.metrics import SummaryAccumulator
    from safeswitch.leftturn.task import LeftTurnTask

    cell = shard.cell  # a policy is loaded with one torch thread (load_policy)
    config, policy = controller_setup(cell.controller, cell.model, cell.switching, cell.settings)
    task = LeftTurnTask(config)
    accumulator = SummaryAccumulator()
    rows: list[list[Any]] = []
    for start in range(shard.start, shard.stop, CHUNK):
        names, batch = space.chunk(task, start, min(start + CHUNK, shard.stop))
        result, plan = run_controller(task, policy, batch, trace=False)
        accumulator.add(result, plan.time_to_clear, config.episode.horizon_s)
        rows.extend(episode_rows(names, batch, result, plan.time_to_clear))
    out = Path(folder) / "shards" / cell.key
    out.mkdir(parents=True, exist_ok=True)
    _write_rows(out / f"{shard.index:06d}", CSV_COLUMNS, rows)
    state = accumulator.state()
    write_atomic(out / f"{shard.index:06d}.json", json.dumps(state))
    return state


def _write_rows(stem: Path, columns: tuple[str, ...], rows: list[list[Any]]) -> None:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        import csv

        with (
            replacing(stem.with_suffix(".csv")) as tmp,
            open(tmp, "w", newline="", encoding="utf-8") as handle,
        ):
            writer = csv.writer(handle)
            writer.writerow(columns)
            writer.writerows(rows)
        return
    table = pa.table({name: [row[j] for row in rows] for j, name in enumerate(columns)})
    with replacing(stem.with_suffix(".parquet")) as tmp:
        pq.write_table(table, tmp)


def shard_count(space: Space, shard_size: int) -> int:
    """Shards per cell (the last one may be short)."""
    return -(-space.episodes // shard_size)


def cell_shards(cell: Cell, space: Space, shard_size: int) -> Iterator[Shard]:
    """The cell's shards in order, generated one at a time (a campaign of any length holds
    none of them in memory)."""
    for k, start in enumerate(range(0, space.episodes, shard_size)):
        yield Shard(cell, k, start, min(start + shard_size, space.episodes))


def estimate_s(cells: list[Cell], space: Space, workers: int) -> float:
    """The campaign's expected wall time on ``workers`` workers (at least one) [s]."""
    one = sum(space.episodes / NOMINAL_RATE.get(c.controller, 1_000.0) for c in cells)
    return one if workers <= 1 else one / (workers * PARALLEL_EFFICIENCY)


def plan_lines(cells: list[Cell], space: Space, shard_size: int, workers: int | None) -> list[str]:
    """What a campaign prints before it starts: its size and its estimated wall time, and a
    warning if that runs past :data:`LONG_PLAN_S`."""
    shards = shard_count(space, shard_size)
    where = f"{workers} workers" if workers is not None else "the cluster's workers"
    seconds = estimate_s(cells, space, workers if workers is not None else 1)
    lines = [
        f"campaign: {len(cells)} cell(s) × {shards:,} shard(s) of up to {shard_size:,} "
        f"episodes = {len(cells) * space.episodes:,} episodes on {where}; estimated "
        f"{format_duration(seconds)}"
    ]
    if seconds > LONG_PLAN_S:
        lines.append(
            f"warning: this campaign would run for about {format_duration(seconds)}; Ctrl-C "
            "stops it and --resume continues it, or ask for fewer --episodes"
        )
    return lines


def _check_cells(cells: list[Cell]) -> None:
    """Every cell's controller, policy and logic, as a shard will build them (raises before
    anything is written)."""
    from safeswitch.app.evaluate import controller_setup
    from safeswitch.leftturn.task import LeftTurnTask

    for cell in cells:
        config, _ = controller_setup(cell.controller, cell.model, cell.switching, cell.settings)
        LeftTurnTask(config)  # builds the logic: one that does not fit the left turn is named


def campaign(
    cells: list[Cell],
    space: Space,
    out: str | Path,
    workers: int = 2,
    address: str | None = None,
    resume: bool = False,
    shard_size: int = 10_000,
    progress: bool = True,
) -> CampaignResult:
    """Run (or resume) a campaign and write its folder (see the module docstring).

    Everything is checked before the folder is touched: the cells (their policies and logics),
    the shard size, the workers, the cluster's address and the folder itself. Then one plan
    line (and a warning for a long plan) goes to standard error, unless ``progress`` is off.
    Shards are generated, run and merged one at a time, so memory stays bounded whatever
    ``space.episodes`` is.

    Raises:
        CampaignError: No cells, a shard size below 1, or the folder holds another campaign,
            or a campaign without ``resume``.
        DistributedError: Bad workers, Ray missing or ``address`` not a reachable Ray head.
    """
    from safeswitch.evaluation.metrics import SummaryAccumulator

    folder = Path(out)
    if not cells:
        raise CampaignError("a campaign needs at least one controller")
    if shard_size < 1:
        raise CampaignError(f"--shard-size must be >= 1, got {shard_size}")
    if workers < 0:
        raise DistributedError(f"--workers must be >= 0, got {workers}")
    asked = {
        "cells": [c.record() for c in cells],
        "space": {
            "kind": space.kind,
            "episodes": space.episodes,
            "seed": space.seed,
            "grid": [list(a) for a in space.grid.axes] if space.grid else None,
        },
        "shard_size": shard_size,
    }
    record = folder / "campaign.json"
    if folder.exists() and not folder.is_dir():
        raise CampaignError(f"--out {folder} is a file, not a folder")
    if record.is_file():
        if not resume:
            raise CampaignError(f"{folder} holds a campaign; --resume it or choose another --out")
        if json.loads(record.read_text(encoding="utf-8")) != json.loads(json.dumps(asked)):
            raise CampaignError(f"{folder} holds a different campaign; --resume must ask the same")
    elif folder.is_dir() and any(folder.iterdir()):
        raise CampaignError(f"--out {folder} is not empty and holds no campaign")
    if address is not None:  # a typo or a foreign service leaves no campaign behind
        check_reachable(address)
    _check_cells(cells)
    if progress:
        for line in plan_lines(cells, space, shard_size, workers if address is None else None):
            print(line, file=sys.stderr, flush=True)
    folder.mkdir(parents=True, exist_ok=True)
    write_json(record, asked)

    accumulators = {cell.key: SummaryAccumulator() for cell in cells}
    merged = dict.fromkeys(accumulators, 0)  # shards merged per cell
    failures: list[Failure] = []
    bar = Progress(len(cells) * space.episodes, "campaign", enabled=progress)
    inflight: dict[int, Shard] = {}  # task index → its shard, while the cluster runs it
    task_index = itertools.count()
    ran_now = 0  # shards the cluster handed back

    def todo() -> Iterator[tuple[Shard, Space, str]]:
        """The shards still to run, in order; those already on disk are merged as they are
        met. Consumed lazily by the cluster (task ``j`` is the ``j``-th shard yielded)."""
        for cell in cells:
            for shard in cell_shards(cell, space, shard_size):
                path = folder / "shards" / cell.key / f"{shard.index:06d}.json"
                if path.is_file():
                    merge(shard, json.loads(path.read_text(encoding="utf-8")))
                    bar.skip(shard.stop - shard.start)
                    continue
                inflight[next(task_index)] = shard
                yield shard, space, str(folder)

    def merge(shard: Shard, state: dict[str, Any]) -> None:
        accumulators[shard.cell.key].merge(SummaryAccumulator.from_state(state))
        merged[shard.cell.key] += 1

    def shard_of(j: int) -> Shard:
        nonlocal ran_now
        ran_now += 1
        return inflight.pop(j)

    began = time.perf_counter()
    with cluster(workers, address) as where:

        def finished(j: int, state: dict[str, Any]) -> None:
            shard = shard_of(j)
            merge(shard, state)
            bar.update(shard.stop - shard.start)

        def failed(j: int, error: BaseException) -> None:
            s = shard_of(j)
            failures.append(
                Failure(s.cell.key, s.index, (s.start, s.stop), space.seed, _one_line(error))
            )
            bar.update(s.stop - s.start)

        where.map(run_shard, todo(), finished, failed)
        startup = where.startup_s
    bar.close()
    # in shard order, not in the order the workers happened to report them
    failures.sort(key=lambda f: (f.cell, f.shard))
    per_cell: dict[str, Any] = {}
    shards = shard_count(space, shard_size)
    for cell in cells:
        per_cell[cell.key] = {
            **asdict(cell),
            "scenarios": space.kind,
            "seed": space.seed,
            "complete": merged[cell.key] == shards,
            **accumulators[cell.key].summary(),
        }
    summary = {
        "cells": per_cell,
        "failures": [asdict(f) for f in failures],
        "shards": shards * len(cells),
        "shards_run_now": ran_now,
        "workers": workers if address is None else None,
        "address": address,
        "ray_startup_s": round(startup, 2),
        "wall_time_s": round(time.perf_counter() - began, 2),
    }
    write_json(folder / "summary.json", summary)
    return CampaignResult(summary, failures)


def _one_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    cause = getattr(error, "cause", None)  # RayTaskError keeps the task's own exception
    if cause is not None:
        return f"{type(cause).__name__}: {str(cause).strip().splitlines()[-1]}"
    return f"{type(error).__name__}: {text[-1] if text else ''}"
