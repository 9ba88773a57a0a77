"""Closed-loop behaviour of the left turn with scripted learned controllers."""

import numpy as np
import pytest

from safeswitch.leftturn import make_vec_env
from safeswitch.leftturn.config import LeftTurnConfig
from safeswitch.leftturn.scenarios import named_scenarios
from safeswitch.leftturn.task import OUTCOMES, LeftTurnTask

from .conftest import cruise_action


def run_episodes(vec, policy, episodes_per_env=1):
    """Roll a VecEnv until every environment has finished ``episodes_per_env`` episodes."""
    obs = vec.reset()
    finished = np.zeros(vec.num_envs, dtype=int)
    summaries = []
    while (finished < episodes_per_env).any():
        obs, _, dones, infos = vec.step(policy(obs))
        for i in np.flatnonzero(dones & (finished < episodes_per_env)):
            summaries.append(infos[i]["episode"])
        finished += dones
    return summaries


def full_throttle(obs):
    return np.ones((obs.shape[0], 1))


def test_full_throttle_collides_without_a_safety_net_in_some_random_scenarios():
    vec = make_vec_env(
        512, switching="none", seed=11, config={"episode": {"learned_scope": "episode"}}
    )
    collisions = np.array([s["collision"] for s in run_episodes(vec, full_throttle)])
    assert 0.05 < collisions.mean() < 0.6


@pytest.mark.parametrize("scenario", ["yield1", "yield2"])
def test_paper_safety_controller_stops_full_throttle_before_the_conflict_point(scenario):
    task = LeftTurnTask(LeftTurnConfig(switching="paper"))
    state = task.initial(named_scenarios(scenario, 1))
    activated, stopped_at = False, None
    for _ in range(task.config.episode.horizon_ticks):
        state, record = task.step(state, np.ones(1))
        assert not record.collision[0]
        activated |= bool(record.safety_active[0])
        if record.ego_speed[0] == 0.0 and stopped_at is None:
            stopped_at = state.world.progress[0, 0]
    assert activated
    assert stopped_at is not None and stopped_at < task.conflict.s_point_a
    assert stopped_at <= task.conflict.zone_a[0]  # outside the conflict zone, even


def test_a_cruise_at_the_speed_limit_passes_in_front_in_cut():
    task = LeftTurnTask(LeftTurnConfig(switching="paper"))
    state = task.initial(named_scenarios("cut", 1))
    for _ in range(task.config.episode.horizon_ticks):
        state, record = task.step(state, cruise_action(state.world.vehicles.speed[:, 0]))
        assert not record.collision[0] and not record.safety_active[0]
    assert OUTCOMES[state.outcome[0]] == "cut"


def test_the_random_scenarios_need_cutting_and_yielding_in_a_good_share():
    """A cruise at the limit, unshielded, shows which answer each scenario needs: it passes
    first where cutting in front is right and collides where yielding is."""
    vec = make_vec_env(
        1000, switching="none", seed=3, config={"episode": {"learned_scope": "episode"}}
    )
    summaries = run_episodes(vec, lambda obs: cruise_action(obs[:, 2])[:, None])
    collided = np.array([s["collision"] for s in summaries])
    cut = np.array([OUTCOMES[s["outcome"]] == "cut" for s in summaries]) & ~collided
    assert cut.mean() > 0.25 and collided.mean() > 0.2


def test_yield2_needs_the_ego_to_wait_longer_than_yield1():
    """The north car arrives later in yield2: a shielded cruise clears the zone later."""
    clear = {}
    for scenario in ("yield1", "yield2"):
        vec = make_vec_env(1, config=LeftTurnConfig(switching="paper", scenario=scenario), seed=0)
        clear[scenario] = run_episodes(vec, lambda obs: cruise_action(obs[:, 2])[:, None])[0][
            "time_to_clear"
        ]
    assert clear["yield2"] > clear["yield1"] + 0.5


def test_a_subset_of_episodes_steps_exactly_as_it_does_in_the_full_batch():
    task = LeftTurnTask(LeftTurnConfig(switching="paper"))
    n = 64
    state = task.initial(task.draw_scenarios(5, np.arange(n), np.zeros(n, dtype=np.int64)))
    rows = np.array([3, 17, 40, 63])
    part = state.take(rows)
    assert part.batch_size == len(rows)
    rng = np.random.default_rng(0)
    for _ in range(300):
        actions = rng.uniform(-1.0, 1.0, n)
        state, record = task.step(state, actions)
        part, part_record = task.step(part, actions[rows])
        np.testing.assert_array_equal(part.world.progress, state.world.progress[rows])
        np.testing.assert_array_equal(part_record.safety_active, record.safety_active[rows])
    assert np.ptp(state.world.progress[rows, 0]) > 1.0  # the episodes differ
    # a copy: stepping it leaves the original alone
    before = state.world.progress.copy()
    task.step(state.take(rows), actions[rows])
    np.testing.assert_array_equal(state.world.progress, before)
