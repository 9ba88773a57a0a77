"""The Table I controllers on the plant (SPEC §2)."""

from dataclasses import replace

import numpy as np
import pytest

from safeswitch.core.config import ConfigError
from safeswitch.core.pid import PIDState, pid_step
from safeswitch.evaluation.planner import Planner
from safeswitch.evaluation.rollout import rollout
from safeswitch.evaluation.traffic_planner import GapPlanner
from safeswitch.leftturn.config import ControllerConfig, LeftTurnConfig
from safeswitch.leftturn.info import step_info
from safeswitch.leftturn.make import build_task
from safeswitch.leftturn.statistics import SPEEDING_MARGIN
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.sim.vehicle import VehicleState, vehicle_step


@pytest.mark.parametrize("v0", [6.94, 10.0])
def test_pid_b_holds_the_emergency_deceleration(task, v0):
    c = task.config
    gains, target = c.controllers.brake_pid, c.controllers.emergency_decel
    state = VehicleState.at(np.zeros(1), 0.0, 0.0, v0, throttle=1.0)  # throttle still open
    pid = PIDState.zeros((1,), task.brake_feedforward())
    accel, decels = 0.0, []
    while state.speed[0] > 0:
        brake, pid = pid_step(gains, pid, np.array([target + accel]), c.episode.dt)
        state, out = vehicle_step(c.vehicle, state, 0.0, brake, 0.0, c.episode.dt)
        accel = out.accel_lon[0]
        decels.append(-accel)
    decels = np.array(decels)
    assert np.mean(decels[5:-5]) == pytest.approx(target, rel=0.1)
    # The stop fits in what the paper switching logic reserves for it.
    p = c.paper
    reserved = v0**2 / (2 * target) + v0 * p.latency_s + p.stop_margin_m
    assert state.x[0] <= reserved


def _task_with(switching="none", **controllers):
    """The left turn with the learned controller in charge all episode and ``controllers``."""
    c = LeftTurnConfig()
    return LeftTurnTask(
        replace(
            c,
            switching=switching,
            episode=replace(c.episode, learned_scope="episode"),
            controllers=replace(c.controllers, **controllers),
        )
    )


def _limited_task(limit_kmh, switching="none"):
    return _task_with(switching, learned_speed_limiter_kmh=limit_kmh)


def _drive(task, action, ticks):
    state = task.initial(task.draw_scenarios(0, np.arange(4), np.zeros(4, dtype=np.int64)))
    records = []
    for _ in range(ticks):
        state, record = task.step(state, np.full(4, action))
        records.append(record)
    return records


def test_the_learned_speed_limiter_holds_full_throttle_at_the_tolerated_speed():
    ticks = 600  # 12 s: the turn, and the straight after it
    free = _drive(_limited_task(None), 1.0, ticks)
    limited = _drive(_limited_task(29.9), 1.0, ticks)
    tolerated = LeftTurnConfig().rewards.tolerated_speed
    free_top = max(r.ego_speed.max() for r in free)
    top = max(r.ego_speed.max() for r in limited)
    assert free_top > tolerated + 10 / 3.6  # without it, full throttle is far over 30 km/h
    # Never counted as speeding (the lag's overshoot stays inside the 0.1 km/h margin) ...
    assert top <= tolerated + SPEEDING_MARGIN
    # ... and it does not make the car crawl: within 1.5 s of the start it is at 29.5 km/h.
    assert min(r.ego_speed.min() for r in limited[75:]) >= 29.5 / 3.6
    # The learned throttle asked for is recorded as asked; what ran was cut.
    assert all(np.all(r.learned_throttle == 1.0) for r in limited)
    assert min(r.throttle.min() for r in limited) < 0.5


