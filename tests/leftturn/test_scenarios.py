"""The random scenario distribution, and a training distribution focused on a band of it."""

import dataclasses

import numpy as np
import pytest

from safeswitch.core.config import ConfigError, from_dict
from safeswitch.leftturn.config import LeftTurnConfig, ScenarioConfig
from safeswitch.leftturn.make import build_task

N = 20_000


def draw(scenarios: ScenarioConfig, seed: int = 9):
    task = build_task(None, LeftTurnConfig(scenarios=scenarios))
    return task.draw_scenarios(seed, np.arange(N), np.zeros(N, dtype=np.int64))


def test_a_focused_distribution_moves_only_the_focused_share_of_arrival_offsets():
    plain = draw(ScenarioConfig())
    focused = draw(ScenarioConfig(focus_share=0.25, focus_arrival_offset_s=(1.8, 3.0)))
    # every other parameter is drawn from the same numbers
    for name in ("ego_start_distance", "ego_speed", "north_speed"):
        assert np.array_equal(getattr(plain, name), getattr(focused, name))
    moved = focused.arrival_offset != plain.arrival_offset
    assert abs(moved.mean() - 0.25) < 0.015
    assert np.all((focused.arrival_offset[moved] >= 1.8) & (focused.arrival_offset[moved] <= 3.0))
    in_band = (focused.arrival_offset >= 1.8) & (focused.arrival_offset <= 3.0)
    # 15 % of the plain distribution (1.2 of its 8 s) plus the focused quarter
    assert abs(in_band.mean() - (0.25 + 0.75 * 1.2 / 8.0)) < 0.015
    assert plain.arrival_offset.min() >= -3.0 and plain.arrival_offset.max() <= 5.0


def test_a_focused_box_draws_a_share_of_whole_scenarios_from_wider_ranges():
    """Every ``focus_`` range set moves the focused share's values into it (a wider scene mixed
    into training); the rest are the plain distribution's draws, unchanged."""
    plain = draw(ScenarioConfig())
    wide = ScenarioConfig(
        focus_share=0.5, focus_arrival_offset_s=(-3.0, 5.0), focus_north_speed_kmh=(6.0, 44.0),
        focus_ego_speed_kmh=(18.0, 30.0), focus_ego_start_distance_m=(22.0, 40.0),
    )  # fmt: skip
    mixed = draw(wide)
    moved = mixed.north_speed != plain.north_speed
    assert abs(moved.mean() - 0.5) < 0.015
    for name in ("ego_start_distance", "ego_speed", "arrival_offset"):
        assert np.array_equal(getattr(mixed, name)[~moved], getattr(plain, name)[~moved])
    kmh = mixed.north_speed[moved] * 3.6
    assert kmh.min() < 8.0 and kmh.max() > 42.0 and kmh.min() >= 6.0 - 1e-9
    assert (mixed.ego_start_distance[moved] < 30.0).mean() > 0.4
    assert mixed.ego_speed.max() * 3.6 > 29.0
    # a focus range left unset keeps the plain range for the focused share
    only_north = draw(dataclasses.replace(wide, focus_ego_start_distance_m=None))
    assert only_north.ego_start_distance.min() >= 32.0


def test_a_focused_box_that_does_not_fit_the_road_is_refused():
    far = ScenarioConfig(focus_share=0.1, focus_north_speed_kmh=(20.0, 90.0))
    with pytest.raises(ConfigError, match="north_speed_kmh"):
        build_task(None, LeftTurnConfig(scenarios=far))


def test_the_plain_distribution_is_what_it_was_before_the_focus_existed():
    """``focus_share`` 0 draws four numbers per scenario, as before it was added: the
    scenarios behind every recorded result stay the same."""
    from safeswitch.leftturn.scenarios import counter_uniforms

    u = counter_uniforms(9, np.arange(N), np.zeros(N, dtype=np.int64), 4)
    plain = draw(ScenarioConfig())
    assert np.array_equal(plain.arrival_offset, -3.0 + 8.0 * u[:, 3])
    assert np.array_equal(plain.ego_start_distance, 32.0 + 8.0 * u[:, 0])


@pytest.mark.parametrize(
    ("given", "named"),
    [({"focus_share": 1.5}, "focus_share"), ({"focus_share": float("nan")}, "focus_share"),
     ({"focus_arrival_offset_s": (3.0, 1.8)}, "focus_arrival_offset_s"),
     ({"focus_north_speed_kmh": (0.0, 30.0)}, "focus_north_speed_kmh"),
     ({"focus_ego_start_distance_m": (10.0, 30.0)}, "focus_ego_start_distance_m")],
)  # fmt: skip
def test_a_bad_focus_is_named(given, named):
    with pytest.raises(ConfigError, match=named):
        ScenarioConfig(**given)


def test_only_training_draws_from_train_scenarios(monkeypatch, tmp_path):
    """``train_scenarios`` is the training environments' distribution; the validation and the
    evaluations keep ``env.scenarios``."""
    from safeswitch.training import run as run_module
    from safeswitch.training import train
    from safeswitch.training.config import TrainConfig
    from safeswitch.training.validation import Validator

    config = from_dict(TrainConfig, {
        "n_envs": 4, "timesteps": 1024, "train_only": {"scenarios": {"focus_share": 0.5}},
        "validation": {"every": 1024, "episodes": 50}})  # fmt: skip
    assert config.train_env.scenarios.focus_share == 0.5
    assert config.env.scenarios.focus_share == 0.0
    assert config.train_env == dataclasses.replace(
        config.env, scenarios=dataclasses.replace(config.env.scenarios, focus_share=0.5)
    )
    assert Validator(config, tmp_path).task.config.scenarios.focus_share == 0.0
    seen = []

    class Stop(Exception):
        pass

    def capture(n, *, config, **kwargs):
        seen.append(config)
        raise Stop

    monkeypatch.setattr(run_module, "LeftTurnVecEnv", capture)
    with pytest.raises(Stop):
        train(config, tmp_path / "run", progress_bar=False)
    assert seen[0].scenarios.focus_share == 0.5


