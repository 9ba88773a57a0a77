import math

import numpy as np
import pytest

from safeswitch.core.registry import logic_names
from safeswitch.core.switching import INVALID_LEARNED_ACTION, NeverSwitch, reason_names, supervise
from safeswitch.leftturn.config import PaperSwitchingConfig
from safeswitch.leftturn.logics.paper import (
    PaperSwitching,
    braking_distance,
    time_to_reach,
)
from safeswitch.leftturn.scenarios import named_scenarios
from safeswitch.leftturn.views import NorthConflict, north_view

CFG = PaperSwitchingConfig()
DECEL = 6.0


def test_ttr_uses_the_path_distance_along_the_curve(task):
    g = task.config.geometry
    radius = g.box_half_size + g.lane_width / 2
    # Hand computation: the conflict point on the 11.75 m arc centred at (-10, -10), where the
    # north car's lane (x = -1.75) crosses it; the ego stands at the stop line, where the arc
    # starts, so the path distance is R·θ (not the 8.4 m straight line).
    theta = math.acos((-g.lane_width / 2 + g.box_half_size) / radius)
    state = task.initial(named_scenarios("cut", 1))
    state.world.progress[0, 0] = g.approach_length  # the stop line
    conflict = task.view(state)
    assert conflict.ego_to_conflict[0] == pytest.approx(radius * theta, abs=0.01)
    straight_line = np.linalg.norm(
        task.conflict.point - np.array([g.lane_width / 2, -g.box_half_size])
    )
    assert radius * theta > straight_line + 0.2
    ttr = time_to_reach(conflict.ego_to_conflict, np.array([5.0]), CFG.min_speed)
    assert ttr[0] == pytest.approx(radius * theta / 5.0, abs=0.01)


def test_ttr_guards_zero_speed_and_braking_distance_is_eq3():
    assert time_to_reach(np.array([10.0]), np.array([0.0]), 0.1)[0] == pytest.approx(100.0)
    assert braking_distance(np.array([7.0]), 6.0)[0] == pytest.approx(49 / 12)


def make_state(ego_to_stop, ego_speed=7.0, gap=0.0, at=True):
    """A state whose ``TTR_n - TTR_e`` is ``CFG.ttr_threshold_s + gap`` (one conflict, measured
    from the ego at 0 and the north car at 0)."""
    ego_to_conflict = ego_to_stop + 5.0
    ttr_e = ego_to_conflict / ego_speed
    north_speed = 8.0
    north_to_conflict = (ttr_e + CFG.ttr_threshold_s + gap) * north_speed
    geometry = NorthConflict(
        ego_point=ego_to_conflict, ego_zone=(ego_to_stop, ego_to_conflict + 5.0),
        ego_cert_zone=(ego_to_stop, ego_to_conflict + 5.0), north_point=north_to_conflict,
        north_zone=(north_to_conflict - 5.0, north_to_conflict + 5.0),
        north_cert_zone=(north_to_conflict - 5.0, north_to_conflict + 5.0),
        approach_distance=30.0,
    )  # fmt: skip
    zero = np.zeros(1)
    view = north_view(geometry, zero, np.array([ego_speed]), zero, zero, zero,
                      np.array([north_speed]), np.array([north_speed]), np.array([at]))  # fmt: skip
    assert view.ego_to_stop[0] == ego_to_stop and view.both_at_intersection[0] == at
    return view


def decide(state):
    logic = PaperSwitching(CFG, DECEL)
    decision = logic.decide(state, np.zeros((1, 2)), np.zeros((1, 2)))
    return bool(decision.use_safety[0]), logic.reasons[int(decision.reason[0])]


def test_paper_logic_switches_exactly_at_the_braking_point():
    v = 7.0
    boundary = v**2 / (2 * DECEL) + v * CFG.latency_s + CFG.stop_margin_m
    assert decide(make_state(boundary + 1e-6, v, gap=-0.1)) == (False, "learned")
    assert decide(make_state(boundary - 1e-6, v, gap=-0.1)) == (True, "no_gap_at_braking_point")


def test_paper_logic_switches_exactly_at_the_time_gap_threshold():
    assert decide(make_state(1.0, gap=+1e-6))[0] is False  # there is time to cut in front
    assert decide(make_state(1.0, gap=-1e-6))[0] is True


def test_paper_logic_is_silent_unless_both_cars_are_at_the_intersection():
    assert decide(make_state(0.5, gap=-1.0, at=False))[0] is False
    assert decide(make_state(0.5, gap=-1.0, at=True))[0] is True


def test_supervisor_never_executes_nan_and_clips_out_of_range():
    logic = NeverSwitch()
    learned = np.array([[np.nan, 0.0], [np.inf, 0.0], [1.7, -0.3], [0.4, 0.0]])
    safe = np.array([[0.0, 0.8]] * 4)
    sup = supervise(logic, None, learned, safe, 0.0, 1.0)
    names = reason_names(logic)
    assert sup.safety_active.tolist() == [True, True, False, False]
    assert [names[r] for r in sup.reason] == [INVALID_LEARNED_ACTION] * 2 + ["learned"] * 2
    np.testing.assert_array_equal(sup.executed, [[0, 0.8], [0, 0.8], [1.0, 0.0], [0.4, 0.0]])
    assert np.isnan(sup.learned[0, 0])  # the record keeps what was proposed


