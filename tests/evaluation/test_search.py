"""The open-loop search (:mod:`safeswitch.evaluation.search`): a policy's actions replayed
open loop drive exactly its episodes, the search never ranks a scene below where it started
and reports what its sequences drive, and its smooth perturbations are linear between knots."""

from dataclasses import replace

import numpy as np
import pytest

from safeswitch.evaluation.evaluate import scenario_set
from safeswitch.evaluation.rollout import rollout
from safeswitch.evaluation.search import (
    drive_open_loop,
    family_of_drivers,
    policy_actions,
    search_sequences,
    smooth_noise,
)
from safeswitch.leftturn.spaces import throttle_scene
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.training.config import load_config
from safeswitch.training.policies import load_policy


@pytest.fixture(scope="module")
def scene():
    env = load_config("certified").env
    task = LeftTurnTask(replace(env, episode=replace(env.episode, learned_scope="episode")))
    scenarios, _ = scenario_set(task, "random", 24, 7_000_001)
    return task, scenarios


@pytest.fixture(scope="module")
def throttle(scene):
    """The same scene with the paper's learned action, the throttle alone (the shipped
    `certified` policy works both pedals): where -1 closes the throttle, as the searches from a
    closed throttle below assume."""
    task, scenarios = scene
    return LeftTurnTask(throttle_scene(task.config)), scenarios


def rank(clear, dirty):
    """What the search minimises, as comparable tuples: never cleared, dirty ticks, time."""
    return [(bool(np.isnan(c)), int(d), 0.0 if np.isnan(c) else float(c))
            for c, d in zip(clear, dirty, strict=True)]  # fmt: skip


def test_a_policys_actions_replayed_open_loop_drive_its_episodes(scene):
    task, scenarios = scene
    act = load_policy("certified").as_policy()
    closed = rollout(task, scenarios, act)
    actions, own_clear, own_dirty, first = policy_actions(task, scenarios, act)
    clear, _, dirty = drive_open_loop(task, scenarios, actions)
    np.testing.assert_array_equal(clear, np.asarray(closed.time_to_clear, dtype=float))
    np.testing.assert_array_equal(
        dirty, closed.comfort_violation_steps + closed.speeding_steps + closed.safety_steps
    )
    # what it reports of its own episodes is what the replay drives
    np.testing.assert_array_equal(own_clear, clear)
    np.testing.assert_array_equal(own_dirty, dirty)
    np.testing.assert_array_equal(first < 0, own_dirty == 0)


def test_the_first_dirty_tick_is_where_the_dirty_ticks_begin(scene):
    task, scenarios = scene
    some = scenarios.take(np.arange(4))
    _, _, dirty, first = policy_actions(task, some, lambda obs, state, tick: np.ones(4))
    assert (dirty > 0).all() and (first >= 50).all()  # full throttle breaks a rule, not at once
    # cut each episode short: before its first dirty tick it is clean, with it it is not
    for i in range(4):
        one = some.take(np.array([i]))
        for ticks, expected_dirty in ((first[i], False), (first[i] + 1, True)):
            short = replace(task.config.episode, horizon_s=ticks * task.config.episode.dt)
            cut = LeftTurnTask(replace(task.config, episode=short))
            assert cut.config.episode.horizon_ticks == ticks
            _, _, dirty_cut = drive_open_loop(cut, one, np.ones((1, 1)))
            assert bool(dirty_cut[0] > 0) == expected_dirty, (i, ticks)


@pytest.mark.parametrize("knot", [1, 5])
def test_the_search_ranks_no_scene_below_its_start(throttle, knot):
    task, scenarios = throttle
    start = np.full((24, 24), -1.0)  # the throttle closed throughout: never clears
    clear0, _, dirty0 = drive_open_loop(task, scenarios, start)
    assert np.isnan(clear0).all()
    clear, dirty, seqs = search_sequences(
        task, scenarios, start, population=24, rounds=3, seed=3,
        seeds=family_of_drivers(24), knot=knot,
    )  # fmt: skip
    assert all(a <= b for a, b in zip(rank(clear, dirty), rank(clear0, dirty0), strict=True))
    assert (~np.isnan(clear)).sum() >= 12  # it finds clears the start never makes
    # what it reports is what its sequences drive
    again, _, dirty_again = drive_open_loop(task, scenarios, seqs)
    np.testing.assert_array_equal(again, clear)
    np.testing.assert_array_equal(dirty_again, dirty)


