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
}