@pytest.mark.parametrize("switching", logic_names())
@pytest.mark.parametrize("scope", ["window", "episode"])
def test_the_task_switches_exactly_as_supervise_with_the_registered_logic(switching, scope):
    """Every registered logic that serves the left turn: the task's tick must decide exactly
    what the framework's supervision step decides with the logic object, from the task's own
    view of the state — the learned throttle while in charge, PID_th's otherwise and in place
    of a NaN/inf learned action, PID_b's brake as the safety action."""
    from safeswitch.core.arrays import columns
    from safeswitch.core.pid import pid_step
    from safeswitch.core.registry import LogicContextError
    from safeswitch.leftturn.config import resolve_config
    from safeswitch.leftturn.task import LeftTurnTask

    config = resolve_config({"episode": {"learned_scope": scope}}, switching=switching)
    try:
        task = LeftTurnTask(config)  # the logic is built once the scene is
    except LogicContextError:
        pytest.skip(f"{switching} is a logic for another plant")
    ctrl, dt = task.config.controllers, task.config.episode.dt
    n = 256
    state = task.initial(task.draw_scenarios(3, np.arange(n), np.zeros(n, dtype=np.int64)))
    rng = np.random.default_rng(5)
    interventions = invalid = 0
    for _ in range(400):
        action = rng.uniform(-1.3, 1.3, n)
        action[rng.random(n) < 0.03] = np.nan
        action[rng.random(n) < 0.01] = np.inf
        conflict = task.view(state)
        rule, _ = pid_step(
            ctrl.throttle_pid, state.pid_throttle, ctrl.speed_limit - conflict.ego_speed, dt
        )
        in_charge = conflict.both_at_intersection if scope == "window" else np.ones(n, dtype=bool)
        new_state, record = task.step(state, action)
        proposed = np.where(in_charge, 0.5 * (action + 1.0), rule)
        zeros = np.zeros(n)
        sup = supervise(
            task.switching,
            conflict,
            columns(proposed, zeros),
            columns(zeros, record.safety_brake),
            0.0,
            1.0,
            fallback=columns(state.world.vehicles.throttle[:, 0], state.world.vehicles.brake[:, 0]),
        )
        np.testing.assert_array_equal(record.both_at_intersection, conflict.both_at_intersection)
        np.testing.assert_array_equal(record.throttle, sup.executed[:, 0])
        np.testing.assert_array_equal(record.brake, sup.executed[:, 1])
        np.testing.assert_array_equal(record.safety_active, sup.safety_active)
        rule_ran = ~in_charge & ~sup.use_safety
        np.testing.assert_array_equal(
            record.reason, np.where(rule_ran, task.reasons.index("rule_in_charge"), sup.reason)
        )
        interventions += int((sup.use_safety & np.isfinite(proposed)).sum())
        invalid += int((~sup.valid).sum())
        state = new_state
    assert invalid > 0
    if switching != "none":
        assert interventions > 0  # the comparison covered the logic's own decisions


OVERRULES = tuple(
    f"guard:{r}:overrules_primary"
    for r in (
        "backup_stop",
        "backup_clear",
        "no_certified_backup_brake",
        "no_certified_backup_clear",
    )
)


def test_a_reason_in_end_on_reasons_ends_the_episode_on_its_first_tick():
    """``episode.end_on_reasons``: the first tick on which one of those reasons' safety action
    runs ends the episode (terminated, as a collision would, not truncated); every episode
    without one plays exactly as without the setting."""
    import dataclasses

    from safeswitch.core.config import from_dict
    from safeswitch.evaluation.rollout import rollout
    from safeswitch.leftturn.config import LeftTurnConfig
    from safeswitch.leftturn.make import build_task

    plain_config = from_dict(
        LeftTurnConfig, {"switching": "guarded", "episode": {"learned_scope": "episode"}}
    )
    ending_config = dataclasses.replace(
        plain_config, episode=dataclasses.replace(plain_config.episode, end_on_reasons=OVERRULES)
    )

    def cruise(obs, state, tick):
        return np.full(state.batch_size, 0.6)

    def play(config):
        task = build_task(None, config)
        scenarios = task.draw_scenarios(3, np.arange(400), np.zeros(400, dtype=np.int64))
        codes = [task.reasons.index(r) for r in OVERRULES]
        first_overrule = np.full(400, -1)
        ended = np.full(400, -1)
        live = np.ones(400, dtype=bool)

        def record(state, rec, tick):
            hit = live & rec.safety_active & np.isin(rec.reason, codes) & (first_overrule < 0)
            first_overrule[hit] = tick
            stop = live & (rec.terminated | rec.truncated)
            ended[stop & rec.terminated] = tick
            live[stop] = False

        return rollout(task, scenarios, cruise, record), first_overrule, ended

    plain, overruled, _ = play(plain_config)
    ending, overruled_too, ended = play(ending_config)
    hit = overruled >= 0
    assert 50 < hit.sum() < 400  # some episodes have an overrule, some do not
    assert np.array_equal(overruled_too, overruled)  # the same up to the first one
    assert np.array_equal(ended[hit], overruled[hit])  # which ends the episode
    assert np.all(ended[~hit] == -1) and not ending.collision.any()
    assert np.array_equal(ending.episode_return[~hit], plain.episode_return[~hit])
    assert np.all(ending.ticks[hit] < plain.ticks[hit])


def test_an_unknown_reason_to_end_on_is_named():
    from safeswitch.core.config import from_dict
    from safeswitch.leftturn.config import LeftTurnConfig
    from safeswitch.leftturn.make import build_task

    config = from_dict(LeftTurnConfig, {"episode": {"end_on_reasons": [OVERRULES[0]]}})
    with pytest.raises(ValueError, match=r"end_on_reasons.*overrules_primary.*'paper'"):
        build_task(None, config)  # the paper logic alone never overrules itself
