"""The certified switching logic: zero collisions for any learned controller (SPEC §3)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from safeswitch.core.switching import supervise
from safeswitch.evaluation.adversaries import catalogue
from safeswitch.evaluation.rollout import rollout
from safeswitch.leftturn.config import resolve_config
from safeswitch.leftturn.scenarios import scenario_grid
from safeswitch.leftturn.task import LeftTurnTask
from safeswitch.leftturn.views import north_view
from safeswitch.sim.vehicle import VehicleState, vehicle_step
from safeswitch.training.policies import load_policy

ADVERSARIES = (
    "uniform",
    "bang_bang",
    "full_throttle",
    "zero_throttle",
    "enter_then_stop",
    "creep",
    "nan_inf",
    "noisy_cruise",
    "noisy_trained",
)


@pytest.fixture(scope="module")
def shipped_act():
    return load_policy("shipped").act


@pytest.fixture(scope="module")
def certified_task():
    return LeftTurnTask(
        resolve_config({"episode": {"learned_scope": "episode"}}, switching="certified")
    )


@pytest.fixture(scope="module")
def logic(certified_task):
    return certified_task.switching


def scenarios_for(task, random_count=1000):
    random = task.draw_scenarios(123, np.arange(random_count), np.zeros(random_count, int))
    grid = scenario_grid(
        np.linspace(-3, 5, 17), np.array([20.0, 24.0, 28.0, 32.0]), np.array([18.0, 21.5, 25.0])
    )
    return random, grid


@pytest.fixture(scope="module")
def guarded_task():
    return LeftTurnTask(
        resolve_config({"episode": {"learned_scope": "episode"}}, switching="guarded")
    )


@pytest.mark.parametrize("switching", ["certified", "guarded"])
@pytest.mark.parametrize("adversary", ADVERSARIES)
def test_no_adversary_makes_certified_collide(request, shipped_act, adversary, switching):
    """The filter alone, and the filter beneath the paper logic (``guarded``: it judges what
    the paper logic lets through, so its guarantee covers the pair)."""
    task = request.getfixturevalue(f"{switching}_task")
    random, grid = scenarios_for(task)
    for scenarios in (random, grid):
        batch = scenarios.ego_speed.shape[0]
        make = catalogue(task, batch, seed=1, trained=shipped_act)[adversary]
        result = rollout(task, scenarios, make())
        assert result.collision.sum() == 0
        assert result.lost_control.sum() == 0  # nor any slide off the lane (the curve speeds)
        assert result.min_separation.min() > 0.0
        assert result.max_lateral.max() <= task.config.certified.ego_max_lateral_m


@pytest.mark.slow
def test_the_paper_logic_has_a_blind_spot_that_certified_closes():
    """Changing pace after the gap looked safe (here: random bang-bang throttle) defeats the
    paper's rule, not the filter, nor the filter beneath the paper's rule; there, both act (the
    filter, which allows for the worst the north car can do, on most of the ticks)."""
    counts, reasons = {}, {}
    for switching in ("paper", "certified", "guarded"):
        task = LeftTurnTask(
            resolve_config({"episode": {"learned_scope": "episode"}}, switching=switching)
        )
        scenarios, _ = scenarios_for(task, 2000)
        ticks = np.zeros(len(task.reasons), dtype=np.int64)

        def count(state, record, tick, ticks=ticks, task=task):
            acted = record.reason[record.safety_active]
            ticks[:] += np.bincount(acted, minlength=len(task.reasons))

        result = rollout(task, scenarios, catalogue(task, 2000, seed=1)["bang_bang"](), count)
        counts[switching] = int(result.collision.sum())
        reasons[switching] = dict(zip(task.reasons, ticks.tolist(), strict=True))
    assert counts["paper"] > 0 and counts["certified"] == 0 and counts["guarded"] == 0
    paper_ticks = reasons["guarded"]["no_gap_at_braking_point"]
    guard_ticks = sum(n for r, n in reasons["guarded"].items() if r.startswith("guard:"))
    assert paper_ticks > 0 and guard_ticks > 0, reasons
    # and where the paper logic's own braking was unsafe, the filter overruled it
    overruled = sum(n for r, n in reasons["guarded"].items() if r.endswith(":overrules_primary"))
    assert overruled > 0, reasons


def test_a_safe_learned_action_is_never_replaced(certified_task):
    """Far from the intersection every action is safe: the filter stays silent."""
    scenarios, _ = scenarios_for(certified_task, 200)
    silent = []

    def watch(state, record, tick):
        far = state.world.progress[:, 0] < certified_task.conflict.zone_a[0] - 25.0
        silent.append(~record.safety_active[far])

    rollout(certified_task, scenarios, catalogue(certified_task, 200, 0)["uniform"](), watch)
    assert np.concatenate(silent).all()


@pytest.fixture(scope="module")
def north(certified_task):
    """The geometry of the ego's conflict with the north car (the states below use it)."""
    return certified_task.north_conflict


