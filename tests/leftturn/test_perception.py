"""Perception (the paper's Remark 2): what the ego sees of the north car, and the certified
logic's guarantee for any errors within the declared bounds."""

from types import SimpleNamespace

import numpy as np
import pytest

from safeswitch.core.config import ConfigError
from safeswitch.evaluation.adversaries import catalogue
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.config import resolve_config
from safeswitch.leftturn.make import build_task
from safeswitch.training.policies import load_policy

DT = 0.02


def task_with(perception, switching="certified", assume="declared", scope="episode"):
    config = resolve_config(
        {"episode": {"learned_scope": scope}, "certified": {"perception": assume}},
        switching=switching, perception=perception,
    )  # fmt: skip
    return build_task(None, config)


def north(perception):
    """The north car's column of a perception state."""
    return SimpleNamespace(**{
        name: getattr(perception, name)[:, 0]
        for name in ("progress", "speed", "seen", "ever", "low", "high", "speed_high")
    })  # fmt: skip


def trace(task, count=200, seed=3, action=0.2):
    """Every tick of ``count`` episodes under a constant action: the truth (north progress and
    speed), the perception state, and the scenario set."""
    scenarios = task.scenario_set(seed, count)
    state = task.initial(scenarios)
    truth, seen = [], []
    for _ in range(task.config.episode.horizon_ticks):
        truth.append((state.world.progress[:, 1].copy(), state.world.vehicles.speed[:, 1].copy()))
        seen.append(north(state.perception))
        state, _ = task.step(state, np.full(count, action))
    return truth, seen


@pytest.mark.parametrize(
    "perception",
    [
        {"position_error_m": 1.5},
        {"speed_error_mps": 2.0},
        {"position_error_m": 1.0, "speed_error_mps": 1.0, "latency_s": 0.2},
        {"position_error_m": 1.0, "errors": "adversarial", "latency_s": 0.1},
    ],
)
def test_what_is_seen_differs_from_the_truth_by_at_most_the_bound(perception):
    task = task_with(perception)
    truth, seen = trace(task)
    lag = round(perception.get("latency_s", 0.0) / DT)
    e_p, e_v = perception.get("position_error_m", 0.0), perception.get("speed_error_mps", 0.0)
    worst_p = worst_v = 0.0
    for t in range(lag, len(truth)):
        then_p, then_v = truth[t - lag]
        worst_p = max(worst_p, np.max(np.abs(seen[t].progress - then_p)))
        worst_v = max(worst_v, np.max(np.abs(seen[t].speed - np.maximum(then_v, 0))))
    assert worst_p <= e_p + 1e-9 and worst_v <= e_v + 1e-9
    # the errors are real: they reach most of their bound somewhere
    assert worst_p >= 0.9 * e_p and worst_v >= 0.9 * e_v


def test_latency_is_exact():
    task = task_with({"latency_s": 0.3})
    truth, seen = trace(task)
    lag = 15
    for t in range(len(truth)):
        if t >= lag:
            np.testing.assert_array_equal(seen[t].progress, truth[t - lag][0])
            np.testing.assert_array_equal(seen[t].speed, truth[t - lag][1])
        else:  # before the episode the north car cruised at its speed: extrapolated back
            p0, v0 = truth[0]
            np.testing.assert_allclose(seen[t].progress, p0 - v0 * (lag - t) * DT, atol=1e-9)


def test_a_dropped_vehicle_is_missed_at_most_dropout_max_then_reappears():
    task = task_with({"dropout_prob": 0.2, "dropout_max_s": 0.1})
    _, seen = trace(task, count=300)
    visible = np.stack([s.seen for s in seen], axis=1)  # [B, T]
    assert visible[:, 0].all()  # the first sighting is never missed
    assert 0.05 < 1 - visible.mean() < 0.5
    longest = 0
    for row in visible:
        run = 0
        for v in row:
            run = 0 if v else run + 1
            longest = max(longest, run)
    assert longest == 5  # 0.1 s: five ticks at most, and some miss is that long
    # held while missed: the point estimate is the last sighting
    for t in range(1, len(seen)):
        missed = ~seen[t].seen
        np.testing.assert_array_equal(seen[t].progress[missed], seen[t - 1].progress[missed])


