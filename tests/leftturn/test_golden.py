"""The left turn decides exactly as recorded (see ``golden.py``)."""

import numpy as np
import pytest

from tests.leftturn.golden import COLUMNS, PATH, PRE_FRICTION, digest, digest_and_slides, runs


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