def make_state(north, e_progress, e_speed, e_throttle, e_brake, n_progress, n_speed):
    arrays = [
        np.atleast_1d(np.asarray(v, dtype=float))
        for v in (e_progress, e_speed, e_throttle, e_brake, n_progress, n_speed)
    ]
    arrays = list(np.broadcast_arrays(*arrays))
    return north_view(north, *(np.ascontiguousarray(a) for a in arrays), arrays[5].copy())


def is_safe(logic, s):
    return logic.safe(s)


def advance(logic, north, s, pedals, north_accel, progress_ratio):
    """One tick of the plant's longitudinal model for the ego, the north car anywhere within
    the assumptions, and the ego's progress per metre driven anywhere in the allowed band."""
    dt = logic.dt
    ego = VehicleState.at(0.0, 0.0, 0.0, s.ego_speed, s.ego_throttle)
    ego.brake = np.asarray(s.ego_brake, dtype=np.float64).copy()
    ego, _ = vehicle_step(logic.vehicle, ego, pedals[:, 0], pedals[:, 1], 0.0, dt)
    th, br, speed = ego.throttle, ego.brake, ego.speed
    progress = s.ego_progress + 0.5 * (s.ego_speed + speed) * dt * progress_ratio
    top = logic.config.other_max_speed_kmh / 3.6
    n_speed = np.clip(s.north_speed + north_accel * dt, 0.0, top)
    n_progress = s.north_progress + 0.5 * (s.north_speed + n_speed) * dt
    return make_state(north, progress, speed, th, br, n_progress, n_speed)


@settings(max_examples=400, deadline=None)
@given(
    e_offset=st.floats(-40.0, 15.0),
    e_speed=st.floats(0.0, 15.0),
    e_throttle=st.floats(0.0, 1.0),
    e_brake=st.floats(0.0, 1.0),
    n_offset=st.floats(-80.0, 15.0),
    n_speed=st.floats(0.0, 13.8),
    throttle=st.floats(0.0, 1.0),
    brake=st.sampled_from([0.0, 0.0, 1.0]),
    north_accel=st.floats(-9.0, 2.5),
    progress_ratio=st.floats(1 / 1.05, 1.05),
)
def test_invariant_safe_states_stay_safe_under_any_learned_action(
    logic,
    north,
    e_offset,
    e_speed,
    e_throttle,
    e_brake,
    n_offset,
    n_speed,
    throttle,
    brake,
    north_accel,
    progress_ratio,
):
    state = make_state(
        north,
        north.ego_cert_zone[0] + e_offset,
        e_speed,
        e_throttle,
        e_brake,
        north.north_cert_zone[0] + n_offset,
        n_speed,
    )
    if not is_safe(logic, state)[0]:
        return
    learned = np.array([[throttle, brake]])
    sup = supervise(logic, state, learned, np.array([[0.0, 1.0]]), 0.0, 1.0)
    after = advance(logic, north, state, sup.executed, north_accel, progress_ratio)
    assert is_safe(logic, after)[0]