def test_vehicles_beyond_the_sight_distance_are_not_seen():
    task = task_with({"sight_distance_m": 25.0})
    truth, seen = trace(task)
    point = task.conflict.s_point_b
    for (p, _), s in zip(truth, seen, strict=True):
        np.testing.assert_array_equal(s.seen, point - p <= 25.0)
        far = ~s.ever
        np.testing.assert_allclose(s.progress[far], point - 25.0)


@pytest.mark.parametrize(
    "perception",
    [
        {"position_error_m": 1.0, "speed_error_mps": 1.0, "latency_s": 0.2},
        {"position_error_m": 2.0, "speed_error_mps": 2.0, "latency_s": 0.4,
         "errors": "adversarial"},
        {"position_error_m": 0.5, "dropout_prob": 0.1, "dropout_max_s": 1.0,
         "sight_distance_m": 30.0, "errors": "adversarial"},
    ],
)  # fmt: skip
def test_the_tracker_always_contains_the_truth(perception):
    task = task_with(perception)
    truth, seen = trace(task, count=300, action=0.6)
    for (p, v), s in zip(truth, seen, strict=True):
        assert np.all(s.low <= p + 1e-9) and np.all(p <= s.high + 1e-9)
        assert np.all(v <= s.speed_high + 1e-9)
    # and it is informative: once seen, the interval is a few metres wide, not unbounded
    width = seen[-1].high - seen[-1].low
    assert np.median(width) < 20.0


def test_adversarial_errors_make_the_north_car_look_as_late_as_the_bounds_allow():
    """On every tick before its zone, the adversarial sighting puts the north car's arrival
    (distance to its zone over speed) no sooner than a random sighting within the same bounds
    does, and both within the bounds of the truth."""
    bounds = {"position_error_m": 2.0, "speed_error_mps": 2.0, "latency_s": 0.1}
    runs = {}
    for errors in ("random", "adversarial"):
        truth, seen = trace(task_with({**bounds, "errors": errors}), count=100)
        runs[errors] = seen
    entry = task_with(bounds).conflict.zone_b[0]
    for t, (rand, adv) in enumerate(zip(runs["random"], runs["adversarial"], strict=True)):
        before = truth[max(t - 5, 0)][0] + 2.0 < entry
        arrival = {
            name: (entry - s.progress[before]) / np.maximum(s.speed[before], 1e-9)
            for name, s in (("random", rand), ("adversarial", adv))
        }
        assert np.all(arrival["adversarial"] >= arrival["random"] - 1e-9)


@pytest.mark.slow
def test_adversarial_errors_make_the_paper_logic_collide_more_than_random_ones():
    bounds = {"position_error_m": 3.0, "speed_error_mps": 3.0, "latency_s": 0.3}
    collisions = {}
    for errors in ("random", "adversarial"):
        task = task_with({**bounds, "errors": errors}, switching="paper")
        scenarios = task.scenario_set(11, 1000)
        adversaries = catalogue(task, 1000, seed=7)
        collisions[errors] = sum(
            int(rollout(task, scenarios, adversaries[name]()).collision.sum())
            for name in ("uniform", "noisy_cruise")
        )
    assert collisions["adversarial"] > 1.3 * collisions["random"] > 0, collisions


def test_a_scenario_replays_its_perception_exactly():
    perception = {"position_error_m": 1.0, "dropout_prob": 0.1, "dropout_max_s": 0.2}
    a, b = task_with(perception), task_with(perception)
    _, seen_a = trace(a, count=20)
    _, seen_b = trace(b, count=20)
    for x, y in zip(seen_a, seen_b, strict=True):
        np.testing.assert_array_equal(x.progress, y.progress)
        np.testing.assert_array_equal(x.seen, y.seen)


