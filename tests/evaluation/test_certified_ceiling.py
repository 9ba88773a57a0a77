"""``benchmarks/certified_ceiling.py``'s careful search (and ``search_refinement.py``, which
starts from a policy's actions): a policy's actions replayed open loop drive exactly its
episodes, and the search never ranks a scene below where it started."""

import importlib.util
import sys
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from safeswitch.evaluation.evaluate import scenario_set
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.training.config import load_config
from safeswitch.training.policies import load_policy

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture(scope="module")
def ceiling():
    sys.path.insert(0, str(BENCHMARKS))
    try:
        spec = importlib.util.spec_from_file_location(
            "ceiling_under_test", BENCHMARKS / "certified_ceiling.py"
        )
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.path.remove(str(BENCHMARKS))
        sys.modules.pop("ceiling_under_test", None)


@pytest.fixture(scope="module")
def scene():
    env = load_config("certified").env
    task = LeftTurnTask(replace(env, episode=replace(env.episode, learned_scope="episode")))
    scenarios, _ = scenario_set(task, "random", 24, 7_000_001)
    return task, scenarios


def rank(clear, dirty):
    """What the search minimises, as comparable tuples: never cleared, dirty ticks, time."""
    return [(bool(np.isnan(c)), int(d), 0.0 if np.isnan(c) else float(c))
            for c, d in zip(clear, dirty, strict=True)]  # fmt: skip


def test_a_policys_actions_replayed_open_loop_drive_its_episodes(ceiling, scene):
    task, scenarios = scene
    act = load_policy("certified").as_policy()
    closed = rollout(task, scenarios, act)
    actions = ceiling.policy_actions(task, scenarios, act)
    clear, _, dirty = ceiling.drive_open_loop(task, scenarios, actions)
    np.testing.assert_array_equal(clear, np.asarray(closed.time_to_clear, dtype=float))
    np.testing.assert_array_equal(
        dirty, closed.comfort_violation_steps + closed.speeding_steps + closed.safety_steps
    )


def test_the_careful_search_ranks_no_scene_below_its_start(ceiling, scene):
    task, scenarios = scene
    start = np.full((24, 24), -1.0)  # the throttle closed throughout: never clears
    clear0, _, dirty0 = ceiling.drive_open_loop(task, scenarios, start)
    assert np.isnan(clear0).all()
    search = SimpleNamespace(seed=3, population=24, rounds=3)
    seeds = ceiling.family_of_drivers(24)
    clear, dirty, seqs = ceiling.search_sequences(task, scenarios, start, search, seeds=seeds)
    assert all(a <= b for a, b in zip(rank(clear, dirty), rank(clear0, dirty0), strict=True))
    assert (~np.isnan(clear)).sum() >= 12  # it finds clears the start never makes
    # what it reports is what its sequences drive
    again, _, dirty_again = ceiling.drive_open_loop(task, scenarios, seqs)
    np.testing.assert_array_equal(again, clear)
    np.testing.assert_array_equal(dirty_again, dirty)