@settings(max_examples=300, deadline=None)
@given(
    e_offset=st.floats(-40.0, 15.0),
    e_speed=st.floats(0.0, 15.0),
    n_offset=st.floats(-80.0, 15.0),
    n_speed=st.floats(0.0, 13.8),
    throttle=st.one_of(st.floats(-5.0, 5.0), st.just(np.nan), st.just(np.inf)),
)
def test_executed_action_is_the_learned_one_or_a_backup_and_never_nan(
    logic, north, e_offset, e_speed, n_offset, n_speed, throttle
):
    state = make_state(
        north,
        north.ego_cert_zone[0] + e_offset,
        e_speed,
        0.2,
        0.0,
        north.north_cert_zone[0] + n_offset,
        n_speed,
    )
    pid_brake = np.array([[0.0, 0.7]])
    sup = supervise(logic, state, np.array([[throttle, 0.0]]), pid_brake, 0.0, 1.0)
    executed = sup.executed[0]
    assert np.isfinite(executed).all()
    candidates = [[1.0, 0.0], [0.0, 0.0], [0.0, 1.0], pid_brake[0]]  # clear: throttle or coast
    if np.isfinite(throttle):
        candidates.append([min(max(throttle, 0.0), 1.0), 0.0])
    assert any(np.allclose(executed, c) for c in candidates)
    if not np.isfinite(throttle):
        assert sup.safety_active[0]


def break_north(task, scenarios, new_speed_kmh, when_progress, adversary="uniform"):
    """Roll an adversary while the north car's autopilot target changes to ``new_speed_kmh``
    once it is ``when_progress`` metres before its conflict zone."""
    triggered = np.zeros(scenarios.ego_speed.shape[0], dtype=bool)
    flagged = np.zeros_like(triggered)
    no_backup = {
        task.reasons.index("no_certified_backup_brake"),
        task.reasons.index("no_certified_backup_clear"),
    }

    def hook(state, record, tick):
        near = state.world.progress[:, 1] > task.north_conflict.north_cert_zone[0] - when_progress
        change = near & ~triggered
        state.scenarios.north_speed[change] = new_speed_kmh / 3.6
        triggered[change] = True
        flagged[np.isin(record.reason, list(no_backup))] = True

    policy = catalogue(task, scenarios.ego_speed.shape[0], 0)[adversary]()
    return rollout(task, scenarios, policy, hook), flagged


def test_a_north_car_that_brakes_hard_and_stops_in_the_intersection_is_still_avoided(
    certified_task,
):
    """Braking only delays the north car: outside the assumptions' letter, inside their
    spirit. The filter waits for it."""
    scenarios, _ = scenarios_for(certified_task, 1000)
    result, _ = break_north(certified_task, scenarios, 0.0, when_progress=-3.0)  # stops inside
    assert result.collision.sum() == 0


def test_a_north_car_faster_than_assumed_is_flagged_whenever_it_causes_a_collision(
    certified_task,
):
    scenarios, _ = scenarios_for(certified_task, 1000)
    # (A north car three times faster than assumed, from 60 m before its zone: with the curve
    # speeds the clear backup keeps to, a milder break of the assumption no longer shows.)
    result, flagged = break_north(
        certified_task, scenarios, 150.0, when_progress=60.0, adversary="full_throttle"
    )
    # Breaking the speed assumption can defeat the certificate ...
    assert result.collision.sum() > 0
    # ... but never silently: every such collision follows a "no certified backup" decision.
    assert flagged[result.collision].all()


