"""``safeswitch sweep``: a training configuration over several seeds and hyper-parameter values,
the runs in parallel as Ray tasks, each a normal run directory, and a table across them.

``--set ppo.gamma=0.99,0.995`` varies a key (a dotted path into the configuration) over the
listed values; several ``--set`` make a grid; every combination runs with every seed. A run
that finished earlier is reused, one that was interrupted is resumed from its checkpoint, so
``--resume`` of the whole sweep loses nothing. Plain Ray tasks rather than Ray Tune: each run is
a complete, resumable training of its own and the search is a grid — Tune's schedulers and
search algorithms would add nothing here.

Folder::

    <run>/        one run directory per combination and seed (see ``safeswitch train``)
    sweep.json    what was asked, and each run's training and evaluation figures
    sweep.md      the same as a table
"""

from __future__ import annotations

import itertools
import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import yaml

from safeswitch.app.distributed import check_reachable, cluster
from safeswitch.core.config import ConfigError, from_dict, set_key, to_dict
from safeswitch.io import write_atomic, write_json
from safeswitch.training.config import TrainConfig, load_config

#: The columns of the table, from each run's ``metrics.json``: (label, path, format).
COLUMNS = (
    ("training failures", ("training", "failures"), "{:d}"),
    ("failures", ("evaluation", "failures"), "{:d}"),
    ("collisions", ("evaluation", "collisions"), "{:d}"),
    ("safety episodes", ("evaluation", "safety_activation_episodes"), "{:d}"),
    ("comfort exceeded", ("evaluation", "comfort_violation_fraction"), "{:.2%}"),
    ("speeding", ("evaluation", "speeding_episodes"), "{:d}"),
    ("top speed [km/h]", ("evaluation", "max_speed_kmh"), "{:.1f}"),
    ("full stops", ("evaluation", "stops"), "{:d}"),
    ("cut", ("evaluation", "cut_episodes"), "{:d}"),
    ("cleared", ("evaluation", "cleared_episodes"), "{:d}"),
    ("time to clear [s]", ("evaluation", "mean_time_to_clear_s"), "{:.2f}"),
    ("faster than the oracle", ("evaluation", "faster_than_oracle_episodes"), "{:d}"),
    ("efficiency", ("evaluation", "mean_efficiency"), "{:.3f}"),
    ("wall time [s]", ("wall_time_s",), "{:.0f}"),
)
#: Columns whose value breaks a target when it is not 0 (marked ✘ in the table).
MUST_BE_ZERO = ("training failures", "failures", "collisions", "speeding",
                "faster than the oracle")  # fmt: skip


def parse_sets(specs: list[str]) -> list[tuple[str, list[Any]]]:
    """``key=v1,v2`` → (key, [v1, v2]) with YAML-typed values.

    Raises:
        ConfigError: A malformed specification.
    """
    out = []
    for spec in specs:
        key, sep, values = spec.partition("=")
        if not sep or not key or not values:
            raise ConfigError(f"--set {spec!r}: expected key=value[,value...]")
        out.append((key, [yaml.safe_load(v) for v in values.split(",")]))
    return out


def _with(config: TrainConfig, key: str, value: Any) -> TrainConfig:
    data = to_dict(config)
    set_key(data, key, value)
    return from_dict(TrainConfig, data)


def plan_runs(
    config: TrainConfig, seeds: list[int], sets: list[tuple[str, list[Any]]]
) -> dict[str, TrainConfig]:
    """Run name → its configuration (every combination of the ``sets`` with every seed)."""
    runs = {}
    keys = [k for k, _ in sets]
    for values in itertools.product(*(v for _, v in sets)):
        variant = config
        for key, value in zip(keys, values, strict=True):
            variant = _with(variant, key, value)
        label = "_".join(f"{k.split('.')[-1]}={v}" for k, v in zip(keys, values, strict=True))
        for seed in seeds:
            name = f"{label}_seed{seed}" if label else f"seed{seed}"
            runs[name] = replace(variant, seed=seed)
    return runs


