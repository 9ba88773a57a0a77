"""The policies that ship with the package, by the name the command line knows them (a light
module: ``--help`` lists them without importing torch)."""

from __future__ import annotations

from pathlib import Path

#: Where the shipped policies live, one folder each.
SHIPPED_DIR = Path(__file__).resolve().parent.parent / "policies"

#: Name on the command line → folder under :data:`SHIPPED_DIR` (``shipped`` is the paper
#: policy).
SHIPPED = {
    "shipped": "paper",
    "paper": "paper",
    "paper-warm": "paper_warm",
    "paper-scratch": "paper_scratch",
    "no-adas": "no_adas",
    "certified": "certified",
    "none": "none",
    "traffic-paper": "traffic_paper",
    "traffic-certified": "traffic_certified",
    "highway-certified": "highway_certified",
    "highway-none": "highway_none",
}

#: Shipped policies (by folder) that miss their targets, with what they measure: the left
#: turn's on today's plant — tyre friction came after they were trained (issue #37) — on 1,000
#: unseen random scenarios (seed 1,000,003; ``traffic_certified``: the ``test`` family, seed
#: 424,242), highway-env's on its 50 evaluation episodes (seed 1,000,003). The one training
#: pipeline of issue #39 retrains the left turn's (``paper`` is); until then every summary of
#: them says so.
MISSING_TARGETS = {
    "certified": (
        "needs the safety action in 189 of 1,000 scenarios and clears 897 (efficiency 0.80): "
        "trained before tyre friction; retrained on this plant its recipe reaches at best "
        "0.845 of the oracle and 97-98 % cleared (docs/learning_experiments.md), to be "
        "retrained (issue #39)"
    ),
    "traffic_certified": (
        "clears 56 of 1,000 test-family scenes, fewer than the rule under the same filter "
        "(73): trained before tyre friction, to be retrained (issue #39)"
    ),
    "highway_certified": (
        "the Safety controller acts on 1.18 % of its 50 evaluation episodes' steps, above the "
        "0.5 % issue #39 asks (its fallback, no more often than highway-env's IDM/MOBIL driver "
        "under the same logic, 36.7 %, holds): all 89 steps keep it from closing on the car "
        "ahead (docs/highway.md)"
    ),
}


def missing_targets(model: object) -> str | None:
    """Why the shipped policy named ``model`` misses its targets, or ``None`` (also for any
    model that is not a shipped policy's name)."""
    folder = SHIPPED.get(str(model))
    return None if folder is None else MISSING_TARGETS.get(folder)
