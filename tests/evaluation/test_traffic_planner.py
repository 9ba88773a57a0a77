"""The gap planner: in traffic, a throttle-only controller that waits for a gap the certified
filter accepts, so that the filter never has to act."""

import numpy as np
import pytest

from safeswitch.core.config import ConfigError, from_dict
from safeswitch.evaluation.rollout import rollout
from safeswitch.evaluation.traffic_planner import GapPlanner, GapPlannerConfig
from safeswitch.leftturn.make import build_task
from safeswitch.training.config import TrainConfig

SCENES = 24
CERTIFIED = {"switching": "certified", "episode": {"learned_scope": "episode"}}


def drive_scenes(config=None, env=CERTIFIED, speeds=None):
    """24 `train` scenes (20 s) under `certified` (``env``) driven by the gap planner, with
    each tick's ego progress, whether the planner had decided to go, and its action (and, into
    a list ``speeds``, the ego's speed)."""
    task = build_task(None, env, traffic={"preset": "train", "horizon_s": 20.0})
    planner = GapPlanner(task, config)
    scenes = task.draw_scenarios(7, np.arange(SCENES), np.zeros(SCENES, dtype=np.int64))
    progress, going, actions = [], [], []

    def drive_and_record(obs, state, tick):
        action = planner(obs, state, tick)
        progress.append(state.world.progress[:, 0].copy())
        going.append(planner._decision.copy())
        actions.append(action)
        if speeds is not None:
            speeds.append(state.world.vehicles.speed[:, 0].copy())
        return action

    result = rollout(task, scenes, drive_and_record)
    return planner, result, np.array(progress), np.array(going), np.array(actions)


@pytest.fixture(scope="module")
def drive():
    return drive_scenes()


@pytest.mark.slow
def test_the_certified_filter_never_acts_on_it(drive):
    _, result, _, _, _ = drive
    assert result.collision.sum() == 0
    assert np.all(result.safety_steps == 0)


@pytest.mark.slow
def test_it_clears_where_a_gap_comes_and_waits_before_every_crossing_zone_otherwise(drive):
    planner, result, progress, going, _ = drive
    cleared = np.isfinite(result.time_to_clear)
    assert 0 < cleared.sum() < SCENES  # some scenes give a gap within 20 s, some do not
    # A scene enters the first crossing zone only after the planner decided to go.
    for b in range(SCENES):
        inside = np.flatnonzero(progress[:, b] > planner.first_entry)
        if inside.size:
            assert going[: inside[0], b].any()
        else:
            assert progress[:, b].max() <= planner.first_entry - 0.5  # stopped short of it


@pytest.mark.slow
def test_a_wait_closes_the_throttle_near_its_stop(drive):
    """Within ``coast_band_m`` of where a wait stops the throttle is closed (-1), not the
    throttle of a walking pace that would creep on into the filter's stop."""
    planner, _, progress, going, actions = drive
    c = planner.config
    stop = planner.first_entry - c.stop_extra_m
    near = ~going & (progress > stop - c.coast_band_m) & (progress <= planner.first_entry)
    assert near.sum() > 100
    assert np.all(actions[near] == -1.0)
    far = ~going & (progress < stop - c.coast_band_m - 5.0)
    assert np.any(actions[far] > -1.0)  # further back it tracks its approach speed


@pytest.mark.slow
def test_a_go_margin_starts_no_sooner_and_the_filter_still_never_acts(drive):
    """``go_margin_s``: a drive starts only if it would also pass begun later; until the
    planner without the margin first goes both drive alike, so the margin never goes sooner."""
    _, _, _, going, _ = drive
    _, result, _, margin_going, _ = drive_scenes(GapPlannerConfig(go_margin_s=0.6))
    assert np.all(result.safety_steps == 0)
    first = np.where(going.any(axis=0), going.argmax(axis=0), len(going))
    later = np.where(margin_going.any(axis=0), margin_going.argmax(axis=0), len(going))
    assert np.all(later >= first) and np.any(later > first)


