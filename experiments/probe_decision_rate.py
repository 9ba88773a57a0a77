"""How much the learned controller's decision rate costs in traffic (issue #39;
docs/learning_experiments.md, "The decision rate in traffic").

The shipped `traffic-certified` recipe holds each learned action for 0.3 s
(`episode.decision_interval: 15`), which is what lets PPO from a random start leave the waiting
basin ("A coarser decision rate"); the gap planner it is measured against rechecks its go
decision every 0.1 s and, in `benchmarks/traffic_certified.py`'s target row, acts every tick.
This probe drives the gap planner under the recipe's scene (its filter, limiters and learned
brake) on the 1,000 `test` scenes of seed 1000003 with each action held for 1, 5 and 15 ticks:
the differences are what the coarser rates alone cost a controller that otherwise decides as
the planner does. Run: ``python experiments/probe_decision_rate.py [traffic_certified]``
(about five minutes, one core).
"""

import sys

from probe_go_rule import score_rules, test_scenes

from safeswitch.evaluation.traffic_planner import GapPlanner


def main() -> None:
    name = sys.argv[1] if len(sys.argv) > 1 else "traffic_certified"
    for ticks in (1, 5, 15):
        task, scenes = test_scenes(name, decision_interval=ticks)
        rule = (f"gap planner, each action held {ticks} ticks", GapPlanner(task))
        score_rules(task, [rule], scenes)


if __name__ == "__main__":
    main()