def test_the_observation_and_the_paper_logic_see_what_is_seen():
    task = task_with({"latency_s": 0.5, "position_error_m": 1.0}, switching="paper", scope="window")
    scenarios = task.scenario_set(2, 50)
    state = task.initial(scenarios)
    obs = task.observe(state)
    np.testing.assert_allclose(obs[:, 5], state.perception.speed[:, 0], rtol=1e-6)
    for _ in range(40):
        state, record = task.step(state, np.zeros(50))
    seen = north(state.perception)
    xy, _ = task.world.routes[1].pose_at(seen.progress)
    x, y = xy[:, 0], xy[:, 1]
    np.testing.assert_allclose(record.observation[:, 3], x, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(record.observation[:, 4], y, rtol=1e-6, atol=1e-4)
    # the north car drives along y: half a second late it is seen metres behind
    behind = np.abs(record.observation[:, 4] - state.world.vehicles.y[:, 1])
    assert np.all(behind > 1.0)
    view = task.view(state)
    np.testing.assert_array_equal(view.other_progress[:, 0], seen.progress)
    # measures keep the truth
    np.testing.assert_array_equal(task.conflicts(state).other_progress[:, 0],
                                  state.world.progress[:, 1])  # fmt: skip


def test_the_vec_env_resets_perception_with_its_episodes():
    from safeswitch.leftturn import make_vec_env

    perception = {"position_error_m": 1.0, "latency_s": 0.2, "sight_distance_m": 50.0,
                  "dropout_prob": 0.1, "dropout_max_s": 0.2}  # fmt: skip
    env = make_vec_env(6, switching="certified", seed=3, perception=perception)
    env.reset()
    low, high = env.observation_space.low, env.observation_space.high
    ended = np.zeros(6, dtype=bool)
    for _ in range(env.task.config.episode.horizon_ticks + 30):
        obs, _, done, _ = env.step(np.zeros((6, 1)))
        assert np.all((obs >= low) & (obs <= high))
        ended |= done
    assert ended.all()
    # every new episode's sensor history is its own: the north car's past, never the old
    # episode's (which ended far along its route)
    seen = env.state.perception
    assert np.all(seen.history[:, 0, :, 0] <= env.state.world.progress[:, 1:2] + 1e-9)
    assert np.all(seen.high[:, 0] >= env.state.world.progress[:, 1] - 1e-9)


def test_perfect_perception_keeps_no_perception_state():
    task = task_with({})
    assert task.perception is None
    assert task.initial(task.scenario_set(0, 3)).perception is None


@pytest.mark.parametrize(
    ("perception", "message"),
    [
        ({"latency_s": 0.03}, "perception.latency_s must be a whole number of ticks"),
        ({"dropout_prob": 0.1}, "perception.dropout_prob needs dropout_max_s > 0"),
        ({"position_error_m": -1.0}, "perception.position_error_m"),
        ({"errors": "worst"}, "errors"),
        ({"sight": 3.0}, "unknown configuration key perception.'sight'"),
    ],
)
def test_bad_perception_settings_are_refused_by_name(perception, message):
    with pytest.raises(ConfigError, match=message.replace(".", r"\.").replace("'", ".")):
        task_with(perception)


def traffic_task(perception, assume="declared", preset="medium", observe="nearest"):
    config = resolve_config(
        {"episode": {"learned_scope": "episode"}, "certified": {"perception": assume}},
        switching="certified", perception=perception,
    )  # fmt: skip
    return build_task(None, config, traffic={"preset": preset, "observe": observe})


def test_in_traffic_every_vehicle_is_tracked_and_its_track_contains_the_truth():
    task = traffic_task(EVERYTHING)
    scenarios = task.scenario_set(4, 64)
    state = task.initial(scenarios)
    checked = tracked = 0
    for _ in range(900):
        state, _ = task.step(state, np.zeros(64))
        seen, tr = state.perception, state.traffic
        known = tr.active & seen.ever[:, 1:]
        truth = tr.progress[known]
        assert np.all(seen.low[:, 1:][known] <= truth + 1e-9)
        assert np.all(truth <= seen.high[:, 1:][known] + 1e-9)
        assert np.all(tr.speed[known] <= seen.speed_high[:, 1:][known] + 1e-9)
        within = tr.active & (task._slot_point[tr.route] - tr.progress <= 40.0)
        checked += int(within.sum())
        tracked += int((known & within).sum())
    # nearly every vehicle within sight is tracked (the rest: just come within it, or missed)
    assert 0.9 * checked < tracked < checked
    # the logic sees them where the sensor put them, not where they are
    view, true_view = task.view(state), task.view(state, truth=True)
    both = view.present[:, 1:] & true_view.present[:, 1:]
    assert both.any() and not np.allclose(view.other_progress[:, 1:][both],
                                          true_view.other_progress[:, 1:][both])  # fmt: skip


def test_in_traffic_the_phantoms_come_closer_by_what_the_sensor_may_miss():
    perfect, perceived = traffic_task({}), traffic_task(EVERYTHING)
    plain, wary = perfect.phantoms(), perceived.phantoms()
    np.testing.assert_array_equal(plain.ego_zone, wary.ego_zone)
    reach = 50 / 3.6 * (10 + 25 + 1) * DT  # top speed over latency, a miss and a tick
    assert np.all(wary.entry <= np.maximum(plain.entry - reach, 0.0) + 1e-9)
    assert np.all(wary.entry >= 0.0) and np.any(wary.entry < plain.entry - reach - 1e-9)
    trusting = traffic_task(EVERYTHING, assume="perfect").phantoms()
    np.testing.assert_array_equal(trusting.entry, plain.entry)


def test_in_traffic_the_nearest_vehicles_are_observed_where_they_are_seen():
    task = traffic_task({"latency_s": 0.4}, observe="nearest")
    truthful = traffic_task({}, observe="nearest")
    scenarios = task.scenario_set(2, 16)
    late, now = task.initial(scenarios), truthful.initial(scenarios)
    for _ in range(200):
        late, rec_late = task.step(late, np.zeros(16))
        now, rec_now = truthful.step(now, np.zeros(16))
    assert rec_late.observation.shape == rec_now.observation.shape
    assert not np.allclose(rec_late.observation[:, 6:], rec_now.observation[:, 6:])


# -- the guarantee ------------------------------------------------------------------------------

EVERYTHING = {
    "position_error_m": 1.0, "speed_error_mps": 1.0, "latency_s": 0.2, "dropout_prob": 0.05,
    "dropout_max_s": 0.5, "sight_distance_m": 40.0, "errors": "adversarial",
}  # fmt: skip


@pytest.fixture(scope="module")
def trained():
    return load_policy("shipped").act


def collisions_by_adversary(task, count, trained, seed=5):
    scenarios = task.scenario_set(seed, count)
    out = {}
    for name, make in catalogue(task, count, seed=7, trained=trained).items():
        result = rollout(task, scenarios, make())
        out[name] = int(result.collision.sum() + result.lost_control.sum())
    return out


@pytest.mark.slow
def test_certified_with_declared_bounds_never_collides_under_adversarial_errors(trained):
    task = task_with(EVERYTHING)
    found = collisions_by_adversary(task, 400, trained)
    assert len(found) >= 9 and sum(found.values()) == 0, found


@pytest.mark.slow
def test_certified_taking_what_it_sees_as_the_truth_collides_under_the_same_errors(trained):
    task = task_with(EVERYTHING, assume="perfect")
    found = collisions_by_adversary(task, 400, trained)
    assert sum(found.values()) > 0, found


@pytest.mark.slow
@pytest.mark.parametrize(
    "perception",
    [
        EVERYTHING,
        {**EVERYTHING, "errors": "random"},
        {"position_error_m": 3.0, "speed_error_mps": 3.0, "latency_s": 0.5,
         "errors": "adversarial"},
        {"dropout_prob": 0.3, "dropout_max_s": 2.0, "sight_distance_m": 20.0},
    ],
)  # fmt: skip
def test_the_guarantee_holds_on_many_scenarios(perception, trained):
    task = task_with(perception)
    found = collisions_by_adversary(task, 3000, trained, seed=17)
    assert sum(found.values()) == 0, found


@pytest.mark.slow
def test_in_traffic_certified_with_declared_bounds_never_collides():
    found = collisions_by_adversary(traffic_task(EVERYTHING, preset="heavy"), 24, None)
    assert len(found) == 8 and sum(found.values()) == 0, found


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["light", "medium", "heavy", "test"])
def test_in_traffic_the_guarantee_holds_at_every_density(preset):
    found = collisions_by_adversary(traffic_task(EVERYTHING, preset=preset), 256, None, seed=9)
    assert sum(found.values()) == 0, found


@pytest.mark.slow
def test_in_traffic_trusting_what_it_sees_collides():
    found = collisions_by_adversary(traffic_task(EVERYTHING, assume="perfect"), 512, None)
    assert sum(found.values()) > 0, found
