"""Scenarios: where the cars start and how fast the north car drives.

Randomness is counter-based: scenario ``k`` of environment ``i`` under seed ``s`` is a pure
function of ``(s, i, k)`` (a SplitMix64 hash). So environment ``i`` of a batch of 4,096 sees
exactly the scenarios that a single environment with the same seed and index sees, whatever the
batch size and whichever environments reset when — and no Python loop over environments is
needed to draw them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from safeswitch.core.arrays import take_rows
from safeswitch.leftturn.config import SCENARIO_NAMES, ScenarioConfig
from safeswitch.sim.geometry import FloatArray

_MASK64 = (1 << 64) - 1


def splitmix64(x: NDArray[Any]) -> NDArray[np.uint64]:
    """SplitMix64 finaliser (Steele, Lea & Flood 2014): a bijective 64-bit mixer."""
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def counter_uniforms(
    seed: int, env_ids: NDArray[np.int64], episodes: NDArray[np.int64], count: int
) -> FloatArray:
    """Uniform numbers in [0, 1), a pure function of ``(seed, env_id, episode, j)``.

    Args:
        seed: Base seed (any Python int; reduced modulo 2⁶⁴).
        env_ids: Environment index per row, shape ``[B]``.
        episodes: Episode counter per row, shape ``[B]``.
        count: Numbers per row.

    Returns:
        Array ``[B, count]``.
    """
    with np.errstate(over="ignore"):
        start: NDArray[np.uint64] = np.full(np.shape(env_ids), seed & _MASK64, dtype=np.uint64)
        key = splitmix64(start)
        key = splitmix64(key ^ np.asarray(env_ids, dtype=np.uint64))
        key = splitmix64(key ^ (np.asarray(episodes, dtype=np.uint64) << np.uint64(20)))
        draws = splitmix64(key[:, None] + np.arange(1, count + 1, dtype=np.uint64))
    return (draws >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))


@dataclass
class Scenarios:
    """A batch of scenario parameters, each of shape ``[B]``.

    Attributes:
        ego_start_distance: Ego's path distance to the conflict point at the start [m].
        ego_speed: Ego's initial speed [m/s].
        north_speed: North car's speed [m/s], held by its autopilot.
        arrival_offset: North's arrival at the conflict point minus the ego's nominal one [s].
    """

    ego_start_distance: FloatArray
    ego_speed: FloatArray
    north_speed: FloatArray
    arrival_offset: FloatArray

    def take(self, rows: NDArray[Any]) -> Scenarios:
        """The scenarios at ``rows`` (indices or a mask; repeats allowed), as a new batch."""
        return cast(Scenarios, take_rows(self, rows))

    def north_start_distance(self, speed_limit: float) -> FloatArray:
        """North's path distance to the conflict point at the start [m]: it arrives
        ``arrival_offset`` after the ego would, cruising at ``speed_limit`` [m/s]."""
        ego_arrival = self.ego_start_distance / speed_limit
        return self.north_speed * (ego_arrival + self.arrival_offset)


#: The paper's Section VI scenarios (ours: the paper gives no numbers). The ego starts 36 m from
#: the conflict point at 25 km/h; the north car drives 29 km/h. ``cut``: it arrives 3 s after
#: the ego would — enough to pass in front. ``yield1``: it arrives 0.4 s before the ego would —
#: slowing a little lets it pass first. ``yield2``: it arrives 1.0 s after the ego would — too
#: close to cut in front, so the ego must wait longer, slowing nearly to a stop.
NAMED_SCENARIOS: dict[str, dict[str, float]] = {
    "cut": {
        "ego_start_distance": 36.0,
        "ego_speed_kmh": 25.0,
        "north_speed_kmh": 29.0,
        "arrival_offset": 3.0,
    },
    "yield1": {
        "ego_start_distance": 36.0,
        "ego_speed_kmh": 25.0,
        "north_speed_kmh": 29.0,
        "arrival_offset": -0.4,
    },
    "yield2": {
        "ego_start_distance": 36.0,
        "ego_speed_kmh": 25.0,
        "north_speed_kmh": 29.0,
        "arrival_offset": 1.0,
    },
}
assert tuple(NAMED_SCENARIOS) == SCENARIO_NAMES


def scenario_uniforms(config: ScenarioConfig) -> int:
    """Uniforms per scenario :func:`sample_scenarios` needs: 4, and a fifth that picks the
    focused ones when ``focus_share`` is set (so the plain distribution's draws stay what they
    were)."""
    return 5 if config.focus_share > 0 else 4


def sample_scenarios(config: ScenarioConfig, uniforms: FloatArray) -> Scenarios:
    """Scenarios from uniforms ``[B, scenario_uniforms(config)]`` (see
    :func:`counter_uniforms`)."""

    def between(bounds: tuple[float, float], u: FloatArray) -> FloatArray:
        return bounds[0] + (bounds[1] - bounds[0]) * u

    names = ("ego_start_distance_m", "ego_speed_kmh", "north_speed_kmh", "arrival_offset_s")
    values = [between(getattr(config, name), uniforms[:, i]) for i, name in enumerate(names)]
    if config.focus_share > 0:
        focused = uniforms[:, 4] < config.focus_share
        for i, name in enumerate(names):
            values[i] = np.where(focused, between(config.focused(name), uniforms[:, i]), values[i])
    return Scenarios(
        ego_start_distance=values[0],
        ego_speed=values[1] / 3.6,
        north_speed=values[2] / 3.6,
        arrival_offset=values[3],
    )


def farthest_starts(config: ScenarioConfig, speed_limit: float) -> tuple[float, float, float]:
    """How far before the conflict point the distribution can start each car: the ego's
    farthest path distance [m], the north car's [m] and the latest arrival offset it draws [s]
    (the focused ranges' too when ``focus_share`` is set). The north car starts farthest out
    at its highest speed, the ego's farthest start and the latest arrival (see
    :meth:`Scenarios.north_start_distance`)."""

    def highest(name: str) -> float:
        high = getattr(config, name)[1]
        return max(high, config.focused(name)[1]) if config.focus_share > 0 else high

    ego, offset = highest("ego_start_distance_m"), highest("arrival_offset_s")
    farthest = Scenarios(
        ego_start_distance=np.array([ego]),
        ego_speed=np.array([highest("ego_speed_kmh") / 3.6]),
        north_speed=np.array([highest("north_speed_kmh") / 3.6]),
        arrival_offset=np.array([offset]),
    )
    return ego, max(float(farthest.north_start_distance(speed_limit)[0]), 0.0), offset


def named_scenarios(name: str, batch: int) -> Scenarios:
    """``batch`` copies of a named scenario (``"cut"``, ``"yield1"`` or ``"yield2"``)."""
    if name not in NAMED_SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; expected one of {list(NAMED_SCENARIOS)}")
    v = NAMED_SCENARIOS[name]
    ones = np.ones(batch)
    return Scenarios(
        ego_start_distance=v["ego_start_distance"] * ones,
        ego_speed=v["ego_speed_kmh"] / 3.6 * ones,
        north_speed=v["north_speed_kmh"] / 3.6 * ones,
        arrival_offset=v["arrival_offset"] * ones,
    )


def scenario_grid(
    arrival_offsets: FloatArray,
    north_speeds_kmh: FloatArray,
    ego_speeds_kmh: FloatArray,
    ego_start_distance: float = 36.0,
) -> Scenarios:
    """Every combination of the given values, flattened to a batch (for exhaustive sweeps)."""
    offset, north, ego = np.meshgrid(
        arrival_offsets, north_speeds_kmh, ego_speeds_kmh, indexing="ij"
    )
    return Scenarios(
        ego_start_distance=np.full(offset.size, float(ego_start_distance)),
        ego_speed=ego.ravel() / 3.6,
        north_speed=north.ravel() / 3.6,
        arrival_offset=offset.ravel().astype(np.float64),
    )
