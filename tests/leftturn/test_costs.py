"""The left turn publishes its named costs through the channel every plant uses
(``info["cost"]``, ``info["costs"]``; issue #39): summed over an episode they are the
episode's own counts, in the single Env and the VecEnv alike, and the generic pipeline's
constraints read them by name."""

import numpy as np
import pytest

from safeswitch.leftturn import LeftTurnEnv, make_vec_env
from safeswitch.leftturn.statistics import PUBLISHED_COSTS

#: Full throttle for the whole episode under the paper's logic: speeding, hard braking when
#: the safety action fires, and (in some scenarios) the ego never clear.
CONFIG = {"episode": {"learned_scope": "episode", "decision_interval": 5}}


def _episode_sums(env, action):
    sums = dict.fromkeys(PUBLISHED_COSTS, 0.0)
    intervention, steps = 0.0, 0
    while True:
        _, _, terminated, truncated, info = env.step(np.array([action], dtype=np.float32))
        assert set(info["costs"]) == set(PUBLISHED_COSTS)
        for name, value in info["costs"].items():
            assert 0 <= value <= 5 and value == int(value)  # ticks of a 5-tick step
            sums[name] += value
        assert info["cost"] == (1.0 if info["safety_active"] else 0.0)
        intervention += info["cost"]
        steps += 1
        if terminated or truncated:
            return sums, intervention, steps


@pytest.mark.parametrize("action", [1.0, 0.3])
def test_the_costs_summed_over_an_episode_are_the_episodes_own_counts(action):
    vec = make_vec_env(1, seed=11, switching="paper", config=CONFIG)
    vec.reset()
    sums = dict.fromkeys(PUBLISHED_COSTS, 0.0)
    while True:
        _, _, done, infos = vec.step(np.array([[action]], dtype=np.float32))
        for name, value in infos[0]["costs"].items():
            sums[name] += value
        if done[0]:
            episode = infos[0]["episode"]
            break
    assert sums["speeding"] == episode["speeding_steps"]
    assert sums["comfort"] == episode["comfort_violation_steps"]
    assert sums["safety"] == episode["safety_steps"]
    cleared = episode["time_to_clear"]
    ticks = episode["l"]
    if np.isnan(cleared):
        assert sums["uncleared"] == ticks
    else:  # the ticks before the one the ego cleared on
        assert sums["uncleared"] == round(cleared / 0.02) - 1
    # the single Env publishes the same numbers for the same scenario
    env = LeftTurnEnv(switching="paper", config=CONFIG)
    env.reset(seed=11)
    single, _, _ = _episode_sums(env, action)
    assert single == sums
    if action == 1.0:  # full throttle speeds and meets the safety action: the counts are live
        assert sums["speeding"] > 0 and sums["safety"] > 0


def test_an_infos_costs_stay_those_of_its_own_step():
    """The VecEnv's infos are lazy: read after later steps, they still hold their step's
    costs (the counters are fresh arrays each step, not overwritten)."""
    vec = make_vec_env(2, seed=3, switching="paper", config=CONFIG)
    vec.reset()
    kept = []
    for _ in range(40):
        _, _, _, infos = vec.step(np.ones((2, 1), dtype=np.float32))
        kept.append((infos, [dict(info["costs"]) for info in infos]))
    for infos, read_then in kept:
        assert [dict(info["costs"]) for info in infos] == read_then


def test_the_generic_constraints_read_the_left_turns_costs_by_name():
    """One channel: ``NamedCostConstraints`` — the pipeline's constraints for any plant —
    charges the left turn's published ``speeding`` at its multiplier, and the switch's
    ``intervention`` from ``info["cost"]``."""
    from safeswitch.training.config import ConstraintConfig
    from safeswitch.training.constraints import NamedCostConstraints

    def twins():
        return make_vec_env(2, seed=7, switching="paper", config=CONFIG)

    plain = twins()
    charged = NamedCostConstraints(
        twins(),
        {"speeding": ConstraintConfig(budget=0.01), "intervention": ConstraintConfig(budget=0.01)},
        1,
    )
    charged.multipliers["speeding"].value = 2.0
    charged.multipliers["intervention"].value = 0.5
    plain.reset()
    charged.reset()
    seen = 0.0
    for _ in range(60):
        action = np.ones((2, 1), dtype=np.float32)
        _, r_plain, _, infos = plain.step(action)
        _, r_charged, _, _ = charged.step(action)
        expected = np.array(
            [2.0 * info["costs"]["speeding"] + 0.5 * info["cost"] for info in infos]
        )
        np.testing.assert_allclose(r_plain - r_charged, expected, rtol=1e-5, atol=1e-4)
        seen += expected.sum()
    assert seen > 0  # the charge was not vacuous


def test_counting_off_publishes_no_costs():
    vec = make_vec_env(1, seed=1, config=CONFIG)
    vec.count_costs = False
    vec.reset()
    _, _, _, infos = vec.step(np.ones((1, 1), dtype=np.float32))
    assert "costs" not in infos[0] and "cost" in infos[0]