def random_states(north, rng, n):
    """States around both conflict zones: the ego 40 m before to 15 m into its zone at up to
    54 km/h with any pedals, the north car 80 m before to 15 m into its zone."""
    return make_state(
        north,
        north.ego_cert_zone[0] + rng.uniform(-40, 15, n),
        rng.uniform(0, 15, n),
        rng.uniform(0, 1, n),
        rng.uniform(0, 1, n),
        north.north_cert_zone[0] + rng.uniform(-80, 15, n),
        rng.uniform(0, 13.8, n),
    )


def test_invariant_on_200k_random_states_including_the_intervention_boundary(logic, north):
    """Hypothesis explores shapes; this sweeps volume, so the rare states where the filter
    must intervene (about 0.15 % of safe ones) are hit hundreds of times."""
    rng = np.random.default_rng(0)
    n = 200_000
    state = random_states(north, rng, n)
    safe = is_safe(logic, state)
    learned = np.stack([rng.uniform(0, 1, n), rng.choice([0.0, 0.0, 1.0], n)], axis=1)
    sup = supervise(logic, state, learned, np.tile([0.0, 1.0], (n, 1)), 0.0, 1.0)
    after = advance(
        logic, north, state, sup.executed, rng.uniform(-9, 2.5, n),
        rng.uniform(1 / 1.05, 1.05, n),
    )  # fmt: skip
    assert (safe & sup.safety_active).sum() > 100
    assert not (safe & ~is_safe(logic, after)).any()


def test_the_cheap_screen_only_passes_states_the_full_certificate_accepts(logic, north):
    """``settled`` skips the certificate; every state it passes must be one the certificate
    accepts after a tick of any pedals, including full throttle with no brake."""
    rng = np.random.default_rng(3)
    n = 200_000
    state = random_states(north, rng, n)
    settled = logic.settled(state)
    assert 0.2 < settled.mean() < 0.9  # the screen decides a real share, not all or nothing
    for pedals in ([1.0, 0.0], [0.0, 0.0], [0.5, 0.5]):
        accepted = logic.accepts(state, np.tile(pedals, (n, 1)))
        assert accepted[settled].all()


def test_the_quick_curve_bound_only_passes_states_the_full_curve_certificate_accepts(logic):
    """``_stable_quick`` (the screen's, and the filter's first try after the learned tick)
    must be sufficient for ``_stable``: every state it passes, with the lag phase's worst
    speed gain on top of the speed, is one the full curve certificate accepts."""
    from safeswitch.leftturn.logics.certified import _stable, _stable_quick

    rng = np.random.default_rng(5)
    c, envelope = logic.bounds.c, logic.envelope
    route = envelope.spacing * envelope.curve.shape[0]
    passed = 0
    for _ in range(20_000):
        progress, speed = rng.uniform(0, route), rng.uniform(0, 15)
        throttle, brake = rng.uniform(0, 1), rng.choice([0.0, rng.uniform(0, 1)])
        if _stable_quick(progress, speed + c.lag_gain_worst, c, envelope):
            passed += 1
            assert _stable(progress, speed, throttle, brake, logic.bounds, envelope)
    assert 0.3 < passed / 20_000 < 0.99  # it decides a real share


def test_the_quick_stop_bound_never_undercuts_the_exact_one_nor_the_plant(logic):
    rng = np.random.default_rng(4)
    n = 20_000
    speed, throttle, brake = rng.uniform(0, 20, n), rng.uniform(0, 1, n), rng.uniform(0, 1, n)
    exact = logic.stop_distance(speed, throttle, brake)
    assert (logic.quick_stop_distance(speed) >= exact - 1e-9).all()
    # And the exact bound holds on the plant itself: brake fully and measure.
    state = VehicleState.at(np.zeros(n), 0.0, 0.0, speed, throttle)
    state.brake[:] = brake
    for _ in range(800):
        state, _ = vehicle_step(logic.vehicle, state, 0.0, 1.0, 0.0, logic.dt)
    assert (state.speed == 0).all()
    assert (state.x <= exact + 1e-9).all()


