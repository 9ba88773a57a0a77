"""Is the shipped traffic policy limited by its go predictor's mistakes? (issue #39;
docs/learning_experiments.md, "The exact go check in place of the predictor").

The `traffic-certified` policy reads a learned go predictor's probability as the last value of
its observation: that the planners' fast drive from here passes every conflict zone without the
filter acting. The predictor approximates a forward simulation that needs only what a car can
see (the gap planner's go check with ``foresight: observed``: the vehicles on the approaches
now, every driver one who never yields). This one-off probe drives the shipped policy on the
1,000 `test` scenes of seed 1000003 under `certified` three times: as trained (the predictor),
and with that value replaced by the simulated check itself (1 or 0; recomputed at each of the
policy's decisions, held in between), seeing what a car could and seeing everything. No
training; the policy is unchanged.

Run: ``python experiments/probe_exact_go_feature.py [EPISODES [MODEL]]`` (MODEL: a run of the
recipe instead of the shipped policy; one core: 18 s as trained, 75 s with each check, for
1,000 scenes).
"""

import sys
from typing import Any

import numpy as np
from probe_go_rule import score_rules, test_scenes

from safeswitch.app.evaluate import controller_setup, fit_observations
from safeswitch.evaluation.planner_config import GapPlannerConfig
from safeswitch.evaluation.traffic_planner import GapPlanner

#: The policy driven unless another is given.
MODEL = "traffic-certified"


def exact_go(task, foresight: str = "observed") -> None:
    """Replace ``task``'s go predictor value (the observation's last) by the gap planner's
    simulated check from the same state, computed at each decision tick and held between (the
    check is built at the first observation; also ``experiments/finetune_exact_go.py``'s)."""
    if task.go_model is None:
        return
    interval = task.config.episode.decision_interval
    complete = task.complete_observation
    held: dict[str, Any] = {}

    def observation(state, observed):
        out = complete(state, observed)
        if "check" not in held:
            held["check"] = GapPlanner(task, GapPlannerConfig(foresight=foresight))
        check = held["check"]
        if "go" not in held or held["go"].shape[0] != out.shape[0]:
            held["go"] = check.passes(state).astype(np.float32)
        else:
            rows = np.flatnonzero(state.tick % interval == 0)
            if rows.size:
                held["go"][rows] = check.passes(state.take(rows))
        out[:, -1] = held["go"]
        return out

    task.complete_observation = observation


def main() -> None:
    episodes = int(sys.argv[1]) if len(sys.argv) > 1 else 1000
    model = sys.argv[2] if len(sys.argv) > 2 else MODEL
    for label, foresight in (
        ("the predictor (as trained)", None),
        ("the exact check, observed", "observed"),
        ("the exact check, full foresight", "full"),
    ):
        task, scenes = test_scenes("traffic_certified", episodes)
        _, policy = controller_setup("learned", model, "certified")
        policy = fit_observations(policy, model, task)
        if foresight is not None:
            exact_go(task, foresight)
        score_rules(task, [(label, policy)], scenes)


if __name__ == "__main__":
    main()
