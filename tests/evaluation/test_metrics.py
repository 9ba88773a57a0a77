"""The evaluation summary's comfort counts, and a campaign's shards merged into one."""

import json

import numpy as np

from safeswitch.evaluation.adversaries import catalogue
from safeswitch.evaluation.metrics import SummaryAccumulator, summarize
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.config import resolve_config
from safeswitch.leftturn.task import LeftTurnTask


def results():
    """Two chunks of episodes with comfort broken in some and not in others: a random
    driver's and the rule's."""
    task = LeftTurnTask(resolve_config({"episode": {"learned_scope": "episode"}}))
    scenarios = task.scenario_set(11, 64)
    random = rollout(task, scenarios, catalogue(task, 64, 2)["bang_bang"]())
    calm = rollout(task, scenarios, catalogue(task, 64, 2)["zero_throttle"]())
    return random, calm


def test_episodes_with_a_comfort_limit_broken_are_counted_beside_the_ticks():
    random, calm = results()
    broken = random.comfort_violation_steps > 0
    assert 0 < broken.sum() < broken.size  # some episodes, not all: the count can tell
    s = summarize(random)
    assert s["comfort_violation_episodes"] == int(broken.sum())
    assert s["comfort_violation_steps"] == int(random.comfort_violation_steps.sum())
    assert s["comfort_violation_steps"] > s["comfort_violation_episodes"]
    both = SummaryAccumulator()
    both.add(random)
    both.add(calm)
    calm_broken = int((calm.comfort_violation_steps > 0).sum())
    assert both.summary()["comfort_violation_episodes"] == int(broken.sum()) + calm_broken


def test_a_shard_written_before_a_count_existed_makes_it_unknown_not_short():
    random, calm = results()
    new, old = SummaryAccumulator(), SummaryAccumulator()
    new.add(random)
    old.add(calm)
    state = json.loads(json.dumps(old.state()))  # as a shard file holds it
    assert SummaryAccumulator.from_state(state).summary() == old.summary()
    del state["counts"]["comfort_violation_episodes"]
    del state["unknown"]  # a shard written by the version before
    merged = SummaryAccumulator.from_state(new.state())
    merged.merge(SummaryAccumulator.from_state(state))
    s = merged.summary()
    assert s["comfort_violation_episodes"] is None
    assert s["episodes"] == 128 and s["comfort_violation_steps"] == int(
        random.comfort_violation_steps.sum() + calm.comfort_violation_steps.sum()
    )
    # and it stays unknown through a further round trip (a merged campaign written again)
    again = SummaryAccumulator.from_state(json.loads(json.dumps(merged.state())))
    assert again.summary()["comfort_violation_episodes"] is None
    assert np.isfinite(s["comfort_violation_fraction"])