@pytest.mark.slow
def test_the_clear_time_bound_is_never_beaten_by_the_plant(logic):
    """The clear backup on the plant itself — full throttle below its holding speed, closed
    above it — covers the distance no later than the bound says, from any state the filter
    counts it from, and never drives faster than the sharpest curve allows."""
    from safeswitch.leftturn.logics.certified import clear_pedals

    c = logic.bounds.c
    rng = np.random.default_rng(6)
    n = 20_000
    throttle, brake = rng.uniform(0, 1, n), rng.uniform(0, 1, n)
    top = c.clear_hold + c.accel_max * c.lag_time * (1 - throttle)  # where the filter counts it
    speed = rng.uniform(0, 1, n) * top
    distance = rng.uniform(0, 30, n)
    bound = logic.clear_time(distance, speed, throttle, brake)
    assert np.isfinite(bound).all()
    state = VehicleState.at(np.zeros(n), 0.0, 0.0, speed, throttle)
    state.brake[:] = brake
    reached = np.where(distance <= 0, 0.0, np.inf)
    peak = speed.copy()
    for k in range(1, 1500):
        before = state.x
        pedals = np.array([clear_pedals(v, th, c) for v, th in zip(state.speed, state.throttle,
                                                                   strict=True)])  # fmt: skip
        state, _ = vehicle_step(logic.vehicle, state, pedals[:, 0], pedals[:, 1], 0.0, logic.dt)
        peak = np.maximum(peak, state.speed)
        # The crossing within the tick, interpolated between the two positions.
        with np.errstate(divide="ignore", invalid="ignore"):
            crossing = (k - 1 + (distance - before) / (state.x - before)) * logic.dt
        reached = np.where(np.isinf(reached) & (state.x >= distance), crossing, reached)
        if np.isfinite(reached).all():
            break
    assert (reached <= bound + 1e-9).all()
    assert (bound - reached).mean() < 0.5  # a useful bound, not a vacuous one
    sharpest = np.sqrt(logic.envelope.curve.min())
    assert peak.max() + c.lag_gain_worst <= sharpest  # within every curve of the ego's route


def test_the_filter_predicts_the_learned_tick_exactly_as_the_plant_drives_it(logic, north):
    """The one-tick prediction runs the plant's own longitudinal model: speed and pedal positions
    agree bit for bit, and the true progress lies within the predicted bounds."""
    rng = np.random.default_rng(8)
    n = 50_000
    state = random_states(north, rng, n)
    pedals = np.stack([rng.uniform(0, 1, n), rng.choice([0.0, 0.3, 1.0], n)], axis=1)
    low, high, speed, throttle, brake = logic.predict(state, pedals)
    plant = VehicleState.at(0.0, 0.0, 0.0, state.ego_speed, state.ego_throttle)
    plant.brake = state.ego_brake.copy()
    plant, _ = vehicle_step(logic.vehicle, plant, pedals[:, 0], pedals[:, 1], 0.0, logic.dt)
    np.testing.assert_array_equal(speed, plant.speed)
    np.testing.assert_array_equal(throttle, plant.throttle)
    np.testing.assert_array_equal(brake, plant.brake)
    step = plant.x  # driven straight east from 0: the arc length of the tick
    assert (low <= state.ego_progress + step + 1e-12).all()
    assert (state.ego_progress + step <= high + 1e-12).all()
    assert (high - low > 0).any()


