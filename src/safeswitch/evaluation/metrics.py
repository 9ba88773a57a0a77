"""Summary figures of a batch of episodes (the fields of ``safeswitch evaluate --json``),
accumulated chunk by chunk so that any number of episodes fits in constant memory.

Fields:
    episodes: Episodes evaluated.
    failures: Episodes that ended in a failure: a collision or a loss of control.
    collisions: Episodes that ended in a collision.
    lost_control_episodes: Episodes that ended with the ego off its lane (its tyres slid:
        faster into a curve, or braking harder in one, than the friction circle allows).
    safety_activation_episodes: Episodes in which a safety action was executed at least once.
    safety_activation_steps: Ticks, over all episodes, on which a safety action was executed.
    cleared_episodes: Episodes in which the ego left its conflict zone (with the north car).
    never_cleared_episodes: The others (``episodes − cleared_episodes``).
    mean_time_to_clear_s: Mean time until the ego left its conflict zone [s], over the cleared
        episodes (``null`` if none cleared).
    comfort_violation_steps: Ticks beyond a comfort limit (|a_lon| > 5 or |a_lat| > 3 m/s²).
    comfort_violation_fraction: The same as a share of all ticks.
    comfort_violation_episodes: Episodes with at least one such tick (a policy can keep the
        share of ticks small while breaking a limit briefly in many episodes; ``null`` for a
        campaign merged from shards written before it was counted).
    stops: Episodes in which the ego came to a full stop (speed below 0.1 m/s).
    speeding_episodes: Episodes in which the ego drove faster than the tolerated speed (the
        highest at which ``R_v`` is at its best: the speed limit plus 5 km/h, 30 km/h; the
        oracle's ``v_max``). An episode that clears sooner than the oracle broke this or
        another of the oracle's limits.
    speeding_steps: Ticks, over all episodes, faster than the tolerated speed.
    cut_episodes / yield_episodes: Cleared episodes in which the ego left its conflict zone
        before / after the north car left its own (cut + yield = cleared).
    mean_return: Mean episode return.
    mean_terms: Each reward term of Eq. 5, summed per episode, mean over episodes.
    mean_min_speed_kmh: Mean over episodes of the lowest ego speed [km/h].
    max_speed_kmh: Highest ego speed of any episode [km/h].
    max_accel_lon / max_accel_lat: Largest |a_lon| and |a_lat| of any episode [m/s²].
    max_lateral_deviation_m: Largest distance from the route's centre line [m].
    ticks: Ticks simulated (all episodes).
    ttc_conflict_episodes: Episodes whose smallest time to collision at a conflict zone was at
        most 1.5 s (a *conflict* by SSAM's threshold; see :mod:`safeswitch.evaluation.surrogate`).
    mean_min_ttc_s: Mean smallest TTC over the episodes that were ever on a collision course.
    pet_below_1s_episodes: Episodes with a post-encroachment time below 1 s.
    mean_min_pet_s: Mean smallest PET over the episodes with an encroachment.
    mean_oracle_time_to_clear_s: The oracle's mean time to clear over the same scenarios [s]
        (with an oracle).
    mean_efficiency: Mean over scenarios of the oracle's time to clear divided by the
        controller's; an episode that never clears counts with the whole horizon (with an
        oracle).
    faster_than_oracle_episodes: Episodes that cleared more than :data:`FASTER_MARGIN_S`
        sooner than the oracle, with an oracle. Each did something the oracle's model rules
        out: speeding, breaking a comfort limit, being in its conflict zone while the north car
        is in its own, or entering the turn faster than a point mass may (the plant's lateral
        acceleration lags the route's curvature; README, "Evaluation").
    faster_than_oracle_speeding / _comfort / _either: Of those, the ones that sped, that broke
        a comfort limit, and that did either (:mod:`safeswitch.evaluation.verdict` names them).

Sums are taken per chunk with numpy and combined exactly (:class:`ExactSum`), so a summary
depends only on the episodes and the chunk size — not on how many processes ran the chunks, nor
in which order they were combined — and an accumulator's size does not grow with the number of
chunks (a campaign of any length merges into one).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from safeswitch.evaluation.oracle import efficiency
from safeswitch.evaluation.rollout import RolloutResult
from safeswitch.evaluation.surrogate import TTC_CONFLICT_S
from safeswitch.sim.geometry import FloatArray

#: Speed below which the ego counts as stopped [m/s].
STOP_SPEED = 0.1

#: An episode counts as faster than the oracle when it clears more than this much sooner [s]:
#: the clearing instant is read in whole 20 ms ticks, and the speeding count's 0.1 km/h
#: margin buys about one more tick over a 40 m turn at 30 km/h, so a controller that keeps
#: every limit can beat the oracle by two ticks, never by three.
FASTER_MARGIN_S = 0.05


class ExactSum:
    """The exact sum of floats added one by one, in memory that does not grow with their
    number: non-overlapping partial sums whose exact total is the sum (Shewchuk's expansion
    arithmetic, as in ``math.fsum``). :attr:`value` is the correctly rounded total, so it does
    not depend on the order of the additions."""

    __slots__ = ("partials",)

    def __init__(self, values: list[float] | None = None) -> None:
        self.partials: list[float] = []
        for value in values or ():
            self.add(value)

    def add(self, value: float) -> None:
        """Add one finite float."""
        x, kept = float(value), 0
        for y in self.partials:
            if abs(x) < abs(y):
                x, y = y, x
            high = x + y
            low = y - (high - x)  # the rounding error of high, exactly
            if low:
                self.partials[kept] = low
                kept += 1
            x = high
        del self.partials[kept:]
        self.partials.append(x)

    def merge(self, other: ExactSum) -> None:
        for value in other.partials:
            self.add(value)

    @property
    def value(self) -> float:
        return math.fsum(self.partials)


class SummaryAccumulator:
    """The documented summary of episodes added chunk by chunk (:meth:`add`)."""

    _COUNTS = (
        "episodes",
        "collisions",
        "lost_control_episodes",
        "failures",
        "safety_activation_episodes",
        "safety_activation_steps",
        "cleared_episodes",
        "comfort_violation_steps",
        "comfort_violation_episodes",
        "stops",
        "speeding_episodes",
        "speeding_steps",
        "cut_episodes",
        "yield_episodes",
        "ticks",
        "oracle_cleared",
        "efficiency_count",
        "faster_than_oracle_episodes",
        "faster_than_oracle_speeding",
        "faster_than_oracle_comfort",
        "faster_than_oracle_either",
        "collision_course_episodes",
        "ttc_conflict_episodes",
        "encroachment_episodes",
        "pet_below_1s_episodes",
    )
    _SUMS = ("time_to_clear", "return", "min_speed", "oracle_time", "efficiency", "min_ttc",
             "min_pet")  # fmt: skip
    _MAXIMA = ("max_accel_lon", "max_accel_lat", "max_lateral_deviation_m", "max_speed")

    def __init__(self) -> None:
        self.counts = dict.fromkeys(self._COUNTS, 0)
        self.sums: dict[str, ExactSum] = {name: ExactSum() for name in self._SUMS}
        self.term_sums: dict[str, ExactSum] = {}
        self.maxima = dict.fromkeys(self._MAXIMA, -math.inf)
        self.with_oracle = False
        #: Counts some merged shard did not hold (written before they were counted): the
        #: summary gives them as ``None`` rather than a total that leaves those shards out.
        self.unknown: set[str] = set()

    def add(
        self,
        result: RolloutResult,
        oracle_time: FloatArray | None = None,
        horizon_s: float | None = None,
    ) -> None:
        """Add a chunk of episodes (and the oracle's times to clear of the same scenarios)."""
        r, c, s = result, self.counts, self.sums
        cleared = np.isfinite(r.time_to_clear)
        c["episodes"] += int(r.collision.size)
        c["collisions"] += int(r.collision.sum())
        c["lost_control_episodes"] += int(r.lost_control.sum())
        c["failures"] += int((r.collision | r.lost_control).sum())
        c["safety_activation_episodes"] += int((r.safety_steps > 0).sum())
        c["safety_activation_steps"] += int(r.safety_steps.sum())
        c["cleared_episodes"] += int(cleared.sum())
        c["comfort_violation_steps"] += int(r.comfort_violation_steps.sum())
        c["comfort_violation_episodes"] += int((r.comfort_violation_steps > 0).sum())
        c["stops"] += int((r.min_speed < STOP_SPEED).sum())
        c["speeding_episodes"] += int((r.speeding_steps > 0).sum())
        c["speeding_steps"] += int(r.speeding_steps.sum())
        c["cut_episodes"] += int((r.outcome == 1).sum())
        c["yield_episodes"] += int((r.outcome == 2).sum())
        c["ticks"] += int(r.ticks.sum())
        s["time_to_clear"].add(float(r.time_to_clear[cleared].sum()))
        s["return"].add(float(r.episode_return.sum()))
        s["min_speed"].add(float(r.min_speed.sum()))
        course, encroached = np.isfinite(r.min_ttc), np.isfinite(r.min_pet)
        c["collision_course_episodes"] += int(course.sum())
        c["ttc_conflict_episodes"] += int((r.min_ttc <= TTC_CONFLICT_S).sum())
        c["encroachment_episodes"] += int(encroached.sum())
        c["pet_below_1s_episodes"] += int((r.min_pet[encroached] < 1.0).sum())
        s["min_ttc"].add(float(r.min_ttc[course].sum()))
        s["min_pet"].add(float(r.min_pet[encroached].sum()))
        for name, values in r.terms.items():
            self.term_sums.setdefault(name, ExactSum()).add(float(values.sum()))
        if r.collision.size:
            for key, values in (
                ("max_accel_lon", r.max_accel_lon),
                ("max_accel_lat", r.max_accel_lat),
                ("max_lateral_deviation_m", r.max_lateral),
                ("max_speed", r.max_speed),
            ):
                self.maxima[key] = max(self.maxima[key], float(values.max()))
        if oracle_time is not None:
            if horizon_s is None:
                raise ValueError("an oracle's times need the horizon (horizon_s)")
            self.with_oracle = True
            known = np.isfinite(oracle_time)
            c["oracle_cleared"] += int(known.sum())
            s["oracle_time"].add(float(oracle_time[known].sum()))
            ratio = efficiency(oracle_time, r.time_to_clear, horizon_s)
            finite = np.isfinite(ratio)
            c["efficiency_count"] += int(finite.sum())
            faster = finite & (r.time_to_clear < oracle_time - FASTER_MARGIN_S)
            sped, uncomfortable = r.speeding_steps > 0, r.comfort_violation_steps > 0
            c["faster_than_oracle_episodes"] += int(faster.sum())
            c["faster_than_oracle_speeding"] += int((faster & sped).sum())
            c["faster_than_oracle_comfort"] += int((faster & uncomfortable).sum())
            c["faster_than_oracle_either"] += int((faster & (sped | uncomfortable)).sum())
            s["efficiency"].add(float(ratio[finite].sum()))

    def merge(self, other: SummaryAccumulator) -> None:
        """Add another accumulator's episodes (chunks in order: ``self`` first)."""
        for key in self._COUNTS:
            self.counts[key] += other.counts[key]
        for key in self._SUMS:
            self.sums[key].merge(other.sums[key])
        for name, parts in other.term_sums.items():
            self.term_sums.setdefault(name, ExactSum()).merge(parts)
        for key in self._MAXIMA:
            self.maxima[key] = max(self.maxima[key], other.maxima[key])
        self.with_oracle |= other.with_oracle
        self.unknown |= other.unknown

    def state(self) -> dict[str, Any]:
        """Everything the accumulator holds, as plain JSON-able data (:meth:`from_state`
        restores it: a campaign's shards travel as this)."""
        return {
            "counts": dict(self.counts),
            "sums": {k: list(v.partials) for k, v in self.sums.items()},
            "term_sums": {k: list(v.partials) for k, v in self.term_sums.items()},
            "maxima": {k: (None if v == -math.inf else v) for k, v in self.maxima.items()},
            "with_oracle": self.with_oracle,
            "unknown": sorted(self.unknown),
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> SummaryAccumulator:
        accumulator = cls()
        accumulator.counts.update(state["counts"])
        accumulator.unknown = set(state.get("unknown", ())) | (
            set(cls._COUNTS) - set(state["counts"])
        )
        # Lists of floats whose exact sum is the total: partials, or (a shard written before
        # partials were kept) one sum per chunk.
        accumulator.sums.update({k: ExactSum(v) for k, v in state["sums"].items()})
        accumulator.term_sums = {k: ExactSum(v) for k, v in state["term_sums"].items()}
        accumulator.maxima.update(
            {k: (-math.inf if v is None else v) for k, v in state["maxima"].items()}
        )
        accumulator.with_oracle = bool(state["with_oracle"])
        return accumulator

    def summary(self) -> dict[str, Any]:
        """The summary (see the module docstring); undefined means are ``None``."""
        c, n = self.counts, self.counts["episodes"]

        def mean(key: str, count: int) -> float | None:
            return self.sums[key].value / count if count else None

        def largest(key: str) -> float | None:
            return self.maxima[key] if n else None

        out: dict[str, Any] = {
            "episodes": n,
            "failures": c["failures"],
            "collisions": c["collisions"],
            "lost_control_episodes": c["lost_control_episodes"],
            "safety_activation_episodes": c["safety_activation_episodes"],
            "safety_activation_steps": c["safety_activation_steps"],
            "cleared_episodes": c["cleared_episodes"],
            "never_cleared_episodes": n - c["cleared_episodes"],
            "mean_time_to_clear_s": mean("time_to_clear", c["cleared_episodes"]),
            "comfort_violation_steps": c["comfort_violation_steps"],
            "comfort_violation_fraction": c["comfort_violation_steps"] / max(c["ticks"], 1),
            "comfort_violation_episodes": (
                None
                if "comfort_violation_episodes" in self.unknown
                else c["comfort_violation_episodes"]
            ),
            "stops": c["stops"],
            "speeding_episodes": c["speeding_episodes"],
            "speeding_steps": c["speeding_steps"],
            "cut_episodes": c["cut_episodes"],
            "yield_episodes": c["yield_episodes"],
            "mean_return": mean("return", n),
            "mean_terms": {
                name: parts.value / n if n else None for name, parts in self.term_sums.items()
            },
            "mean_min_speed_kmh": None if not n else 3.6 * self.sums["min_speed"].value / n,
            "max_speed_kmh": None if not n else 3.6 * self.maxima["max_speed"],
            "max_accel_lon": largest("max_accel_lon"),
            "max_accel_lat": largest("max_accel_lat"),
            "max_lateral_deviation_m": largest("max_lateral_deviation_m"),
            "ticks": c["ticks"],
            "ttc_conflict_episodes": c["ttc_conflict_episodes"],
            "mean_min_ttc_s": mean("min_ttc", c["collision_course_episodes"]),
            "pet_below_1s_episodes": c["pet_below_1s_episodes"],
            "mean_min_pet_s": mean("min_pet", c["encroachment_episodes"]),
        }
        if self.with_oracle:
            out["mean_oracle_time_to_clear_s"] = mean("oracle_time", c["oracle_cleared"])
            out["mean_efficiency"] = mean("efficiency", c["efficiency_count"])
            for key in ("faster_than_oracle_episodes", "faster_than_oracle_speeding",
                        "faster_than_oracle_comfort", "faster_than_oracle_either"):  # fmt: skip
                out[key] = c[key]
        return out


def summarize(
    result: RolloutResult,
    oracle_time: FloatArray | None = None,
    horizon_s: float | None = None,
) -> dict[str, Any]:
    """The documented summary of one :class:`RolloutResult` (one chunk)."""
    accumulator = SummaryAccumulator()
    accumulator.add(result, oracle_time, horizon_s)
    return accumulator.summary()