def test_the_learned_speed_limiter_leaves_a_slower_controller_alone(task):
    limited = _limited_task(29.9, switching=task.config.switching)
    free = LeftTurnTask(replace(task.config, episode=limited.config.episode))
    action = 0.4 * 2 - 1  # a throttle of 0.4 settles well below 29.9 km/h
    for a, b in zip(_drive(free, action, 400), _drive(limited, action, 400), strict=True):
        assert b.ego_speed.max() < 29 / 3.6
        np.testing.assert_array_equal(a.throttle, b.throttle)
        np.testing.assert_array_equal(a.ego_speed, b.ego_speed)


def test_the_learned_speed_limiter_keeps_the_action_checks():
    task = _limited_task(29.9, switching="paper")
    state = task.initial(task.draw_scenarios(0, np.arange(3), np.zeros(3, dtype=np.int64)))
    for _ in range(100):  # full throttle up to the limiter's speed
        state, record = task.step(state, np.ones(3))
    assert record.ego_speed.min() > 29.5 / 3.6
    cap = task.limit_speed(np.ones(3), record.ego_speed)
    assert np.all(cap < 0.5)
    state, record = task.step(state, np.array([5.0, np.nan, 1.0]))
    # Out of range: still reported as clipped, and cut to the limiter's cap, not to 1.
    assert record.action_clipped[0] and not record.action_clipped[2]
    np.testing.assert_array_equal(record.throttle[[0, 2]], cap[[0, 2]])
    # NaN is still refused by the logic, not turned into a throttle by the limiter.
    assert task.reasons[record.reason[1]] == "invalid_learned_action"


def test_the_curve_limiter_lets_full_throttle_corner_within_the_comfort_limit():
    """``controllers.learned_curve_accel``: the speed limiter's cap falls ahead of the turn to
    the speed that corners at that acceleration, reached by closing the throttle; full throttle
    then takes the 11.75 m turn within the 3 m/s² comfort limit (without it, at 6 m/s²), and
    the straights at the limiter's speed."""
    lateral = LeftTurnConfig().rewards.comfort_accel_lat
    free = _drive(_limited_task(29.9), 1.0, 600)
    curved = _drive(_task_with(learned_speed_limiter_kmh=29.9, learned_curve_accel=2.8), 1.0, 600)
    assert max(np.abs(r.accel_lat).max() for r in free) > 2 * lateral
    assert max(np.abs(r.accel_lat).max() for r in curved) <= lateral
    # on the straight before the turn it still reaches the limiter's speed
    assert max(r.ego_speed.max() for r in curved[:250]) >= 29.5 / 3.6
    # the cap: the limiter's speed far from the turn, √(a/|κ|) in it, and a coast between
    task = _task_with(learned_speed_limiter_kmh=29.9, learned_curve_accel=2.8)
    spacing, kappa = task.ego_curvature()
    _, caps = task.curve_speed_caps(2.8, 1.0, 29.9 / 3.6)
    assert caps[0] == pytest.approx(29.9 / 3.6)
    assert np.all(caps**2 * kappa <= 2.8 + 1e-9)
    assert np.all(np.diff(caps**2) >= -2.0 * 1.0 * spacing - 1e-9)  # never more than a coast
    # the learned action may still ask for less: a slower driver is left alone
    slow = 0.3 * 2 - 1
    for a, b in zip(_drive(_limited_task(29.9), slow, 600),
                    _drive(task, slow, 600), strict=True):  # fmt: skip
        np.testing.assert_array_equal(a.throttle, b.throttle)


def test_the_curve_limiter_needs_the_speed_limiter():
    needs = r"controllers\.learned_curve_accel.*limiter_kmh, got 2\.8"
    with pytest.raises(ConfigError, match=needs):
        ControllerConfig(learned_curve_accel=2.8)
    with pytest.raises(ConfigError, match=r"controllers\.learned_curve_decel"):
        ControllerConfig(learned_speed_limiter_kmh=29.9, learned_curve_decel=0.0)


