"""``safeswitch calibrate-perception``: perception bounds from (seen, true) pairs by split
conformal prediction (:mod:`safeswitch.evaluation.calibration`), written as a ``perception:``
block that ``--perception FILE`` reads."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from safeswitch.core.config import ConfigError, from_dict, to_dict
from safeswitch.evaluation.calibration import (
    Calibration,
    SensorModel,
    calibrate,
    declared_of,
    read_pairs,
    simulate_pairs,
)
from safeswitch.io import prepare_output_dir, write_atomic, write_json
from safeswitch.leftturn.config import PerceptionConfig


def calibrate_perception(
    out: str | Path,
    pairs: str | Path | None = None,
    sensor: str | Path | dict[str, Any] | None = None,
    alpha: float = 0.05,
    count: int = 100_000,
    seed: int = 0,
    holdout: float = 0.5,
    overwrite: bool = False,
) -> Calibration:
    """Calibrate from a pairs file (``pairs``) or a simulated sensor (``sensor``: a YAML file
    or a dict of :class:`~safeswitch.evaluation.calibration.SensorModel` keys, ``count`` pairs
    from ``seed``); writes ``perception.yaml`` and ``calibration.json`` to ``out``.

    Raises:
        ConfigError: Neither or both sources, or a bad file or value (named).
    """
    if (pairs is None) == (sensor is None):
        raise ConfigError("calibrate-perception needs one source: --pairs CSV or --simulate YAML")
    if pairs is not None:
        columns = read_pairs(pairs)
        declared: dict[str, Any] = {}
        source: dict[str, Any] = {"pairs": str(pairs)}
    else:
        model = _sensor(sensor)
        columns = simulate_pairs(model, count, seed)
        declared = declared_of(model)
        source = {"simulated": to_dict(model), "count": count, "seed": seed}
    result = calibrate(*columns, alpha=alpha, holdout=holdout, seed=seed, declared=declared)
    block = to_dict(from_dict(PerceptionConfig, result.perception(), where="perception"))
    folder = prepare_output_dir(out, overwrite)
    header = (
        f"# safeswitch calibrate-perception: split conformal bounds, alpha = {alpha}\n"
        f"# held-out coverage: position {result.coverage_position:.4f}, speed "
        f"{result.coverage_speed:.4f}, both {result.coverage_both:.4f} "
        f"({result.holdout_pairs:,} pairs)\n"
    )
    write_json(folder / "calibration.json", {**to_dict(result), "source": source})
    write_atomic(folder / "perception.yaml",
                 header + yaml.safe_dump({"perception": block}, sort_keys=False))  # fmt: skip
    return result


def _sensor(sensor: str | Path | dict[str, Any] | None) -> SensorModel:
    if isinstance(sensor, dict):
        return from_dict(SensorModel, sensor, where="sensor")
    try:
        with open(str(sensor), encoding="utf-8") as handle:
            data = yaml.safe_load(handle)
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"--simulate {sensor}: {exc}") from None
    if isinstance(data, dict) and set(data) == {"sensor"}:
        data = data["sensor"]
    return from_dict(SensorModel, data, where="sensor")
