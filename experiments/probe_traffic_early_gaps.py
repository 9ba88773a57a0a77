"""Where PPO from a random start loses to the gap planner in traffic from every leg.

A one-off probe for docs/learning_experiments.md ("Where PPO loses to the gap planner in
traffic"): the gap planner and a trained policy under `certified` (the narrower zones of the
from-scratch recipes) on the 1,000 `test` scenes of seed 1000003; prints how many scenes each
clears within the left turn's 12 s and after, and what the policy did in the scenes the gap
planner clears within 12 s and it never clears. Run (after `safeswitch train --config
experimental/traffic_certified_constrained_hold15 --seed 1 --out runs/hold15_s1`):
``python experiments/probe_traffic_early_gaps.py runs/hold15_s1``.
"""

import sys
import tempfile
from pathlib import Path

import pandas as pd

from safeswitch.app.evaluate import evaluate

ZONES = ("env.certified.ego_max_lateral_m=0.45", "env.certified.zone_margin_m=0.9")


def episodes(out: Path, controller: str, model: str | None) -> pd.DataFrame:
    settings = ZONES if model is None else ()
    evaluate(controller, model, "random", 1000, 1_000_003, "certified" if model is None else None,
             out, traffic="test", settings=settings)  # fmt: skip
    return pd.read_csv(out / "episodes.csv")


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        planner = episodes(Path(tmp) / "gap_planner", "gap_planner", None)
        policy = episodes(Path(tmp) / "policy", "learned", sys.argv[1])
    for name, frame in (("gap planner", planner), ("policy", policy)):
        t = frame["time_to_clear_s"]
        print(
            f"{name}: cleared {t.notna().sum()}, within 12 s {(t <= 12).sum()}, "
            f"after {(t > 12).sum()}; safety episodes {(frame['safety_steps'] > 0).sum()}"
        )
    early = planner["time_to_clear_s"] <= 12
    lost = early & policy["time_to_clear_s"].isna()
    both = early & policy["time_to_clear_s"].notna()
    late = (policy["time_to_clear_s"] - planner["time_to_clear_s"])[both]
    print(
        f"the gap planner clears {early.sum()} within 12 s; the policy clears {both.sum()} of "
        f"them ({late.mean():.2f} s later on average) and never clears {lost.sum()}"
    )
    print(
        f"in those {lost.sum()}: the policy stopped (under 1 km/h) in "
        f"{(policy['min_speed_kmh'][lost] < 1).sum()}, needed the filter in "
        f"{(policy['safety_steps'][lost] > 0).sum()}, drove at most "
        f"{policy['max_speed_kmh'][lost].mean():.1f} km/h on average; the gap planner cleared "
        f"them at {planner['time_to_clear_s'][lost].mean():.1f} s on average "
        f"({(planner['outcome'][lost] == 'cut').sum()} in front of the conflicting vehicle, "
        f"{(planner['outcome'][lost] == 'yield').sum()} behind it), "
        f"the filter in {(planner['safety_steps'][lost] > 0).sum()}"
    )


if __name__ == "__main__":
    main()