@pytest.mark.parametrize("scope", ["window", "episode"])
@pytest.mark.parametrize("switching", ["paper", "certified", "none"])
def test_invalid_learned_actions_add_no_collisions(scope, switching):
    """NaN on 30 % of the ticks of a random learned controller, the rest unchanged: as many
    collisions as without the NaN ticks (within sampling noise). Braking in their place —
    wherever the ego was — made it 266 in 2,500 under the paper logic in the default window."""
    from safeswitch.evaluation.adversaries import uniform, with_invalid

    task = LeftTurnTask(resolve_config({"episode": {"learned_scope": scope}}, switching=switching))
    n = 1500
    scenarios = task.draw_scenarios(99, np.arange(n), np.zeros(n, int))
    alone = rollout(task, scenarios, uniform(np.random.default_rng(5)))
    broken = with_invalid(uniform(np.random.default_rng(5)), np.random.default_rng(3))
    invalid = rollout(task, scenarios, broken)
    assert invalid.invalid_steps.sum() > 10_000  # NaN ticks while the learned controller drove
    expected = int(alone.collision.sum())
    assert invalid.collision.sum() <= expected + 3 * np.sqrt(expected + 1) + 2


# -- narrower certified zones for an ego behind a speed limiter ---------------------------------

LIMITED = {"controllers": {"learned_speed_limiter_kmh": 29.9}}
NARROW = {"certified": {"ego_max_lateral_m": 0.45, "zone_margin_m": 0.9}}


@pytest.mark.parametrize("adversary", ["uniform", "bang_bang", "full_throttle", "enter_then_stop"])
def test_behind_the_speed_limiter_no_throttle_takes_the_ego_045_m_off_its_route(adversary):
    """What lets a training guard (configs/paper.yaml) assume ``ego_max_lateral_m`` 0.45 instead
    of 0.6: the limited ego takes the turn at no more than 30 km/h, where ``PID_lka`` holds it
    within 0.44 m whatever the throttle does — without the limiter, full throttle reaches 0.51 m."""
    config = {"episode": {"learned_scope": "episode"}, **LIMITED}
    task = LeftTurnTask(resolve_config(config, switching="none"))
    for scenarios in scenarios_for(task, 1000):
        batch = scenarios.ego_speed.shape[0]
        result = rollout(task, scenarios, catalogue(task, batch, 0)[adversary]())
        assert result.max_lateral.max() <= 0.45
    free = LeftTurnTask(resolve_config({"episode": {"learned_scope": "episode"}}, switching="none"))
    random, _ = scenarios_for(free, 1000)
    assert (
        rollout(free, random, catalogue(free, 1000, 0)["full_throttle"]()).max_lateral.max() > 0.45
    )


#: A training guard with the assumptions of the left-turn scene itself (the north car holds
#: its speed, 20-32 km/h): experiments/paper_fric_scene_guard.yaml.
SCENE = {"certified": {"other_max_accel": 0.05, "other_max_speed_kmh": 32.1}}


def test_in_the_left_turn_scene_the_north_car_holds_its_speed_so_a_scene_guard_is_truthful():
    """What lets a training guard assume the scene's north car (``SCENE``): on every tick of
    every scenario, whatever the ego does, the north car's speed is its scenario's, at most
    32 km/h — and a guard that assumes a faster, accelerating one would still be sound."""
    task = LeftTurnTask(resolve_config({"episode": {"learned_scope": "episode"}}, switching="none"))
    random, grid = scenarios_for(task, 1000)
    for scenarios in (random, grid):
        batch = scenarios.ego_speed.shape[0]
        state = task.initial(scenarios)
        start = state.world.vehicles.speed[:, 1].copy()
        assert start.max() <= 32.0 / 3.6 + 1e-9
        act = catalogue(task, batch, 0)["bang_bang"]()
        for tick in range(task.config.episode.horizon_ticks):
            state, _ = task.step(state, act(task.observe(state), state, tick))
            np.testing.assert_array_equal(state.world.vehicles.speed[:, 1], start)