def test_train_only_changes_the_training_environment_alone_and_names_a_bad_key():
    from safeswitch.training.config import TrainConfig

    given = {"deploy_switching": "paper", "env": {"switching": "guarded"},
             "train_only": {"paper": {"ttr_threshold_s": 2.3}}}  # fmt: skip
    config = from_dict(TrainConfig, given)
    assert config.train_env.paper.ttr_threshold_s == 2.3
    assert config.train_env.switching == "guarded"  # the rest of env is kept, key by key
    assert config.env.paper.ttr_threshold_s == 2.0
    assert config.deployed_env.paper.ttr_threshold_s == 2.0
    with pytest.raises(ConfigError, match=r"train_only\.paper.*'ttr_thresh'"):
        from_dict(TrainConfig, {"train_only": {"paper": {"ttr_thresh": 2.3}}})
    with pytest.raises(ConfigError, match=r"ttr_threshold_s.*-1"):
        from_dict(TrainConfig, {"train_only": {"paper": {"ttr_threshold_s": -1.0}}})
    with pytest.raises(ConfigError, match=r"train_only\.scenarios: expected a mapping"):
        from_dict(TrainConfig, {"train_only": {"scenarios": 3}})


def test_rehearsing_environments_draw_the_other_distribution_and_the_rest_are_unchanged():
    """``LeftTurnVecEnv.rehearse`` (``safeswitch adapt``'s rehearsal): the last environments
    draw their episodes from another distribution, exactly the scenarios a batch of that
    distribution would draw for them; the others draw what they drew without it, episode after
    episode."""
    from safeswitch.leftturn.vec_env import LeftTurnVecEnv

    original = LeftTurnConfig(switching="certified")
    shift = dataclasses.replace(original, scenarios=ScenarioConfig(north_speed_kmh=(38.0, 44.0)))

    def north_speeds(vec, episodes):
        speeds = [[info["scenario"]["north_speed"] for info in vec.reset_infos]]
        for _ in range(episodes - 1):  # every episode lasts the horizon: all end together
            done = np.zeros(vec.num_envs, dtype=bool)
            while not done.all():
                _, _, dones, _ = vec.step(np.zeros((vec.num_envs, 1), dtype=np.float32))
                done |= dones
            speeds.append([info["scenario"]["north_speed"] for info in vec.reset_infos])
        return 3.6 * np.array(speeds)

    def batch(config, rehearse=0):
        vec = LeftTurnVecEnv(6, config=config, seed=5)
        if rehearse:
            vec.rehearse(original, rehearse)
        vec.reset()
        return vec

    mixed = batch(shift, rehearse=2)
    assert mixed.rehearsing.tolist() == [False] * 4 + [True] * 2
    got = north_speeds(mixed, 3)
    np.testing.assert_array_equal(got[:, :4], north_speeds(batch(shift), 3)[:, :4])
    np.testing.assert_array_equal(got[:, 4:], north_speeds(batch(original), 3)[:, 4:])
    assert (got[:, :4] >= 38).all() and (got[:, 4:] <= 32).all()
    with pytest.raises(ValueError, match=r"count must be in 0…6, got 7"):
        mixed.rehearse(original, 7)


@pytest.mark.parametrize(
    "given",
    [
        {"north_speed_kmh": (40.0, 50.0)},
        {"arrival_offset_s": (-3.0, 12.0)},
        {"focus_share": 0.2, "focus_arrival_offset_s": (1.0, 9.0), "north_speed_kmh": (30, 40)},
    ],
)
def test_a_distribution_that_starts_the_north_car_off_its_route_is_refused_with_what_fits(given):
    """Before any episode, naming the values; each suggested bound is accepted and draws every
    north car on its route."""
    scenarios = ScenarioConfig(**given)
    with pytest.raises(ConfigError, match=r"starts up to .* before the conflict point") as error:
        build_task(None, LeftTurnConfig(scenarios=scenarios))
    text = str(error.value)
    speed = float(text.split("upper end to at most ")[1].split(" km/h")[0])
    offset = float(text.split("arrival_offset_s's to at most ")[1].split(" s")[0])
    slower = dataclasses.replace(
        scenarios, north_speed_kmh=(min(scenarios.north_speed_kmh[0], speed), speed)
    )
    sooner = dataclasses.replace(
        scenarios,
        arrival_offset_s=(min(scenarios.arrival_offset_s[0], offset), offset),
        focus_arrival_offset_s=(min(scenarios.focus_arrival_offset_s[0], offset), offset),
    )
    for fits in (slower, sooner):
        task = build_task(None, LeftTurnConfig(scenarios=fits))
        state = task.initial(task.scenario_set(3, 2_000))  # the farthest draws start on the route
        assert len(state.tick) == 2_000


def test_a_named_scenario_is_not_held_to_the_random_distribution():
    """With a named scenario the random distribution is never drawn, so it is not checked."""
    far = ScenarioConfig(north_speed_kmh=(40.0, 50.0))
    task = build_task(None, LeftTurnConfig(scenarios=far, scenario="cut"))
    assert task.initial(task.named("cut", 3)).tick.shape == (3,)


def test_an_ego_that_would_start_off_its_route_is_refused_by_name():
    far = ScenarioConfig(ego_start_distance_m=(32.0, 140.0))
    with pytest.raises(ConfigError, match=r"ego_start_distance_m: up to 140 m, but the ego's"):
        build_task(None, LeftTurnConfig(scenarios=far))
