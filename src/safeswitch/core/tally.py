"""What an evaluation counts on every step of a plant under the switch: the steps the Safety
controller acted and why (the logic's reason), and per named cost the plant publishes
(``info["costs"]``) the steps it was positive and how many of those the Safety controller
drove. One tally serves :func:`~safeswitch.training.generic.run_episodes` and highway-env's
drivers (:func:`~safeswitch.examples.highway_drivers.drive`)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from typing import Any


class StepTally:
    """Counts over the steps ``add`` is given (each step's ``info``)."""

    def __init__(self) -> None:
        self.safety_steps = 0
        self.reasons: Counter[str] = Counter()
        self.cost_steps: Counter[str] = Counter()
        self.safety_cost_steps: Counter[str] = Counter()

    def add(self, info: Mapping[str, Any]) -> bool:
        """Count one step; returns whether the Safety controller acted on it."""
        active = bool(info.get("safety_active", False))
        if active:
            self.safety_steps += 1
            self.reasons[str(info.get("reason", "unknown"))] += 1
        for name, cost in info.get("costs", {}).items():
            positive = float(cost) > 0
            self.cost_steps[name] += positive
            self.safety_cost_steps[name] += positive and active
        return active

    def summary(self) -> dict[str, dict[str, int]]:
        """``safety_reasons`` (most frequent first), ``cost_steps`` and ``safety_cost_steps``
        (by cost name)."""
        names = sorted(self.cost_steps)
        return {
            "safety_reasons": dict(self.reasons.most_common()),
            "cost_steps": {name: int(self.cost_steps[name]) for name in names},
            "safety_cost_steps": {name: int(self.safety_cost_steps[name]) for name in names},
        }


__all__ = ["StepTally"]