@pytest.mark.slow
def test_an_observed_foresight_ignores_what_no_car_could_see():
    """``foresight: observed``: the go check runs on a copy with no vehicle still to come and
    every driver rude, so changing the drivers' yielding or the vehicles still to come changes
    none of its decisions, and the state it is given is left as it was."""
    task = build_task(None, CERTIFIED, traffic={"preset": "test", "horizon_s": 20.0})
    scenes = task.draw_scenarios(3, np.arange(64), np.zeros(64, dtype=np.int64))
    state = task.initial(scenes)
    for _ in range(60):  # up to the junction, where the decisions are taken
        state, _ = task.step(state, np.full(64, 0.4))
    every = np.arange(64)
    hidden = state.take(every)  # the same scenes with another hidden future
    hidden.traffic.yields[:] = ~hidden.traffic.yields
    hidden.traffic.schedule.time[:] = np.minimum(hidden.traffic.schedule.time, 1.0)
    hidden.traffic.next_arrival[:] = hidden.traffic.schedule.time[:, :, 0].min(axis=1)
    blind = state.take(every)  # what a car knows, by hand
    blind.traffic.yields[:] = False
    blind.traffic.schedule.time[:] = np.inf
    blind.traffic.next_arrival[:] = np.inf
    before = (state.traffic.yields.copy(), state.traffic.schedule.time.copy())
    observed = GapPlanner(task, GapPlannerConfig(foresight="observed"))
    full = GapPlanner(task, GapPlannerConfig(foresight="full"))
    goes = observed.goes(state)
    assert 0 < goes.sum() < 64
    np.testing.assert_array_equal(goes, observed.goes(hidden))
    np.testing.assert_array_equal(goes, full.goes(blind))
    np.testing.assert_array_equal(state.traffic.yields, before[0])
    np.testing.assert_array_equal(state.traffic.schedule.time, before[1])


#: The ``traffic-certified`` recipe's pedals: one action for both, each held 0.3 s.
BRAKE_SCENE = {**CERTIFIED, "controllers": {"learned_brake": True},
               "episode": {"learned_scope": "episode", "decision_interval": 15}}  # fmt: skip


@pytest.mark.slow
def test_a_braked_approach_stops_nearer_its_stop_and_the_filter_never_acts():
    """``approach: brake``: the wait brakes (a negative action) only while waiting, holds the
    car at its stop, and stops it nearer ``stop_extra_m`` before the zone than the closed
    throttle's coast, which stops short of it; the filter never acts on either."""

    def stops(config):
        speeds: list = []
        planner, result, progress, going, actions = drive_scenes(config, BRAKE_SCENE, speeds)
        assert result.collision.sum() == 0 and np.all(result.safety_steps == 0)
        waiting = ~going & (progress <= planner.first_entry)
        stopped = waiting & (np.array(speeds) < 0.1)
        where = np.array([progress[stopped[:, b], b].max() for b in range(SCENES)
                          if stopped[:, b].any()])  # fmt: skip
        return planner, where, actions, waiting

    planner, coasted, coast_actions, _ = stops(None)
    assert np.all(coast_actions >= 0.0)  # the coast never brakes
    _, braked, actions, waiting = stops(GapPlannerConfig(approach="brake", coast_decel=2.0))
    assert np.any(actions < 0.0) and np.all(actions[~waiting] >= 0.0)
    stop = planner.first_entry - planner.config.stop_extra_m
    assert len(coasted) >= 5 and len(braked) >= 5
    assert np.median(braked) > np.median(coasted) + 1.0
    assert np.all(braked <= stop + 0.5) and np.median(braked) > stop - 1.0


def test_a_braked_approach_needs_a_learned_brake():
    task = build_task(None, CERTIFIED, traffic={"preset": "train", "horizon_s": 20.0})
    with pytest.raises(ConfigError, match=r"gap_planner\.approach .*learned_brake=true"):
        GapPlanner(task, GapPlannerConfig(approach="brake"))


def test_it_needs_a_task_in_traffic():
    with pytest.raises(ValueError, match="needs a task in traffic"):
        GapPlanner(build_task(None, None))


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("coast_decel", 0.0),
        ("stop_extra_m", -1.0),
        ("go_margin_s", -0.1),
        ("recheck_ticks", 0),
        ("foresight", "perfect"),
        ("approach", "slide"),
    ],
)
def test_bad_tuning_is_refused_by_name(field, value):
    with pytest.raises(ConfigError, match=field):
        GapPlannerConfig(**{field: value})


def test_the_gap_planner_teaches_only_in_traffic_and_unknown_teachers_are_refused():
    ws = {"episodes": 8, "teacher": "gap_planner"}
    with pytest.raises(ConfigError, match="needs traffic"):
        from_dict(TrainConfig, {"warm_start": ws})
    with pytest.raises(ConfigError, match="'oracle'"):
        from_dict(TrainConfig, {"warm_start": {**ws, "teacher": "oracle"}, "traffic": "light"})
    config = from_dict(TrainConfig, {"warm_start": ws, "traffic": "light"})
    assert config.warm_start.teacher == "gap_planner"
    # a teacher whose wait brakes needs a scene with the learned brake, refused when read
    braking = {**ws, "gap_planner": {"approach": "brake"}}
    with pytest.raises(ConfigError, match=r"warm_start\.gap_planner\.approach .*learned_brake"):
        from_dict(TrainConfig, {"warm_start": braking, "traffic": "light"})
    scene = {"controllers": {"learned_brake": True}}
    config = from_dict(TrainConfig, {"warm_start": braking, "traffic": "light", "env": scene})
    assert config.warm_start.gap_planner.approach == "brake"
