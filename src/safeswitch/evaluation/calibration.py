"""Perception bounds from data: split conformal prediction over (seen, true) pairs.

The certified logic keeps its guarantee for any perception errors within declared bounds
(:mod:`safeswitch.leftturn.perception`). Where do the bounds come from? From pairs of what a
sensor reported and what was true — logged against ground truth (a survey vehicle, a motion
capture rig, a higher-grade sensor), or simulated from a sensor model — by split conformal
prediction (Vovk et al. 2005; Angelopoulos & Bates, "A gentle introduction to conformal
prediction", 2021; inside safety filters: Lindemann et al., RA-L 2023): the pairs are shuffled
and split; on the calibration half the bound is the ``⌈(n + 1)(1 − α)⌉``-th smallest absolute
error, and a new error drawn like the calibration ones lies within it with probability at least
``1 − α`` (and at most ``1 − α + 1/(n + 1)`` for continuous errors). The other half measures the
coverage actually reached.

What the bound promises is per measurement and marginal: exchangeable pairs (errors that do not
drift between calibration and use), each key on its own (both at once: at least ``1 − 2α``,
reported as measured). The certified logic's guarantee is then conditional on the errors staying
within the bounds; a run of errors beyond them breaks its assumption, as a north car faster than
``other_max_speed_kmh`` does.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.config import Bounds, ConfigError, check, check_bounds

FloatArray = NDArray[np.float64]

#: The columns of a pairs file (CSV with a header; other columns are ignored).
PAIR_COLUMNS = ("seen_position_m", "true_position_m", "seen_speed_mps", "true_speed_mps")


@dataclass(frozen=True)
class SensorModel:
    """A simulated sensor: independent errors of each measurement (``calibrate-perception
    --simulate``).

    Attributes:
        position_sigma_m: Scale of the position error along the path [m] (the standard
            deviation for ``gaussian``; ``laplace``: its scale ``b``, standard deviation
            ``√2·b``).
        speed_sigma_mps: Scale of the speed error [m/s].
        distribution: ``gaussian`` or ``laplace`` (heavier tails).
        latency_s: Carried into the perception block as declared (not calibrated here).
        dropout_prob: Carried as declared.
        dropout_max_s: Carried as declared.
        sight_distance_m: Carried as declared (``null``: no limit).
    """

    position_sigma_m: Annotated[float, Bounds(0, 50, unit="m")] = 0.5
    speed_sigma_mps: Annotated[float, Bounds(0, 20, unit="m/s")] = 0.3
    distribution: Literal["gaussian", "laplace"] = "gaussian"
    latency_s: Annotated[float, Bounds(0, 2, unit="s")] = 0.0
    dropout_prob: Annotated[float, Bounds(0, 1)] = 0.0
    dropout_max_s: Annotated[float, Bounds(0, 10, unit="s")] = 0.0
    sight_distance_m: Annotated[float | None, Bounds(0, 10_000, low_open=True, unit="m")] = None

    def __post_init__(self) -> None:
        check_bounds(self, "sensor")
        check(self.distribution in ("gaussian", "laplace"), "sensor", "distribution",
              self.distribution, "must be 'gaussian' or 'laplace'")  # fmt: skip

    def errors(self, rng: np.random.Generator, count: int) -> tuple[FloatArray, FloatArray]:
        """``count`` position and speed errors."""
        draw = rng.normal if self.distribution == "gaussian" else rng.laplace
        return (
            draw(0.0, self.position_sigma_m, count),
            draw(0.0, self.speed_sigma_mps, count),
        )


@dataclass(frozen=True)
class Calibration:
    """The result of :func:`calibrate`.

    Attributes:
        alpha: The miscoverage asked for.
        position_error_m: Bound on the position error [m].
        speed_error_mps: Bound on the speed error [m/s].
        calibration_pairs: Pairs the bounds were computed on.
        holdout_pairs: Pairs the coverage was measured on.
        coverage_position: Share of held-out position errors within their bound.
        coverage_speed: The same for speed.
        coverage_both: Share of held-out pairs within both bounds.
        declared: The perception keys not calibrated here, carried as declared.
    """

    alpha: float
    position_error_m: float
    speed_error_mps: float
    calibration_pairs: int
    holdout_pairs: int
    coverage_position: float
    coverage_speed: float
    coverage_both: float
    declared: dict[str, Any] = field(default_factory=dict)

    def perception(self) -> dict[str, Any]:
        """The ``perception:`` block (keys of
        :class:`~safeswitch.leftturn.config.PerceptionConfig`)."""
        return {
            "position_error_m": self.position_error_m,
            "speed_error_mps": self.speed_error_mps,
            **self.declared,
        }


def conformal_bound(residuals: FloatArray, alpha: float) -> float:
    """The split-conformal bound on ``|residual|``: the ``⌈(n + 1)(1 − α)⌉``-th smallest of the
    ``n`` calibration values (``inf`` if there are too few for ``α``)."""
    scores = np.sort(np.abs(np.asarray(residuals, dtype=np.float64)))
    n = scores.shape[0]
    rank = math.ceil((n + 1) * (1.0 - alpha))
    return math.inf if rank > n else float(scores[rank - 1])


def calibrate(
    seen_position: FloatArray, true_position: FloatArray, seen_speed: FloatArray,
    true_speed: FloatArray, alpha: float = 0.05, holdout: float = 0.5, seed: int = 0,
    declared: dict[str, Any] | None = None,
) -> Calibration:  # fmt: skip
    """Bounds on the position and speed errors that hold with probability ``1 − α`` each, from
    pairs of measurements and truth, and their coverage on a held-out share ``holdout``.

    Raises:
        ConfigError: ``alpha`` or ``holdout`` out of range, arrays of different lengths, a
            non-finite value (named with its row), or too few pairs for ``alpha``.
    """
    check(0.0 < alpha < 1.0, "calibration", "alpha", alpha, "must be in (0, 1)")
    check(0.0 < holdout < 1.0, "calibration", "holdout", holdout, "must be in (0, 1)")
    columns = [np.asarray(a, dtype=np.float64) for a in (seen_position, true_position,
                                                          seen_speed, true_speed)]  # fmt: skip
    count = columns[0].shape[0]
    for name, column in zip(PAIR_COLUMNS, columns, strict=True):
        if column.shape != (count,):
            raise ConfigError(f"pairs: {name} has {column.shape} values, expected ({count},)")
        bad = np.flatnonzero(~np.isfinite(column))
        if bad.size:
            raise ConfigError(f"pairs: {name} is {float(column[bad[0]])!r} in row {bad[0] + 1}")
    order = np.random.default_rng(seed).permutation(count)
    held = round(count * holdout)
    test, fit = order[:held], order[held:]
    need = math.ceil(1.0 / alpha) - 1
    if fit.size < need or test.size == 0:
        raise ConfigError(
            f"pairs: {count} pairs leave {fit.size} to calibrate on and {test.size} to test; "
            f"alpha={alpha} needs at least {need} to calibrate on"
        )
    position = columns[0] - columns[1]
    speed = columns[2] - columns[3]
    bound_p = conformal_bound(position[fit], alpha)
    bound_v = conformal_bound(speed[fit], alpha)
    within_p = np.abs(position[test]) <= bound_p
    within_v = np.abs(speed[test]) <= bound_v
    return Calibration(
        alpha=alpha, position_error_m=bound_p, speed_error_mps=bound_v,
        calibration_pairs=int(fit.size), holdout_pairs=int(test.size),
        coverage_position=float(within_p.mean()), coverage_speed=float(within_v.mean()),
        coverage_both=float((within_p & within_v).mean()), declared=dict(declared or {}),
    )  # fmt: skip


def read_pairs(path: str | Path) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The four columns of a pairs file (CSV with a header naming :data:`PAIR_COLUMNS`).

    Raises:
        ConfigError: A missing column or a value that is not a number (named with its row).
    """
    with open(path, newline="", encoding="utf-8") as handle:
        reader = csv.DictReader(handle)
        missing = [c for c in PAIR_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise ConfigError(f"{path}: no column {missing[0]!r} (needs {', '.join(PAIR_COLUMNS)})")
        rows: list[list[float]] = []
        for line, row in enumerate(reader, start=2):
            try:
                rows.append([float(row[c]) for c in PAIR_COLUMNS])
            except (TypeError, ValueError):
                bad = next(c for c in PAIR_COLUMNS if not _is_number(row[c]))
                raise ConfigError(
                    f"{path}: line {line}: {bad}={row[bad]!r} is not a number"
                ) from None
    table = np.asarray(rows, dtype=np.float64).reshape(-1, 4)
    return table[:, 0], table[:, 1], table[:, 2], table[:, 3]


def _is_number(text: Any) -> bool:
    try:
        float(text)
    except (TypeError, ValueError):
        return False
    return True


def simulate_pairs(
    sensor: SensorModel, count: int, seed: int = 0
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """``count`` (seen, true) pairs of the north car's position and speed: true states from
    random scenarios of the paper's scene, seen through ``sensor``."""
    from safeswitch.leftturn.config import LeftTurnConfig
    from safeswitch.leftturn.task import LeftTurnTask

    task = LeftTurnTask(LeftTurnConfig())
    rng = np.random.default_rng(seed)
    episodes = max(1, math.ceil(count / 50))
    world = task.without_ego(task.scenario_set(seed, episodes))
    rows = rng.integers(0, world.north.shape[0], count)
    ticks = rng.integers(0, world.north.shape[1], count)
    true_p, true_v = world.north[rows, ticks], world.north_speed[rows, ticks]
    error_p, error_v = sensor.errors(rng, count)
    return true_p + error_p, true_p, np.maximum(true_v + error_v, 0.0), true_v


def declared_of(sensor: SensorModel) -> dict[str, Any]:
    """The perception keys a sensor model declares rather than has calibrated."""
    return {
        "latency_s": sensor.latency_s,
        "dropout_prob": sensor.dropout_prob,
        "dropout_max_s": sensor.dropout_max_s,
        "sight_distance_m": sensor.sight_distance_m,
    }
