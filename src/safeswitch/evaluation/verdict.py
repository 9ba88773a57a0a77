"""What a summary says about the rules a careful driver keeps, read off it: the targets a
shipped left-turn policy is held to, each checked ✔/✘ with its measured value, and the lines
every summary shows beside its efficiency so that a good-looking number cannot hide how it was
bought (issue #37).

The targets (issues #18 and #39): no collision and no loss of control; the Safety controller's
action in at most 2 % of the episodes; a comfort limit exceeded on at most 0.5 % of the ticks;
never faster than the speed limit plus ``R_v``'s tolerance (30 km/h; the ``speeding`` count
allows 0.1 km/h of rounding); at least 0.85 of the oracle's efficiency; at least 99 % of the
episodes cleared. An efficiency above 1 is never a success: the controller broke a limit the
oracle keeps, and the reason is named.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

#: A summary (the fields of :mod:`safeswitch.evaluation.metrics`).
Summary = dict[str, Any]


@dataclass(frozen=True)
class Check:
    """One target checked against a summary.

    Attributes:
        name: The target's short name (a column of the report's verdict).
        ok: Whether the summary meets it (``None``: the summary cannot tell, e.g. no oracle).
        value: The measured value, as the reader reads it.
        target: The target, in words.
    """

    name: str
    ok: bool | None
    value: str
    target: str

    @property
    def mark(self) -> str:
        return {True: "✔", False: "✘", None: "–"}[self.ok]


def _episodes(n: int) -> str:
    return f"{n:,} episode" + ("" if n == 1 else "s")


def _share(count: int, total: int) -> str:
    return f"{count:,} of {total:,}" if total else "–"


def faster_than_oracle_reason(s: Summary) -> str | None:
    """Why episodes cleared sooner than the oracle — what each of them broke — or ``None`` if
    none did."""
    faster = s.get("faster_than_oracle_episodes") or 0
    if not faster:
        return None
    speeding = s.get("faster_than_oracle_speeding", 0)
    comfort = s.get("faster_than_oracle_comfort", 0)
    rest = faster - s.get("faster_than_oracle_either", 0)
    parts = [f"{speeding:,} sped", f"{comfort:,} broke a comfort limit"]
    if rest:
        parts.append(f"{rest:,} neither (into the turn faster than the oracle's point mass may, "
                     "or sharing the conflict area)")  # fmt: skip
    return f"{_episodes(faster)} cleared sooner than the oracle: " + ", ".join(parts)


def _collisions(s: Summary) -> Check:
    n = s["collisions"]
    return Check("collisions", n == 0, f"{n:,}", "0")


def _failures(s: Summary) -> Check:
    n, lost = s["failures"], s.get("lost_control_episodes", 0)
    value = f"{n:,}" + (f" ({lost:,} lost control)" if lost else "")
    return Check("failures", n == 0, value, "0 (collisions and losses of control)")


def _safety(s: Summary) -> Check:
    n, total = s["safety_activation_episodes"], s["episodes"]
    ok = total > 0 and n <= 0.02 * total
    return Check("safety action", ok, f"{_share(n, total)} episodes", "≤ 2 % of episodes")


#: The share of ticks over a comfort limit a shipped policy may have (issue #39's targets).
COMFORT_BUDGET = 0.005


def _comfort(s: Summary) -> Check:
    share = s["comfort_violation_fraction"]
    ok = share <= COMFORT_BUDGET
    return Check("comfort", ok, f"{share:.2%} of ticks", "exceeded on ≤ 0.5 % of ticks")


def _in_episodes(n: int | None) -> str:
    """`` (in N episodes)`` where the count is known."""
    return "" if n is None else f" (in {_episodes(n)})"


def _speed(s: Summary) -> Check:
    n, top = s["speeding_episodes"], s.get("max_speed_kmh")
    value = f"{_episodes(n)} above 30 km/h" + (f" (top {top:.1f} km/h)" if top else "")
    return Check("speed", n == 0, value, "never above 30 km/h")


def _efficiency(s: Summary) -> Check:
    e = s.get("mean_efficiency")
    if e is None:
        return Check("efficiency", None, "no oracle", "≥ 0.85 of the oracle")
    reason = faster_than_oracle_reason(s)
    if e > 1.0:
        return Check("efficiency", False, f"{e:.3f}: above 1 — {reason}", "≥ 0.85, never above 1")
    return Check("efficiency", e >= 0.85, f"{e:.3f}", "≥ 0.85 of the oracle")


def _cleared(s: Summary) -> Check:
    n, total = s["cleared_episodes"], s["episodes"]
    ok = total > 0 and n >= 0.99 * total
    return Check("cleared", ok, f"{_share(n, total)}", "≥ 99 % of episodes")


#: The targets, in the order the verdict shows them.
TARGETS: tuple[Callable[[Summary], Check], ...] = (
    _collisions, _failures, _safety, _comfort, _speed, _efficiency, _cleared,
)  # fmt: skip


def verdict(summary: Summary) -> list[Check]:
    """Every target checked against ``summary``."""
    return [target(summary) for target in TARGETS]


def headline(summary: Summary) -> list[str]:
    """The lines a summary leads with: failures, safety action, speeding and top speed,
    comfort, efficiency with its time to clear (and what an efficiency above 1 means), and
    cut + yield = cleared — each target's mark first, so that a violation stands out as a
    collision does."""
    s = summary
    marks = {c.name: c.mark for c in verdict(s)}
    lines = [
        f"{marks['failures']} failures: {s['failures']:,} (collisions {s['collisions']:,}, "
        f"lost control {s.get('lost_control_episodes', 0):,}) in {_episodes(s['episodes'])}",
        f"{marks['safety action']} safety action: {_episodes(s['safety_activation_episodes'])}",
        f"{marks['speed']} speeding: " + _speed(s).value,
        f"{marks['comfort']} comfort exceeded on {s['comfort_violation_fraction']:.2%} of ticks"
        + _in_episodes(s.get("comfort_violation_episodes")),
    ]
    clear = s.get("mean_time_to_clear_s")
    clear_text = "never cleared" if clear is None else f"time to clear {clear:.2f} s"
    efficiency = s.get("mean_efficiency")
    if efficiency is not None:
        lines.append(f"{marks['efficiency']} efficiency {efficiency:.3f} of the oracle "
                     f"({clear_text})")  # fmt: skip
        reason = faster_than_oracle_reason(s)
        if reason:
            lines.append(f"  ! {reason}")
    else:
        lines.append(f"– {clear_text}")
    lines.append(
        f"{marks['cleared']} cleared {s['cleared_episodes']:,} = cut {s['cut_episodes']:,} + "
        f"yield {s['yield_episodes']:,}; never cleared {s['never_cleared_episodes']:,}"
    )
    return lines
