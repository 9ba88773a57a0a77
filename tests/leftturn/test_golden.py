"""The left turn decides exactly as recorded (see ``golden.py``)."""

import numpy as np
import pytest

from safeswitch.leftturn.config import resolve_config
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.training.policies import load_policy
from tests.leftturn.golden import (
    COLUMNS,
    PATH,
    POLICIES,
    PRE_FRICTION,
    digest,
    digest_and_slides,
    portable_parameters,
    runs,
)  # fmt: skip
from tests.leftturn.portable import GRID, portable_driver


@pytest.fixture(scope="module")
def recorded_runs():
    return {name: (config, make) for name, config, make in runs()}


@pytest.mark.parametrize("name", list(np.load(PATH).keys()))
def test_every_decision_is_bit_for_bit_what_was_recorded(recorded_runs, name):
    config, make_policy = recorded_runs[name]
    recorded = np.load(PATH)[name]
    now = digest(config, make_policy)
    for j, column in enumerate(COLUMNS):
        differ = np.flatnonzero(now[:, j] != recorded[:, j])
        assert differ.size == 0, f"{name}: {column} differs in episodes {differ[:10].tolist()}"


@pytest.mark.parametrize("name", list(np.load(PRE_FRICTION).keys()))
def test_before_the_friction_circle_only_episodes_that_slid_differ(
    recorded_runs, name, monkeypatch
):
    """The one-kernel logics and the unified scene decide as 01d647c did, once the curve
    certificate is switched off (a straight route for it): the only episodes that differ are
    those in which the ego's tyres slid (issue #37's plant)."""
    from safeswitch.leftturn.task import LeftTurnTask

    def straight(task):
        route = task.world.routes[0]
        return route.spacing, np.zeros(len(route.points))

    monkeypatch.setattr(LeftTurnTask, "ego_curvature", straight)
    config, make_policy = recorded_runs[name]
    now, slid = digest_and_slides(config, make_policy)
    differ = np.any(now != np.load(PRE_FRICTION)[name], axis=1)
    assert not (differ & ~slid).any(), np.flatnonzero(differ & ~slid)[:10]


@pytest.mark.parametrize("name", ["paper_warm", "paper_scratch"])
def test_the_portable_driver_is_the_policy_it_stands_for(name):
    """The golden runs' learned controller (numpy, no BLAS: the same on every CPU) computes
    the policy's own deterministic action on the states it drives, up to float32 sums."""
    policy = load_policy(POLICIES / name)
    act = portable_driver(portable_parameters(policy))
    config = resolve_config({"episode": {"learned_scope": "episode"}})
    task = LeftTurnTask(config)
    n = 64
    state = task.initial(task.draw_scenarios(7, np.arange(n), np.zeros(n, dtype=np.int64)))
    observation, seen = task.observe(state), []
    for tick in range(config.episode.horizon_ticks):
        actions = act(observation, state, tick)
        seen.append((observation, actions))
        state, record = task.step(state, actions)
        observation = record.observation
    obs = np.concatenate([o for o, _ in seen])
    ours = np.concatenate([a for _, a in seen])
    theirs, _ = policy.model.predict(policy.normalise(obs), deterministic=True)
    # torch sums in float32: a few 1e-6 from the float64 sums, wherever it runs
    assert np.abs(ours - theirs.reshape(-1)).max() < 1e-5
    assert np.array_equal(ours * GRID, np.rint(ours * GRID))  # on the grid
    assert ours.max() - ours.min() > 1.0  # the states span much of the policy's range
