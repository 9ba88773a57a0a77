"""Does PPO from a random start lean on courteous drivers in traffic from every leg?

A one-off probe for docs/learning_experiments.md ("Does the policy lean on courteous
drivers?"): the `train` family holds 0-50 % non-yielding drivers, the `test` family 50-100 % in
denser flows. The gap planner (under `certified` with the narrower zones of the from-scratch
recipes) and trained policies on 1,000 scenes (seed 1000003) of four families: `train`, `train`
with the `test` family's share of non-yielding drivers, `test` with the `train` family's share,
and `test`. If PPO's deficit against the gap planner grows with the share of non-yielding
drivers more than with the flows, it has learned to wait for a driver who gives way. Run (after
`python benchmarks/train_seeds.py --config experimental/traffic_certified_time_left_terminal_g997
--seeds N --keep DIR`): ``python experiments/probe_traffic_courtesy.py DIR/seed_1 DIR/seed_2 …``.
"""

import sys

from safeswitch.app.evaluate import evaluate
from safeswitch.training.config import load_config

#: The recipe the policies were trained by; the gap planner drives under its filter's zones.
RECIPE = "experimental/traffic_certified_time_left_terminal_g997"
FAMILIES = {
    "train": {"preset": "train"},
    "train flows, test courtesy": {"preset": "train", "non_yielding_share": [0.5, 1.0]},
    "test flows, train courtesy": {"preset": "test", "non_yielding_share": [0.0, 0.5]},
    "test": {"preset": "test"},
}


def main() -> None:
    zones = load_config(RECIPE).env.certified
    settings = (f"env.certified.ego_max_lateral_m={zones.ego_max_lateral_m}",
                f"env.certified.zone_margin_m={zones.zone_margin_m}")  # fmt: skip
    controllers = [("gap planner", "gap_planner", None)]
    controllers += [(f"policy {run}", "learned", run) for run in sys.argv[1:]]
    print("| controller | family | safety episodes | cleared | efficiency |")
    print("|---|---|---:|---:|---:|")
    for name, controller, model in controllers:
        for family, traffic in FAMILIES.items():
            s = evaluate(controller, model, "random", 1000, 1_000_003,
                         "certified" if model is None else None, None, traffic=traffic,
                         settings=settings if model is None else ())  # fmt: skip
            assert s["collisions"] == 0, (name, family, s["collisions"])
            print(
                f"| {name} | {family} | {s['safety_activation_episodes']} | "
                f"{s['cleared_episodes']} | {s['mean_efficiency']:.3f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