@pytest.mark.parametrize(
    ("switching", "scene"), [("certified", False), ("guarded", False), ("guarded", True)]
)
@pytest.mark.parametrize(
    "adversary", ["uniform", "bang_bang", "full_throttle", "enter_then_stop", "creep"]
)
def test_no_adversary_collides_behind_the_limiter_with_the_narrower_zones(
    switching, scene, adversary
):
    """The narrower zones behind the limiter; under `guarded` also with the scene's own north
    car assumed (``SCENE``: the shipped `paper` recipe's training guard)."""
    config = {"episode": {"learned_scope": "episode"}, **LIMITED}
    config["certified"] = {**NARROW["certified"], **(SCENE["certified"] if scene else {})}
    task = LeftTurnTask(resolve_config(config, switching=switching))
    for scenarios in scenarios_for(task, 1000):
        batch = scenarios.ego_speed.shape[0]
        result = rollout(task, scenarios, catalogue(task, batch, 0)[adversary]())
        assert result.collision.sum() == 0 and result.lost_control.sum() == 0


@pytest.mark.slow
def test_the_narrower_zones_let_the_ego_follow_a_north_car_it_yielded_to_more_closely():
    """Why a training guard narrows them: under `guarded` the planner (which plans around the
    paper logic alone and enters right behind the north car it yielded to) is braked by the
    filter; with the zones the limited ego needs, it keeps less of a gap and clears sooner."""
    from safeswitch.evaluation.planner import Planner

    runs = {}
    for name, zones in (("wide", {}), ("narrow", NARROW)):
        config = {"episode": {"learned_scope": "episode"}, **LIMITED, **zones}
        task = LeftTurnTask(resolve_config(config, switching="guarded"))
        random, _ = scenarios_for(task, 500)
        runs[name] = rollout(task, random, Planner(task))
    wide, narrow = runs["wide"], runs["narrow"]
    assert wide.collision.sum() == 0 and narrow.collision.sum() == 0
    assert np.nanmean(narrow.time_to_clear) < np.nanmean(wide.time_to_clear) - 0.2
    assert np.nanmean(narrow.min_pet) < np.nanmean(wide.min_pet) - 0.3


def test_a_configuration_written_with_the_old_north_names_still_loads():
    """The assumptions hold for every other vehicle, so they are named ``other_*``; a run's
    config.yaml written with ``north_max_*`` loads unchanged, and both names at once are refused
    by name."""
    from safeswitch.core.config import ConfigError
    from safeswitch.leftturn.config import resolve_config

    old = resolve_config({"certified": {"north_max_accel": 1.5, "north_max_speed_kmh": 40.0}})
    assert (old.certified.other_max_accel, old.certified.other_max_speed_kmh) == (1.5, 40.0)
    with pytest.raises(ConfigError, match="north_max_accel is the old name of other_max_accel"):
        resolve_config({"certified": {"north_max_accel": 1.5, "other_max_accel": 2.0}})


@pytest.fixture(scope="module")
def braking_task():
    """The certified filter with a learned controller that works both pedals."""
    return LeftTurnTask(
        resolve_config(
            {"episode": {"learned_scope": "episode"}, "controllers": {"learned_brake": True}},
            switching="certified",
        )
    )


@pytest.mark.parametrize("adversary", ["uniform", "bang_bang", "enter_then_stop", "noisy_cruise"])
def test_no_learned_braking_makes_certified_collide(braking_task, adversary):
    """With the learned brake (``controllers.learned_brake``) every negative action brakes —
    anywhere, inside the conflict zone too; the filter judges both pedals and still lets no
    collision through, while executing the learned brake wherever that is safe."""
    task = braking_task
    learned_braking = 0
    for scenarios in scenarios_for(task):
        batch = scenarios.ego_speed.shape[0]

        def count(state, record, tick):
            nonlocal learned_braking
            learned = ~record.safety_active & (record.controller == 0)
            learned_braking += int((learned & (record.brake > 0)).sum())

        make = catalogue(task, batch, seed=1)[adversary]
        result = rollout(task, scenarios, make(), count)
        assert result.collision.sum() == 0
        assert result.lost_control.sum() == 0
        assert result.min_separation.min() > 0.0
    assert learned_braking > 1000  # the learned brake really ran, not the filter's