@pytest.mark.parametrize("kind", ["limiter", "command"])
@pytest.mark.parametrize("bad", [float("nan"), 2.0, 500.0])
def test_a_bad_speed_limiter_or_command_is_named(kind, bad):
    speed, gain = f"learned_speed_{kind}_kmh", f"learned_speed_{kind}_gain"
    with pytest.raises(ConfigError, match=rf"controllers\.{speed}.*" + str(bad)[:3]):
        ControllerConfig(**{speed: bad})
    with pytest.raises(ConfigError, match=gain):
        ControllerConfig(**{gain: 0.0})


def _commanded_task(command_kmh, switching="none"):
    return _task_with(switching, learned_speed_command_kmh=command_kmh)


@pytest.mark.parametrize("kmh", [12.0, 20.0, 29.9])
def test_a_commanded_speed_is_held_by_one_constant_action(kmh):
    task = _commanded_task(29.9)
    action = 2.0 * kmh / 29.9 - 1.0
    records = _drive(task, action, 400)
    late = np.concatenate([r.ego_speed for r in records[250:]])
    # The cruise control settles on the commanded speed (within 0.1 km/h) and holds it ...
    assert np.abs(late * 3.6 - kmh).max() < 0.1
    # ... approached from the starting speed without overshooting it (the paper's throttle
    # action has no set point: the same constant action as a throttle settles far from it).
    start = records[0].ego_speed
    speeds = np.stack([r.ego_speed for r in records])
    target = kmh / 3.6
    assert np.all(speeds <= np.maximum(start, target) + SPEEDING_MARGIN)
    assert np.all(speeds >= np.minimum(start, target) - SPEEDING_MARGIN)
    as_throttle = _drive(_commanded_task(None), action, 400)
    assert abs(as_throttle[-1].ego_speed[0] * 3.6 - kmh) > 1.0


def test_a_zero_speed_command_coasts_and_the_full_command_tops_at_its_speed():
    task = _commanded_task(29.9)
    stopped = _drive(task, -1.0, 400)
    assert all(np.all(r.throttle <= 0.05) for r in stopped)  # never more than rolling holds
    assert stopped[-1].ego_speed.max() < 0.1
    full = _drive(task, 1.0, 600)
    assert max(r.ego_speed.max() for r in full) <= 29.9 / 3.6 + SPEEDING_MARGIN
    assert min(r.ego_speed.min() for r in full[150:]) * 3.6 >= 29.5


def test_a_speed_command_keeps_the_action_checks():
    task = _commanded_task(29.9, switching="paper")
    state = task.initial(task.draw_scenarios(0, np.arange(4), np.zeros(4, dtype=np.int64)))
    for _ in range(20):
        state, record = task.step(state, np.zeros(4))
    state, record = task.step(state, np.array([5.0, np.nan, 1.0, np.inf]))
    # Out of range: clipped to the top speed's command and counted as clipped.
    assert record.action_clipped[0] and not record.action_clipped[2]
    assert record.throttle[0] == record.throttle[2]
    # NaN and inf are refused by the logic, not turned into a set point.
    for i in (1, 3):
        assert task.reasons[record.reason[i]] == "invalid_learned_action"


def _braking_task(switching="none"):
    return _task_with(switching, learned_brake=True)