@pytest.mark.slow
def test_a_margin_counts_the_dirty_ticks_of_the_pushed_sequences_too(scene):
    task, scenarios = scene
    start, _, own_dirty, _ = policy_actions(task, scenarios, load_policy("certified").as_policy())
    assert (own_dirty == 0).sum() >= 20  # the policy's own episodes are clean

    def pushed(seqs, margin):
        return sum(
            drive_open_loop(task, scenarios, np.clip(seqs + shift, -1.0, 1.0))[2]
            for shift in (0.0, margin, -margin)
        )

    plain = search_sequences(task, scenarios, start, population=24, rounds=3, seed=3, knot=5)
    clear, dirty, seqs = search_sequences(
        task, scenarios, start, population=24, rounds=3, seed=3, knot=5, margin=0.1
    )
    # it reports the three episodes' dirty ticks, and its own time to clear
    np.testing.assert_array_equal(dirty, pushed(seqs, 0.1))
    np.testing.assert_array_equal(clear, drive_open_loop(task, scenarios, seqs)[0])
    # the plain search's labels are clean but not with their neighbours; the margin's
    # ranking finds sequences clean with them in more scenes
    assert (plain[1] == 0).sum() >= 20
    assert (pushed(plain[2], 0.1) == 0).sum() < (dirty == 0).sum()
    with pytest.raises(ValueError, match="margin must be in"):
        search_sequences(task, scenarios, start, population=4, rounds=1, seed=0, margin=1.0)


def test_frozen_segments_keep_the_start_and_the_search_changes_the_rest(throttle):
    task, scenarios = throttle
    start = np.full((24, 24), -1.0)  # the throttle closed throughout: never clears
    frozen = np.arange(24) % 12  # up to 5.5 s of closed throttle kept
    clear, dirty, seqs = search_sequences(
        task, scenarios, start, population=16, rounds=2, seed=5,
        seeds=family_of_drivers(24), frozen=frozen,
    )  # fmt: skip
    for i, held in enumerate(frozen):
        np.testing.assert_array_equal(seqs[i, :held], -1.0)
    assert (~np.isnan(clear)).sum() >= 12  # what follows was searched: it clears
    again, _, dirty_again = drive_open_loop(task, scenarios, seqs)
    np.testing.assert_array_equal(again, clear)
    np.testing.assert_array_equal(dirty_again, dirty)
    with pytest.raises(ValueError, match="frozen needs a start"):
        search_sequences(task, scenarios, None, population=4, rounds=1, seed=0,
                         seeds=family_of_drivers(24), frozen=frozen)  # fmt: skip


def test_a_search_needs_a_start_or_seeds(scene):
    task, scenarios = scene
    with pytest.raises(ValueError, match="a start or seeds"):
        search_sequences(task, scenarios, None, population=4, rounds=1, seed=0)


def test_smooth_perturbations_are_linear_between_knots():
    rng = np.random.default_rng(0)
    noise = smooth_noise(rng, (3, 4, 20), knot=5)
    assert noise.shape == (3, 4, 20)
    second = np.diff(noise, 2, axis=-1)  # zero inside each knot interval, not at the knots
    inside = [i for i in range(18) if (i + 1) % 5 != 0]
    np.testing.assert_allclose(second[..., inside], 0.0, atol=1e-12)
    assert np.abs(second[..., 4]).min() > 0  # a bend at the knot (segment 5)
    independent = smooth_noise(np.random.default_rng(0), (3, 4, 20), knot=1)
    assert np.abs(np.diff(independent, 2, axis=-1)).min() > 0