def train_run(config: TrainConfig, folder: str) -> dict[str, Any]:
    """One run (in a worker): reused if complete, resumed if interrupted, else trained."""
    import torch

    from safeswitch.app.train import train_and_plot
    from safeswitch.io import complete_checkpoints

    torch.set_num_threads(config.torch_threads)
    run = Path(folder)
    metrics = run / "metrics.json"
    if metrics.is_file():
        return dict(json.loads(metrics.read_text(encoding="utf-8")))
    resume = bool(complete_checkpoints(run))
    return train_and_plot(config, run, resume=resume, progress_bar=False)


def sweep(
    config_name: str,
    seeds: list[int],
    sets: list[str],
    out: str | Path,
    workers: int = 2,
    address: str | None = None,
    timesteps: int | None = None,
) -> dict[str, Any]:
    """Train every run of the sweep (see the module docstring); returns ``sweep.json``."""
    if not seeds:
        raise ConfigError("a sweep needs at least one --seeds value")
    config = load_config(config_name)
    if timesteps is not None:
        config = replace(config, timesteps=timesteps)
    runs = plan_runs(config, seeds, parse_sets(sets))
    folder = Path(out)
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"--out {folder} is a file, not a folder")
    if address is not None:
        check_reachable(address)  # before the folder is written
    folder.mkdir(parents=True, exist_ok=True)
    asked = {"config": config_name, "seeds": seeds, "sets": sets, "timesteps": timesteps}
    record = folder / "sweep.json"
    if record.is_file():
        previous = json.loads(record.read_text(encoding="utf-8")).get("asked")
        if previous != asked:
            raise ConfigError(f"{folder} holds another sweep ({previous}); choose another --out")
    write_json(record, {"asked": asked, "runs": {}})
    results: dict[str, Any] = {}
    began = time.perf_counter()
    names = list(runs)
    with cluster(workers, address) as where:

        def done(i: int, metrics: dict[str, Any]) -> None:
            results[names[i]] = {"metrics": metrics}
            print(f"sweep: {names[i]} finished ({len(results)}/{len(names)})", flush=True)

        def failed(i: int, error: BaseException) -> None:
            results[names[i]] = {"error": str(error).strip().splitlines()[-1]}
            print(f"sweep: {names[i]} failed: {results[names[i]]['error']}", flush=True)

        where.map(train_run, [(runs[n], str(folder / n)) for n in names], done, failed)
        startup = where.startup_s
    summary = {
        "asked": asked,
        "runs": {n: results[n] for n in names},
        "ray_startup_s": round(startup, 2),
        "wall_time_s": round(time.perf_counter() - began, 2),
    }
    write_json(record, summary)
    write_atomic(folder / "sweep.md", table(summary))
    return summary


def _value(metrics: dict[str, Any], path: tuple[str, ...]) -> Any:
    node: Any = metrics
    for key in path:
        if not isinstance(node, dict) or key not in node:
            return None
        node = node[key]
    return node


def table(summary: dict[str, Any]) -> str:
    """The sweep's runs as a Markdown table, every column that could hide a violation beside
    the efficiency (a non-zero count of failures, speeding or faster-than-oracle episodes
    marked ✘)."""
    header = ["run", *(label for label, _, _ in COLUMNS)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for name, result in summary["runs"].items():
        if "error" in result:
            lines.append(f"| {name} | failed: {result['error']} |")
            continue
        cells = []
        for label, path, fmt in COLUMNS:
            value = _value(result["metrics"], path)
            cell = "–" if value is None else fmt.format(value)
            if label in MUST_BE_ZERO and value:
                cell = f"✘ {cell}"  # a violation stands out, as a collision does
            cells.append(cell)
        lines.append("| " + " | ".join([name, *cells]) + " |")
    return "\n".join(lines) + "\n"