def test_the_learned_brake_works_both_pedals_from_one_action():
    task = _braking_task()
    state = task.initial(task.draw_scenarios(0, np.arange(5), np.zeros(5, dtype=np.int64)))
    actions = np.array([0.4, 0.0, -0.5, -3.0, np.nan])
    state, record = task.step(state, actions)
    np.testing.assert_allclose(record.throttle[:4], [0.4, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(record.brake[:4], [0.0, 0.0, 0.5, 1.0])
    # The record says what the learned controller asked for: the brake included.
    np.testing.assert_allclose(record.learned_throttle[:4], [0.4, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(record.learned_brake[:4], [0.0, 0.0, 0.5, 1.0])
    assert step_info(record, 2, task.reasons)["learned_brake"] == 0.5
    # Out of range: clipped to full brake and counted; NaN refused as ever.
    assert record.action_clipped.tolist()[:4] == [False, False, False, True]
    assert task.reasons[record.reason[4]] == "invalid_learned_action"
    # The brake slows the car far harder than the closed throttle the paper's action has.
    for _ in range(50):
        state, record = task.step(state, actions)
    assert record.ego_speed[2] < record.ego_speed[1] - 3.0


def test_a_learned_brake_with_a_speed_set_point_is_refused():
    with pytest.raises(ConfigError, match=r"controllers\.learned_brake.*must be false"):
        ControllerConfig(learned_brake=True, learned_speed_command_kmh=29.9)


def test_scripted_throttle_drivers_refuse_a_speed_set_point():
    c = LeftTurnConfig()
    scene = replace(c, controllers=replace(c.controllers, learned_speed_command_kmh=25.0))
    with pytest.raises(ValueError, match="learned_speed_command_kmh=25"):
        Planner(LeftTurnTask(scene))


def _pedals_driven(task, driver, scenes):
    """The executed throttle and brake and the learned brake of every tick of ``driver`` on
    ``scenes`` [ticks, 3, B]."""
    pedals = []

    def on_tick(state, record, tick):
        pedals.append((record.throttle.copy(), record.brake.copy(), record.learned_brake.copy()))

    result = rollout(task, scenes, driver, on_tick)
    return np.array(pedals), result


@pytest.mark.slow
@pytest.mark.parametrize("traffic", [None, {"preset": "train", "horizon_s": 8.0}])
def test_the_planners_drive_a_two_pedal_scene_as_the_papers(traffic):
    """A planner's throttles map to the two-pedal action ((a + 1) / 2, the brake never used)
    and its foresight checks its own throttle drives: on a scene with controllers.learned_brake
    it works the pedals tick for tick as on the paper's scene, the filter's braking included."""
    runs = []
    for brake in (False, True):
        env = {"switching": "certified", "controllers": {"learned_brake": brake}}
        task = build_task(None, env, traffic=traffic)
        planner = Planner(task) if traffic is None else GapPlanner(task)
        scenes = task.draw_scenarios(3, np.arange(12), np.zeros(12, dtype=np.int64))
        runs.append(_pedals_driven(task, planner, scenes))
    (paper, paper_run), (pedals, pedal_run) = runs
    np.testing.assert_allclose(pedals, paper, atol=1e-12)
    assert not pedals[:, 2].any()  # the planners never ask for the learned brake
    np.testing.assert_array_equal(pedal_run.time_to_clear, paper_run.time_to_clear)
    assert np.isfinite(paper_run.time_to_clear).any()  # they drove, and cleared
    # Full and closed throttles both driven: the closed one (-1) is a coast on both scenes,
    # where the action unmapped would be the full brake.
    assert paper[:, 0].max() > 0.9 and (paper[:, 0] == 0.0).any()


def _same(a, b):
    """Equal trees of (named) tuples, arrays and numbers, field by field."""
    if isinstance(a, tuple):
        assert type(a) is type(b) and len(a) == len(b)
        return all(_same(x, y) for x, y in zip(a, b, strict=True))
    return np.array_equal(a, b)


def test_the_kernels_plain_constants_are_named_again_field_for_field(task):
    # The tick hands its compiled kernels plain tuples (numba types a NamedTuple by spelling
    # every field's name on each call); the entry names them again. A field added or moved
    # in one place and not the other would swap two constants silently.
    from safeswitch.core.arrays import plain
    from safeswitch.leftturn import task as module

    controllers = task._controller_constants
    original = module.ControllerConstants(*controllers)  # the outer names; the nested below
    named = module.named_controller_constants(controllers)
    assert _same(plain(named), controllers)
    assert type(named) is type(original)
    assert type(named.gains.lane) is module.PIDKernel
    assert named.gains.lane == task._gains.lane and named.plant == task._plant
    assert named.north == task.north_conflict
    book = module.named_bookkeeping_constants(task._bookkeeping_constants)
    assert _same(plain(book), task._bookkeeping_constants)
    assert book.limits == task._limits
